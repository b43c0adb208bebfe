"""The STG's download memory: per-channel and sync capacities, checked before sending.

``SetCapacity(channelCapacity[], syncCapacity[])`` / ``GetCapacity(out, out)`` (the
``mcs.stg.sdk`` MATLAB wrapper of McsUsbNet, ``cstg200x_download_basic.m``): "For each
segment, the memory layout has to be defined. Each channel and sync output can be given an
individual amount of memory space as needed by the application. Make sure the sum does not
exceed the memory"; a download larger than its channel's capacity fails inside the vendor
library, half-way through the download. McsUsbNet 5.3.15's metadata has no download-mode
``GetCapacity``: then only the total (``GetTotalMemory``) can be checked.
"""

from __future__ import annotations

import logging

from nmsid.drivers.errors import DeviceMemoryError
from nmsid.drivers.stg_download import BYTES_PER_POINT, PreparedDownload

log = logging.getLogger(__name__)


def needs(prepared: PreparedDownload, n_channels: int, n_sync: int,
          sync_out: int) -> tuple[list[int], list[int]]:
    """Bytes each channel and each sync output needs for ``prepared`` (0-based lists)."""
    need_ch = [0] * n_channels
    for ch, nbytes in prepared.channel_bytes().items():
        need_ch[ch - 1] = nbytes
    need_sync = [0] * n_sync
    need_sync[sync_out - 1] = prepared.sync_bytes
    return need_ch, need_sync


def fits(need: list[int], capacity: list[int]) -> bool:
    return all(n <= (capacity[i] if i < len(capacity) else 0) for i, n in enumerate(need))


def read_capacity(dev) -> tuple[list[int], list[int]] | None:
    """``GetCapacity(out UInt32[] channel, out UInt32[] sync)`` or None if absent."""
    try:  # pythonnet: out parameters are placeholders and come back in the tuple
        result = dev.GetCapacity(None, None)
    except AttributeError:  # McsUsbNet 5.3.15 has no download-mode GetCapacity
        return None
    if isinstance(result, tuple) and len(result) >= 2:
        return [int(x) for x in result[-2]], [int(x) for x in result[-1]]
    return None


def fit_memory(dev, api, prepared: PreparedDownload, *, n_channels: int, n_sync: int,
               sync_out: int, total_bytes: int) -> dict[int, int]:
    """Check, and if needed lay out, the memory before anything is sent.

    Returns
    -------
    dict
        Capacity per output channel (numbered from 1), empty if the device cannot say.

    Raises
    ------
    DeviceMemoryError
        The trial does not fit the whole memory, or the layout did not take.
    """
    need_ch, need_sync = needs(prepared, n_channels, n_sync, sync_out)
    total_need = sum(need_ch) + sum(need_sync)
    if total_need > total_bytes:
        raise DeviceMemoryError(
            f"trial needs about {total_need / 1e6:.1f} MB of STG memory (estimated "
            f"{BYTES_PER_POINT} B/point), the device has {total_bytes / 1e6:.1f} MB; "
            "shorten the trial; nothing was sent")
    caps = read_capacity(dev)
    if caps is None:
        return {}
    if fits(need_ch, caps[0]) and fits(need_sync, caps[1]):
        return {ch + 1: c for ch, c in enumerate(caps[0])}
    share = (total_bytes - total_need) // (len(need_ch) + len(need_sync))
    new_ch = [need + share for need in need_ch]
    new_sync = [need + share for need in need_sync]
    dev.SetCapacity(api.Array[api.UInt32](new_ch), api.Array[api.UInt32](new_sync))
    log.info("STG memory laid out per channel %s and sync %s bytes (SetCapacity)", new_ch,
             new_sync)
    caps = read_capacity(dev)
    if caps is not None and not (fits(need_ch, caps[0]) and fits(need_sync, caps[1])):
        raise DeviceMemoryError(
            f"STG memory layout did not take: channels need {need_ch} bytes, sync "
            f"{need_sync}; the device reports capacities {caps[0]} and {caps[1]}; nothing "
            "was sent")
    return {} if caps is None else {ch + 1: c for ch, c in enumerate(caps[0])}
