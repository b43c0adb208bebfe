"""The STG's download memory, checked through the members McsUsbNet documents for it.

Sources (McsUsbNet 5.3.15 XML documentation and type metadata, ``shared/vendor/
McsUsbNet-5.3.15/``):

* ``CStg200xDownloadNet.SegmentSelect(UInt32 segment, Stg200xSegmentFlagsEnumNet
  segmentflags)``: "Switchs segment"; ``SegmentDefine``: "On reset, the STG has one segment
  containing all available memory". The driver works in segment 0 with flags ``None``.
* ``CStg200xBasicNet.GetAvailableMemory()``: "the amount of memory available in the
  currently selected segment of the STG ... in bytes"; ``GetTotalMemory()``: "(all
  segments)".
* ``CStg200xDownloadBasicNet.GetMemoryUsageDAC(UInt32 channel)`` /
  ``GetMemoryUsageSyncout(UInt32 channel)``: "the memory usage of the current segment and
  selected analog DAC (syncout) channel".

``GetCapacity`` / ``SetCapacity`` are members of ``CStg200xStreamingNet`` only (the vendor
README; the real assembly's metadata): they are never called in download mode.

The download format's size per point is not documented: the check before sending uses the
conservative :data:`~nmsid.drivers.stg_download.BYTES_PER_POINT`, and the real use is read
back after the download and recorded (``stimulation_json`` ``memory_used_bytes``).
"""

from __future__ import annotations

import logging

from nmsid.drivers.errors import DeviceMemoryError
from nmsid.drivers.stg_download import BYTES_PER_POINT, PreparedDownload

log = logging.getLogger(__name__)

SEGMENT = 0
"""The one segment the driver uses (``DisableMultiFileMode`` at connect)."""


def needs(prepared: PreparedDownload, n_channels: int, n_sync: int,
          sync_out: int) -> tuple[list[int], list[int]]:
    """Bytes each channel and each sync output needs for ``prepared`` (0-based lists)."""
    need_ch = [0] * n_channels
    for ch, nbytes in prepared.channel_bytes().items():
        need_ch[ch - 1] = nbytes
    need_sync = [0] * n_sync
    need_sync[sync_out - 1] = prepared.sync_bytes
    return need_ch, need_sync


def fit_memory(dev, api, prepared: PreparedDownload, *, n_channels: int, n_sync: int,
               sync_out: int, total_bytes: int) -> dict[int, int]:
    """Select segment 0 and check the trial fits its available memory, before sending.

    Returns
    -------
    dict
        ``{0: available bytes of the segment}`` (recorded with the download).

    Raises
    ------
    DeviceMemoryError
        The trial does not fit; nothing was sent.
    """
    need_ch, need_sync = needs(prepared, n_channels, n_sync, sync_out)
    total_need = sum(need_ch) + sum(need_sync)
    no_flags = getattr(api.Stg200xSegmentFlagsEnumNet, "None")  # a Python keyword
    dev.SegmentSelect(api.UInt32(SEGMENT), no_flags)
    available = int(dev.GetAvailableMemory())
    if total_need > available:
        raise DeviceMemoryError(
            f"trial needs about {total_need / 1e6:.2f} MB of STG memory (estimated "
            f"{BYTES_PER_POINT} B/point), segment {SEGMENT} has {available / 1e6:.2f} MB "
            f"available (GetAvailableMemory; {total_bytes / 1e6:.1f} MB in all segments); "
            "shorten the trial; nothing was sent")
    return {SEGMENT: available}


def read_usage(dev, api, prepared: PreparedDownload) -> dict[str, int]:
    """Memory the device reports in use after a download (``GetMemoryUsageDAC`` per output
    channel, ``GetMemoryUsageSyncout`` for the sync output), keyed ``"channel N"`` /
    ``"sync N"`` (numbered from 1). Informative: a failed query is logged, not raised."""
    usage: dict[str, int] = {}
    try:
        for ch, rendered in prepared.channels.items():
            used = int(dev.GetMemoryUsageDAC(api.UInt32(ch - 1)))
            usage[f"channel {ch}"] = used
            if rendered.n_points and used > rendered.n_points * BYTES_PER_POINT:
                log.warning("STG channel %d uses %d B for %d points: more than the %d B/point "
                            "the memory check assumes", ch, used, rendered.n_points,
                            BYTES_PER_POINT)
        usage[f"sync {prepared.sync_out}"] = int(
            dev.GetMemoryUsageSyncout(api.UInt32(prepared.sync_out - 1)))
    except Exception as exc:  # informative only
        log.warning("STG memory usage query failed: %s", exc)
    return usage
