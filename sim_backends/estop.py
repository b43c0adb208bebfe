"""The simulated hardware E-stop switch."""

from __future__ import annotations

from nmsid.sim_backends.world import SimWorld


class SimEStop:
    """The hardware E-stop switch: pressed by the fault script or by :meth:`press`.

    Latching, like a mushroom switch: it stays pressed until :meth:`release`.
    """

    def __init__(self, world: SimWorld):
        self._w = world
        self._closed = False

    def is_pressed(self) -> bool:
        if self._closed:
            return True   # fail-safe: an unreadable switch reads as pressed
        w = self._w
        if w.estop_pressed:
            return True
        # lock-free in the common case: a poll never waits for a simulation in progress
        now = w.clock.monotonic_s()
        if not any(t <= now for t in w.estop_due_s):
            return False
        with w.lock:
            w.update()
            return w.estop_pressed

    def press(self) -> None:
        with self._w.lock:
            self._w.estop_pressed = True
            self._w.estop_pressed_at_s = self._w.now()

    def release(self) -> None:
        with self._w.lock:
            self._w.update()
            self._w.estop_pressed = False
            now = self._w.now()
            self._w.estop_due_s = [t for t in self._w.estop_due_s if t > now]

    @property
    def pressed_at_s(self) -> float | None:
        """Clock time of the latest press."""
        return self._w.estop_pressed_at_s

    def close(self) -> None:
        self._closed = True
