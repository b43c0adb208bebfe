"""Chunk-by-chunk simulation of a virtual participant and its force chain, with state.

:class:`ParticipantSimulator` turns the currents really delivered on each channel (one
value per acquisition sample, absolute sample indices of the rig's time base) into the
true endpoint force and the force chain's reading. Filter states, the dead-time line and
cumulative stimulation carry over from chunk to chunk and from trial to trial (the
participant keeps its state through rests), so the result does not depend on chunking.

Co-activation is sensed once per chunk: the median of ``max(u_e, 0) + max(u_f, 0)`` over
the chunk's stimulated samples, rounded to ``SE_RESOLUTION``; a change smaller than that
(the stimulator's 1 uA quantisation) keeps the previous value, so a trial at constant sE
has constant parameters. Without stimulation the parameters of the last co-activation are
kept (the force relaxes with the dynamics it had: an E-stop gives a smooth decay).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmsid.protocols.effects import chain_of
from nmsid.sim_backends.filters import DelayLine, StatefulFilter, dynamics_zoh
from nmsid.sim_backends.participant import (
    SE_RESOLUTION,
    OperatingPoint,
    VirtualParticipant,
    sensed_sE,
)
from nmsid.sim_backends.sensor import SensorState

QUIET_SKIP_SAMPLES = 20000
"""In a gap without stimulation, after this many samples (10 s at 2 kHz) the dynamics have
decayed to nothing (slowest pole >= 1 / s); the rest of the gap is skipped."""


@dataclass
class SimulatedBlock:
    """The outcome of one simulated sample range."""

    n0: int
    true_force_N: np.ndarray
    """Endpoint force the participant produces (no sensor terms)."""
    force_N: np.ndarray
    """The chain's reading along the extension axis."""
    wrench: np.ndarray
    over_range: bool
    sE: float
    """Co-activation used for the dynamics of this block."""
    cumulative_stim_s: float
    """Cumulative stimulation at the end of the block."""


