"""Chunk-by-chunk simulation of the musculoskeletal participant (one MuJoCo step a sample).

:class:`MskSimulator` has the interface of :class:`sim_backends.simulation.
ParticipantSimulator` (``simulate``, ``advance_quiet``, ``snapshot`` / ``restore``,
``cursor``, ``cumulative_stim_s``), so :class:`nmsid.sim_backends.world.SimWorld` - hence the
stimulator, acquisition, E-stop, fault script, engine and GUI - runs on it unchanged.

Per sample k (absolute index of the rig's time base): the delivered currents give each
muscle's excitation through its electrodes' recruitment (:mod:`nmsid.sim_backends.msk_physics`);
MuJoCo integrates activation dynamics, Hill-type muscle forces and the forearm on its
compliant mount over one timestep; the reading at sample k is the cuff force of the state
at the start of step k (the stimulator holds sample k over the step, so a current change
shows from the next sample on, as with the template participant's zero-order hold); the
sensor chain (:class:`nmsid.sim_backends.sensor.SensorState`: noise, offset, drift, mains,
wrench, over-range) is the template participant's, one signal path for both.

Fatigue (when enabled) updates each muscle's force scale on a fixed grid of absolute
samples, so the result does not depend on how the world chunks the simulation.
"""

from __future__ import annotations

import math

import numpy as np

from nmsid.sim_backends.msk_model import Stepper, configure
from nmsid.sim_backends.sensor import SensorState
from nmsid.sim_backends.simulation import QUIET_SKIP_SAMPLES, SimulatedBlock

QUIET_PIECE_SAMPLES = 2000
"""A rest is simulated in pieces of this many samples until the participant is at rest."""


class MskSimulator:
    """Stateful simulation of one :class:`~nmsid.sim_backends.msk_participant.MskParticipant`."""

    def __init__(self, participant, fs_Hz: float = 2000.0):
        self.p = participant
        self.fs_Hz = float(fs_Hz)
        self.cm = configure(participant.mount, participant.tau_act_s,
                            participant.tau_deact_s, self.fs_Hz, participant.stiffening,
                            joint=participant.joint)
        self.stepper = Stepper(self.cm)
        self.cursor = 0
        self.stim_samples = 0
        self._state = self.cm.rest_state.copy()
        self._fat = np.ones(len(participant.drives))
        self._acc = np.zeros(len(participant.drives))
        """Sum of excitations over the fatigue segment in progress."""
        self._seg_n = max(1, int(round(participant.fatigue.segment_s * self.fs_Hz)))
        reach = np.array([d.own.max_activation + d.spill.max_activation
                          for d in participant.drives])
        self._order = list(self.cm.drive_ctrl) or list(range(len(participant.drives)))
        self._reach = np.zeros(len(reach))       # in the model's actuator order
        self._reach[self._order] = reach
        self.sensor = SensorState(participant.sensor, participant.seed, self.fs_Hz)

    # -- inputs --------------------------------------------------------------------------
    def excitation(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> np.ndarray:
        """MuJoCo ``ctrl`` per sample: the muscles' excitations (in the model's actuator
        order), then the co-activation stiffness in N m/rad; shape (n, muscles + 1)."""
        e = np.column_stack([d.command(I_ext_mA, I_flex_mA) for d in self.p.drives])
        if self.cm.drive_ctrl:
            e[:, self._order] = e.copy()
        return np.column_stack([e, e @ self.cm.srs_Nm_rad])

    # -- simulation ----------------------------------------------------------------------
    def _run(self, ctrl: np.ndarray) -> np.ndarray:
        """Step through ``ctrl``; return the state at the start of every step."""
        n = len(ctrl)
        states = np.empty((n, self._state.size))
        if n == 0:
            return states
        if not self.p.fatigue.enabled:
            out = self.stepper.run(self._state, ctrl)
            states[0] = self._state
            states[1:] = out[:-1]
            self._state = np.array(out[-1])
            return states
        k = 0
        while k < n:
            N = self.cursor + k
            m = min(n - k, self._seg_n - N % self._seg_n)
            self.stepper.set_force_scale(self._fat)
            out = self.stepper.run(self._state, ctrl[k:k + m])
            states[k] = self._state
            states[k + 1:k + m] = out[:-1]
            self._state = np.array(out[-1])
            self._acc += ctrl[k:k + m, :self._acc.size].sum(axis=0)
            k += m
            if (N + m) % self._seg_n == 0:     # segment complete: update the fatigue state
                rel = np.divide(self._acc / self._seg_n, self._reach,
                                out=np.zeros(len(self._reach)), where=self._reach > 0)
                self._fat = self.p.fatigue.step(self._fat, rel, self._seg_n / self.fs_Hz)
                self._acc[:] = 0.0
        return states

    def simulate(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray, *,
                 spike_N: np.ndarray | None = None) -> SimulatedBlock:
        """Simulate the next ``len(I_ext_mA)`` samples from the cursor (see
        :meth:`nmsid.sim_backends.simulation.ParticipantSimulator.simulate`)."""
        I_e = np.asarray(I_ext_mA, dtype=float)
        I_f = np.asarray(I_flex_mA, dtype=float)
        n0 = self.cursor
        states = self._run(self.excitation(I_e, I_f))
        y = self.cm.endpoint_force_N(states[:, self.cm.q_col], states[:, self.cm.v_col])
        on = (I_e > 0) | (I_f > 0)
        self.stim_samples += int(np.count_nonzero(on))
        self.cursor = n0 + I_e.size
        force, wrench, over = self.sensor.measure(y if spike_N is None else y + spike_N, n0)
        return SimulatedBlock(n0, y, force, wrench, over, math.nan, self.cumulative_stim_s)

    def at_rest(self, tol: float = 1e-7) -> bool:
        """True if the state equals the rest state (activations, angle, velocity)."""
        return bool(np.max(np.abs(self._state[1:] - self.cm.rest_state[1:])) < tol)

    def advance_quiet(self, n: int) -> None:
        """Let ``n`` samples pass without stimulation (a rest), without measuring them."""
        if n <= 0:
            return
        done = 0
        limit = min(n, QUIET_SKIP_SAMPLES)
        while done < limit and not self.at_rest():
            m = min(QUIET_PIECE_SAMPLES, limit - done)
            self._run(np.zeros((m, self.cm.model.nu)))
            self.cursor += m
            done += m
        if done < n:       # settled (or 10 s passed): the rest of the gap changes nothing
            if self.p.fatigue.enabled:
                self._fat = self.p.fatigue.step(self._fat, np.zeros_like(self._fat),
                                                (n - done) / self.fs_Hz)
            self._state = self.cm.rest_state.copy()
            self._acc[:] = 0.0
            self.cursor += n - done

    def snapshot(self) -> tuple:
        """The simulator's whole state, to continue exactly from here later."""
        return (self.cursor, self.stim_samples, self._state.copy(), self._fat.copy(),
                self._acc.copy())

    def restore(self, snap: tuple) -> None:
        """Return to a :meth:`snapshot` (the sensor noise depends only on sample indices)."""
        self.cursor, self.stim_samples, state, fat, acc = snap
        self._state = state.copy()
        self._fat = fat.copy()
        self._acc = acc.copy()

    @property
    def cumulative_stim_s(self) -> float:
        return self.stim_samples / self.fs_Hz

    @property
    def force_scale(self) -> np.ndarray:
        """Present fatigue state per muscle (1 = fresh)."""
        return self._fat.copy()
