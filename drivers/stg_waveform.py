"""Render a trial's envelope into the STG's download data: carrier, quantisation, checks.

Pure functions, no device: :func:`render_channel` turns one channel's carrier-amplitude
envelope into the sample values (nA, int32) and durations (us) that McsUsbNet's
``PrepareAndSendData`` takes; :func:`check_rendered` (ceiling) and
:func:`check_charge_balance` (zero net charge per carrier period) are the last checks
before anything is sent, run on exactly the arrays that are sent.

Charge balance by construction
------------------------------
The carrier is ``sin(2 pi f_c t)`` starting at phase 0 at onset, sampled at the output
rate. A carrier period must be a whole number ``P`` of output samples (otherwise refused:
:func:`samples_per_period`). The envelope is held constant over each *whole carrier
period*: the amplitude of period ``k`` is the mean of the (zero-order held) envelope over
that period, never above the largest envelope sample it covers, so the ceiling proven by
:class:`~nmsid.drivers.interfaces.CheckedWaveform` still holds. Within a period, the samples of
the first half-wave are quantised to the device's current resolution *toward zero*
(rounding could step one resolution above the ceiling), and the second half-wave is their
exact negative mirror (``q[P - j] = -q[j]``, ``q[0] = 0``, and ``q[P/2] = 0`` for even
``P``), so every period sums to exactly 0 nA x tick: zero net charge per period, for any
amplitude, resolution, output rate and carrier. Output samples after the last whole
period of the trial (if the trial is not a whole number of periods) are 0 nA.

The previous renderer held the 2 kHz envelope for half a carrier period, so the two
phases of one 1 kHz period had different amplitudes (up to 70 nC net per period); see
``bench/bench_stimulation.py``.

Consecutive equal values are merged into one longer step (the download format is value +
duration, McsUsbNet ``PrepareAndSendData``: "durations are given in units of us"), and a
final 0 nA step is appended because the STG keeps the last value of a channel until the
longest channel ends.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmsid.drivers.errors import ChargeBalanceError, StimulatorSettingError
from nmsid.drivers.interfaces import CurrentLimitError

NA_PER_MA = 1_000_000


@dataclass(frozen=True, eq=False)
class RenderedChannel:
    """One channel's download data: ``values_nA[i]`` is held for ``durations_us[i]``.

    ``period_ticks`` is the carrier period in output samples (0 for sync data).
    """

    values_nA: np.ndarray
    durations_us: np.ndarray
    tick_us: int
    period_ticks: int = 0

    @property
    def n_points(self) -> int:
        return len(self.values_nA)

    def expand(self) -> np.ndarray:
        """Sample-by-sample values on the device's output grid (for tests and checks)."""
        return np.repeat(self.values_nA.astype(np.int64),
                         (self.durations_us // self.tick_us).astype(np.int64))


def output_tick_us(output_rate_Hz: float) -> int:
    """Duration of one output sample in whole microseconds (the STG's unit).

    Raises
    ------
    StimulatorSettingError
        If ``1e6 / output_rate_Hz`` is not a whole number of microseconds.
    """
    tick = 1e6 / output_rate_Hz
    if abs(tick - round(tick)) > 1e-9 or round(tick) < 1:
        raise StimulatorSettingError(
            f"output rate {output_rate_Hz:g} Hz is not a whole number of microseconds per "
            "sample; use 50000, 25000, 20000, 10000 ... Hz (1e6 / whole us)")
    return int(round(tick))


def samples_per_period(output_rate_Hz: float, carrier_Hz: float) -> int:
    """Output samples per carrier period (a whole number >= 4: a sine sampled fewer times
    per period is not a usable carrier).

    Raises
    ------
    StimulatorSettingError
        Naming the carrier, the output rate and the carriers that would be valid.
    """
    if not carrier_Hz > 0:
        raise StimulatorSettingError(f"carrier frequency must be > 0 Hz, got {carrier_Hz!r}")
    p = output_rate_Hz / carrier_Hz
    if abs(p - round(p)) > 1e-9 or round(p) < 4:
        raise StimulatorSettingError(
            f"carrier {carrier_Hz:g} Hz is not a whole number of output samples per period "
            f"at the STG output rate {output_rate_Hz:g} Hz ({p:.4g}); a charge-balanced "
            f"carrier needs output_rate / carrier = 4, 5, 6 ... (e.g. "
            f"{output_rate_Hz / 50:g} or {output_rate_Hz / 25:g} Hz)")
    return int(round(p))


def period_amplitudes_mA(envelope_mA, fs_Hz: float, output_rate_Hz: float,
                         period_ticks: int) -> tuple[np.ndarray, int]:
    """Carrier amplitude held over each whole carrier period, and the trial's output length.

    Returns
    -------
    amplitude_mA : ndarray, shape (n_periods,)
        Mean of the held envelope over each whole period, clipped to the largest envelope
        sample the period covers (so never above the ceiling).
    n_out : int
        Output samples of the trial (``round(len(envelope) / fs * output_rate)``).
    """
    env = np.asarray(envelope_mA, dtype=np.float64)
    n_out = int(round(len(env) / fs_Hz * output_rate_Hz))
    n_periods = n_out // period_ticks  # 0 (shorter than a period): empty arrays throughout
    j = np.arange(n_periods * period_ticks, dtype=np.float64)
    k = np.minimum(np.floor(j * (fs_Hz / output_rate_Hz) + 1e-9).astype(np.int64),
                   len(env) - 1)
    held = env[k].reshape(n_periods, period_ticks)
    return np.minimum(held.mean(axis=1), held.max(axis=1)), n_out


def render_samples(envelope_mA, fs_Hz: float, carrier_Hz: float, output_rate_Hz: float,
                   resolution_nA: float) -> np.ndarray:
    """Charge-balanced carrier on the output grid, in nA (int64); see the module docstring."""
    if not resolution_nA > 0:
        raise StimulatorSettingError(
            f"device current resolution must be > 0 nA, got {resolution_nA!r}")
    P = samples_per_period(output_rate_Hz, carrier_Hz)
    amp_mA, n_out = period_amplitudes_mA(envelope_mA, fs_Hz, output_rate_Hz, P)
    out = np.zeros(n_out, dtype=np.int64)
    if amp_mA.size == 0:
        return out
    half = (P - 1) // 2                       # samples strictly inside the first half-wave
    j = np.arange(1, half + 1, dtype=np.float64)
    s = np.sin(2.0 * np.pi * j / P)           # > 0
    steps = np.trunc(amp_mA[:, None] * NA_PER_MA * s[None, :] / resolution_nA)
    q = np.trunc(steps * resolution_nA).astype(np.int64)  # toward zero, whole nA
    period = np.zeros((len(amp_mA), P), dtype=np.int64)
    period[:, 1:half + 1] = q
    period[:, P - half:] = -q[:, ::-1]        # exact mirror: zero sum per period
    out[:period.size] = period.ravel()
    return out


def compress(samples_nA: np.ndarray, tick_us: int, period_ticks: int = 0) -> RenderedChannel:
    """Merge runs of equal values and append the final 0 nA step."""
    samples = np.append(np.asarray(samples_nA, dtype=np.int64), 0)
    change = np.flatnonzero(np.diff(samples)) + 1
    starts = np.concatenate(([0], change))
    lengths = np.diff(np.concatenate((starts, [len(samples)])))
    return RenderedChannel(values_nA=samples[starts].astype(np.int32),
                           durations_us=(lengths * tick_us).astype(np.uint64),
                           tick_us=tick_us, period_ticks=period_ticks)


def render_channel(envelope_mA, fs_Hz: float, carrier_Hz: float, output_rate_Hz: float,
                   resolution_nA: float) -> RenderedChannel:
    """Envelope (mA) -> download data of one channel (see module docstring)."""
    tick = output_tick_us(output_rate_Hz)
    P = samples_per_period(output_rate_Hz, carrier_Hz)
    return compress(render_samples(envelope_mA, fs_Hz, carrier_Hz, output_rate_Hz,
                                   resolution_nA), tick, P)


def check_rendered(channel: RenderedChannel, ceiling_mA: float, name: str) -> None:
    """Refuse data whose peak current exceeds ``ceiling_mA`` (the last check before sending).

    Raises
    ------
    CurrentLimitError
        Naming the channel, the sample, its value and the ceiling.
    """
    values = channel.values_nA.astype(np.int64)
    limit_nA = ceiling_mA * NA_PER_MA
    if values.size and np.abs(values).max() > limit_nA + 1e-6:
        k = int(np.argmax(np.abs(values)))
        raise CurrentLimitError(
            f"{name}: rendered point {k} = {values[k] / NA_PER_MA:.4f} mA exceeds the "
            f"ceiling {ceiling_mA:.4f} mA; nothing was sent to the stimulator")
    if values.size and values[-1] != 0:
        raise CurrentLimitError(f"{name}: rendered data does not end at 0 nA; nothing was "
                                "sent")


def period_net_nA_ticks(samples_nA: np.ndarray, period_ticks: int) -> np.ndarray:
    """Sum of the samples of each whole carrier period (nA x ticks), then the remainder."""
    s = np.asarray(samples_nA, dtype=np.int64)
    n = len(s) // period_ticks
    sums = s[:n * period_ticks].reshape(n, period_ticks).sum(axis=1)
    rest = s[n * period_ticks:]
    return np.append(sums, rest.sum()) if rest.size else sums


def check_charge_balance(channel: RenderedChannel, resolution_nA: float, name: str) -> float:
    """Refuse data with net charge in any carrier period above one resolution step x tick.

    Returns
    -------
    float
        The worst net charge of one period, nC.

    Raises
    ------
    ChargeBalanceError
        Naming the channel, the period, its net charge and the limit.
    """
    if channel.period_ticks < 1:
        raise ChargeBalanceError(f"{name}: no carrier period known; nothing was sent")
    sums = period_net_nA_ticks(channel.expand(), channel.period_ticks)
    tick_s = channel.tick_us * 1e-6
    if sums.size == 0:
        return 0.0
    k = int(np.argmax(np.abs(sums)))
    worst_nC = abs(int(sums[k])) * tick_s  # nA * s = nC
    limit_nC = resolution_nA * tick_s
    if worst_nC > limit_nC + 1e-12:
        raise ChargeBalanceError(
            f"{name}: carrier period {k} carries a net charge of {worst_nC:.3f} nC, above "
            f"the device's resolution step ({limit_nC:.4f} nC = {resolution_nA:g} nA x "
            f"{channel.tick_us} us); nothing was sent to the stimulator")
    return worst_nC