class ParticipantSimulator:
    """Stateful simulation of one participant at ``fs_Hz``."""

    _op: OperatingPoint
    """The co-activation's parameters in use (set at construction)."""

    def __init__(self, participant: VirtualParticipant, fs_Hz: float = 2000.0):
        self.p = participant
        self.fs_Hz = float(fs_Hz)
        self.cursor = 0
        """Next absolute sample index to simulate."""
        self.stim_samples = 0
        """Samples with current on either channel since the session began."""
        self._op: OperatingPoint  # set by _set_op at the end of __init__
        self._s_raw: float | None = None
        self._ops: dict[float, OperatingPoint] = {}
        # the participant's effects composed at the chain's slots (nmsid.protocols.effects):
        # intensity maps (in participant.muscle_forces_N) -> lag -> one path per muscle when
        # an effect acts on the flexor's dynamics -> delay -> gain -> additive baseline
        self._chain = chain_of(participant.effects)
        self._lag_s = self._chain.lag_s
        self._two_paths = self._chain.two_paths
        n_paths = 2 if self._two_paths else 1
        # one filter per muscle path: activation lag (if any) and dynamics in cascade
        self._dyn = [StatefulFilter(3 if self._lag_s > 0 else 2) for _ in range(n_paths)]
        L_s = self._chain.delay_s
        self._delay = DelayLine(L_s * self.fs_Hz) if L_s > 0 else None
        self._has_gain = self._chain.has_gain
        self._wander = self._chain.additive(participant.seed)
        self.sensor = SensorState(participant.sensor, participant.seed, self.fs_Hz)
        self._set_op(self._sense_default())

    # -- co-activation -------------------------------------------------------------------
    def _sense_default(self) -> float:
        return self.p.sE_range[0]

    def _operating_point(self, s: float) -> OperatingPoint:
        op = self._ops.get(s)
        if op is None:
            op = self.p.operating_point(s)
            self._ops[s] = op
        return op

    def _set_op(self, s: float) -> None:
        op = self._operating_point(s)
        self._op = op
        b, a = dynamics_zoh(op.wn_rad_s, op.zeta, self._lag_s, self.fs_Hz)
        self._dyn[0].set_coefficients(b, a)
        if self._two_paths:
            rw, rz = self._chain.flexor_ratios
            b2, a2 = dynamics_zoh(op.wn_rad_s * rw, op.zeta * rz, self._lag_s, self.fs_Hz)
            self._dyn[1].set_coefficients(b2, a2)

    def _sense(self, I_e: np.ndarray, I_f: np.ndarray, on: np.ndarray) -> None:
        idx = np.flatnonzero(on)
        if idx.size == 0:
            return
        if idx.size > 7:  # a few samples spread over the chunk suffice for the median
            idx = idx[::(idx.size + 6) // 7]
        cal = self.p.calibration
        u_e = (I_e[idx] - cal.Iemin_mA) * (1.0 / (cal.Iemax_mA - cal.Iemin_mA))
        u_f = (I_f[idx] - cal.Ifmin_mA) * (1.0 / (cal.Ifmax_mA - cal.Ifmin_mA))
        s_raw = float(np.median(np.maximum(u_e, 0.0) + np.maximum(u_f, 0.0)))
        if self._s_raw is not None and abs(s_raw - self._s_raw) < SE_RESOLUTION:
            return
        s = sensed_sE(s_raw)
        self._s_raw = s_raw
        if s != self._op.sE:
            self._set_op(s)

    @property
    def operating_point(self) -> OperatingPoint:
        return self._op

    # -- simulation ----------------------------------------------------------------------
    def simulate(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray, *,
                 spike_N: np.ndarray | None = None) -> SimulatedBlock:
        """Simulate the next ``len(I_ext_mA)`` samples from the cursor.

        Parameters
        ----------
        I_ext_mA, I_flex_mA : ndarray
            Carrier amplitudes really delivered, one per sample (0 when output is off).
        spike_N : ndarray, optional
            Added to the reading (fault injection: an electrical spike on the chain).
        """
        I_e = np.asarray(I_ext_mA, dtype=float)
        I_f = np.asarray(I_flex_mA, dtype=float)
        n = I_e.size
        n0 = self.cursor
        on = (I_e > 0) | (I_f > 0)
        self._sense(I_e, I_f, on)
        op = self._op
        f_e, f_f = self.p.muscle_forces_N(I_e, I_f, op)
        if not self._two_paths:
            y = self._dyn[0](f_e - f_f)
        else:
            y = self._dyn[0](f_e) - self._dyn[1](f_f)
        if self._delay is not None:
            y = self._delay(y)
        c_prev = self.stim_samples
        if n:
            c_samples = c_prev + np.cumsum(on)
            self.stim_samples = int(c_samples[-1])
        if self._has_gain and n:
            y = y * self._chain.gain(c_samples / self.fs_Hz)
        if self._wander is not None:
            y = y + self._wander((n0 + np.arange(n)) / self.fs_Hz)
        force, wrench, over = self.sensor.measure(y if spike_N is None else y + spike_N, n0)
        self.cursor = n0 + n
        return SimulatedBlock(n0, y, force, wrench, over, op.sE,
                              self.stim_samples / self.fs_Hz)

    def advance_quiet(self, n: int) -> None:
        """Let ``n`` samples pass without stimulation (a rest), without measuring them."""
        if n <= 0:
            return
        todo = min(n, QUIET_SKIP_SAMPLES)
        z = np.zeros(min(todo, 4000))
        done = 0
        while done < todo:
            m = min(z.size, todo - done)
            self._filter_only(z[:m])
            done += m
        self.cursor += n - todo
        if n > todo:
            for f in self._dyn:
                f.reset()

    def _filter_only(self, d: np.ndarray) -> None:
        if not self._two_paths:
            y = self._dyn[0](d)
        else:
            y = self._dyn[0](d) - self._dyn[1](d)
        if self._delay is not None:
            self._delay(y)
        self.cursor += d.size

    def snapshot(self) -> tuple:
        """The simulator's whole state, to continue exactly from here later."""
        return (self.cursor, self.stim_samples, self._op, self._s_raw,
                [f.state() for f in self._dyn],
                None if self._delay is None else self._delay.state())

    def restore(self, snap: tuple) -> None:
        """Return to a :meth:`snapshot` (the sensor noise depends only on sample indices)."""
        self.cursor, self.stim_samples, self._op, self._s_raw, filt, delay = snap
        for f, st in zip(self._dyn, filt, strict=True):
            f.restore(st)
        if self._delay is not None:
            self._delay.restore(delay)

    @property
    def cumulative_stim_s(self) -> float:
        return self.stim_samples / self.fs_Hz


def simulator_for(participant, fs_Hz: float):
    """The stateful simulator of a participant: :class:`ParticipantSimulator` for the
    template participant, else the one the participant makes (``make_simulator(fs_Hz)``,
    e.g. :class:`nmsid.sim_backends.msk_participant.MskParticipant`)."""
    if isinstance(participant, VirtualParticipant):
        return ParticipantSimulator(participant, fs_Hz)
    return participant.make_simulator(fs_Hz)
