"""Charge and current figures of a prepared STG download (``nmsid stimulation``, session file).

Computed from exactly the samples the driver downloads
(:class:`~nmsid.drivers.stg_download.PreparedDownload`), expanded on the device's output grid:

* ``peak_current_mA``: largest ``|I|``;
* ``max_charge_per_phase_nC``: largest charge of one phase (a run of samples of one sign
  within a carrier period; cathodic and anodic phases are mirror images by construction);
* ``worst_net_charge_per_period_nC``: largest ``|sum I dt|`` over one carrier period;
* ``net_charge_per_trial_uC``: ``sum I dt`` over the whole trial;
* ``points``: (value, duration) points sent, ``memory_bytes`` at
  :data:`~nmsid.drivers.stg_download.BYTES_PER_POINT`, the channel's capacity and whether the
  trial fits it.
"""

from __future__ import annotations

import numpy as np

from nmsid.drivers.stg_download import BYTES_PER_POINT, PreparedDownload
from nmsid.drivers.stg_waveform import NA_PER_MA, RenderedChannel, period_net_nA_ticks

SUMMARY_FORMAT = "nmsid-stimulation-1"


def channel_summary(channel: RenderedChannel, name: str, number: int,
                    capacity_bytes: int | None) -> dict:
    """The figures of one channel (see the module docstring); plain JSON types."""
    x = channel.expand()
    tick_s = channel.tick_us * 1e-6
    P = max(channel.period_ticks, 1)
    n = len(x) // P
    periods = x[:n * P].reshape(n, P) if n else np.zeros((0, P), dtype=np.int64)
    pos = np.where(periods > 0, periods, 0).sum(axis=1)
    neg = np.where(periods < 0, -periods, 0).sum(axis=1)
    phase_nC = float(max(pos.max(initial=0), neg.max(initial=0)) * tick_s)
    net = period_net_nA_ticks(x, P)
    nbytes = channel.n_points * BYTES_PER_POINT
    return {
        "name": name, "channel": int(number),
        "peak_current_mA": float(np.abs(x).max(initial=0) / NA_PER_MA),
        "max_charge_per_phase_nC": phase_nC,
        "worst_net_charge_per_period_nC": float(np.abs(net).max(initial=0) * tick_s),
        "net_charge_per_trial_uC": float(x.sum() * tick_s / 1000.0),
        "samples": int(len(x)), "samples_per_period": int(channel.period_ticks),
        "points": int(channel.n_points), "memory_bytes": int(nbytes),
        "capacity_bytes": None if capacity_bytes is None else int(capacity_bytes),
        "fits_channel_memory": None if capacity_bytes is None else bool(
            nbytes <= capacity_bytes),
    }


def download_summary(prepared: PreparedDownload,
                     capacity_bytes: dict[int, int] | None = None) -> dict:
    """Per-channel figures of one trial's download, plus its timing (plain JSON types)."""
    capacity_bytes = capacity_bytes or {}
    channels = {prepared.names[ch]: channel_summary(r, prepared.names[ch], ch,
                                                    capacity_bytes.get(ch))
                for ch, r in prepared.channels.items()}
    return {"format": SUMMARY_FORMAT, "output_rate_Hz": float(prepared.output_rate_Hz),
            "duration_s": float(prepared.duration_s), "sync_out": int(prepared.sync_out),
            "channels": channels}
