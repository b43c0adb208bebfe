"""A simulated hardware-timed force acquisition (six-axis sensor + A/D)."""

from __future__ import annotations

import time

import numpy as np

from nmsid.drivers.interfaces import AcquisitionFlags, ForceChunk
from nmsid.sim_backends.errors import DeviceStateError, SensorDisconnected, SimConfigError
from nmsid.sim_backends.world import SimWorld

#: Largest real-time wait slice while a read blocks (keeps reads responsive).
_WAIT_SLICE_S = 0.005


class SimForceAcquisition:
    """Delivers the virtual participant's force in chunks, aligned to the stimulator trigger.

    On the fast clock a read returns at once and moves the clock to the time the chunk's
    last sample was taken; in real time it blocks until then (at most ``timeout_s``).
    The force of each chunk is simulated when it is read, from the stimulator output as it
    is at that moment, with the participant's state carried over.
    """

    def __init__(self, world: SimWorld, buffer_s: float = 10.0):
        self._w = world
        self._closed = False
        self.fs_Hz = world.fs_Hz
        self.buffer_s = float(buffer_s)
        """Real time: samples older than this when read are lost (FIFO overflow)."""

    def configure(self, fs_Hz: float) -> float:
        if not (np.isfinite(fs_Hz) and 100.0 <= fs_Hz <= 20_000.0):
            raise SimConfigError(f"acquisition rate {fs_Hz!r} Hz is not supported by the "
                                 "simulated A/D; valid: 100-20000 Hz")
        self._w.set_fs(float(fs_Hz))
        self.fs_Hz = self._w.fs_Hz
        return self.fs_Hz

    def start(self, n_samples: int | None = None, *, triggered: bool = True) -> None:
        if self._closed:
            raise DeviceStateError("start() on a closed acquisition")
        if n_samples is not None and int(n_samples) < 0:
            raise SimConfigError(f"n_samples must be >= 0 or None, got {n_samples!r}")
        with self._w.lock:
            self._w.update()
            if self._w.acq_fault is not None:
                raise SensorDisconnected(f"start() failed: {self._w.acq_fault[0]}")
            if self._w.acq is not None:
                raise DeviceStateError("start() while acquiring; stop() first")
            self._w.start_acquisition(None if n_samples is None else int(n_samples),
                                      triggered)

    def read(self, timeout_s: float) -> ForceChunk | None:
        w = self._w
        clock = w.clock
        realtime = getattr(clock, "realtime", True)
        deadline = clock.monotonic_s() + max(0.0, float(timeout_s))
        while True:
            with w.lock:
                acq = w.acq
                if acq is None:
                    raise DeviceStateError("read() before start()")
                w.update()
                if w.acq_fault is not None:  # USB glitch: nothing more arrives
                    return ForceChunk(start_index=acq.next_k, force_N=np.zeros(0),
                                      flags=AcquisitionFlags(sensor_fault=True,
                                                             detail=w.acq_fault[0]))
                due = None
                if not acq.waiting and not acq.done:
                    Na, Nb = w.next_range(acq)
                    sf = w.stall_at(Na)
                    if sf is not None and not acq.stalled:
                        w.start_stall(acq, sf)
                    if acq.stalled:
                        if sf is None:  # a stall lasts while its fault is pending
                            raise DeviceStateError("simulated stall without its fault")
                        if acq.stall_end_s is not None and clock.monotonic_s() >= acq.stall_end_s:
                            acq.stalled = False
                            sf.done = True
                            dur = sf.fault.duration_s  # set: the stall ends (stall_end_s)
                            lost = int(round(min(sf.fault.lost_s, sf.fault.lost_s if dur is None
                                                 else dur) * w.fs_Hz))
                            if lost:   # a dropout: the stalled samples never arrive
                                acq.next_k += lost
                                acq.lost_detail = (f"sensor dropout: {lost} samples lost "
                                                   "(simulated)")
                            continue
                    else:
                        if realtime:
                            self._check_buffer(acq, clock.monotonic_s())
                            Na, Nb = w.next_range(acq)
                        due = w.due_time(acq, Nb)
                        if not realtime:
                            # a fault due inside this chunk fires first (a sensor lost at
                            # 1.44 s delivers nothing measured after it)
                            t_fault = w.next_timed_fault_s(due)
                            if t_fault is not None and t_fault > clock.monotonic_s():
                                clock.advance_to(t_fault)
                                continue
                            clock.advance_to(due)
                        if clock.monotonic_s() >= due - 1e-12:
                            force, wrench, sync, flags, k0 = w.acquire(acq, Na, Nb)
                            return ForceChunk(start_index=k0, force_N=force,
                                              wrench=wrench, sync=sync, flags=flags)
            # nothing to hand over yet
            now = clock.monotonic_s()
            if not realtime:
                clock.sleep(max(0.0, deadline - now))
                return None
            if now >= deadline:
                return None
            wake = deadline if due is None else min(deadline, due)
            time.sleep(max(0.0, min(_WAIT_SLICE_S, wake - now)))

    def _check_buffer(self, acq, now_s: float) -> None:
        """A host that reads too late loses the oldest samples (the device's buffer holds
        ``buffer_s``), like a hardware FIFO overflow."""
        w = self._w
        lag_s = now_s - w.due_time(acq, acq.N0 + acq.next_k + 1)
        if lag_s <= self.buffer_s:
            return
        keep_from = acq.N0 + int((now_s - self.buffer_s - acq.t0_s) * w.fs_Hz)
        if acq.n_samples is not None:
            keep_from = min(keep_from, acq.N0 + acq.n_samples)
        lost = keep_from - (acq.N0 + acq.next_k)
        if lost > 0:
            acq.next_k += lost
            acq.lost_detail = (f"acquisition buffer overflow: the host read {lag_s:.1f} s "
                               f"late, {lost} samples lost (simulated)")

    def stop(self) -> None:
        with self._w.lock:
            self._w.stop_acquisition()

    def device_fault(self) -> str:
        """What is wrong with the link to the device ("" if nothing)."""
        with self._w.lock:
            self._w.update()
            return self._w.acq_fault[0] if self._w.acq_fault is not None else ""

    def reconnect(self, fs_Hz: float) -> float:
        """Re-open the (simulated) device after a USB glitch; returns the rate.

        Raises
        ------
        SensorDisconnected
            While the simulated glitch lasts (``duration_s`` of the fault).
        """
        with self._w.lock:
            self._w.update()
            self._w.stop_acquisition()
            fault = self._w.acq_fault
            if fault is not None:
                if fault[1] is not None and self._w.now() < fault[1]:
                    raise SensorDisconnected(f"{fault[0]}: the device is not back yet")
                self._w.acq_fault = None
        return self.configure(fs_Hz)

    def close(self) -> None:
        self.stop()
        self._closed = True
