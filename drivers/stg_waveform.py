"""Render a trial's envelope into the STG's download data: carrier, quantisation, checks.

Pure functions, no device: :func:`render_channel` turns one channel's carrier-amplitude
envelope into the sample values (nA, int32) and durations (us) that McsUsbNet's
``PrepareAndSendData`` takes, and :func:`check_rendered` is the last check against the
ceiling before anything is sent.

Rendering: the carrier is ``sin(2 pi f_c t)`` starting at phase 0 at onset; the envelope
is held (zero-order hold) over each of its samples, which keeps every rendered amplitude
at or below an envelope sample, so the ceiling proven by
:class:`~nmsid.drivers.interfaces.CheckedWaveform` still holds. Values are quantised to the
device's current resolution *toward zero* (rounding could step one resolution above the
ceiling). Consecutive equal values are merged into one longer step (the download format is
value + duration), and a final 0 nA step is appended because the STG keeps the last value
of a channel until the longest channel ends.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmsid.drivers.interfaces import CurrentLimitError

NA_PER_MA = 1_000_000


@dataclass(frozen=True, eq=False)
class RenderedChannel:
    """One channel's download data: ``values_nA[i]`` is held for ``durations_us[i]``."""

    values_nA: np.ndarray
    durations_us: np.ndarray
    tick_us: int

    @property
    def n_points(self) -> int:
        return len(self.values_nA)

    def expand(self) -> np.ndarray:
        """Sample-by-sample values on the device's output grid (for tests and checks)."""
        return np.repeat(self.values_nA, (self.durations_us // self.tick_us).astype(np.int64))


def output_tick_us(output_rate_Hz: float) -> int:
    """Duration of one output sample in whole microseconds (the STG's unit)."""
    tick = 1e6 / output_rate_Hz
    if abs(tick - round(tick)) > 1e-9 or round(tick) < 1:
        raise ValueError(f"output rate {output_rate_Hz} Hz is not a whole number of "
                         "microseconds per sample")
    return int(round(tick))


def render_samples(envelope_mA: np.ndarray, fs_Hz: float, carrier_Hz: float,
                   output_rate_Hz: float, resolution_nA: float) -> np.ndarray:
    """Carrier x held envelope on the output grid, quantised toward zero, in nA (int64)."""
    env = np.asarray(envelope_mA, dtype=np.float64)
    n_out = int(round(len(env) / fs_Hz * output_rate_Hz))
    if n_out == 0:
        return np.zeros(0, dtype=np.int64)
    j = np.arange(n_out, dtype=np.float64)
    k = np.minimum(np.floor(j * (fs_Hz / output_rate_Hz) + 1e-9).astype(np.int64),
                   len(env) - 1)
    i_nA = env[k] * NA_PER_MA * np.sin(2.0 * np.pi * carrier_Hz * j / output_rate_Hz)
    if resolution_nA <= 0:
        raise ValueError(f"device current resolution must be > 0 nA, got {resolution_nA}")
    steps = np.trunc(i_nA / resolution_nA)
    return (steps * resolution_nA).astype(np.int64)


def compress(samples_nA: np.ndarray, tick_us: int) -> RenderedChannel:
    """Merge runs of equal values and append the final 0 nA step."""
    samples = np.append(np.asarray(samples_nA, dtype=np.int64), 0)
    change = np.flatnonzero(np.diff(samples)) + 1
    starts = np.concatenate(([0], change))
    lengths = np.diff(np.concatenate((starts, [len(samples)])))
    return RenderedChannel(values_nA=samples[starts].astype(np.int32),
                           durations_us=(lengths * tick_us).astype(np.uint64),
                           tick_us=tick_us)


def render_channel(envelope_mA, fs_Hz: float, carrier_Hz: float, output_rate_Hz: float,
                   resolution_nA: float) -> RenderedChannel:
    """Envelope (mA) -> download data of one channel (see module docstring)."""
    tick = output_tick_us(output_rate_Hz)
    return compress(render_samples(envelope_mA, fs_Hz, carrier_Hz, output_rate_Hz,
                                   resolution_nA), tick)


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
