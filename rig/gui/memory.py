"""Memory held across sessions in one window: give the C heap's freed pages back.

Measured (``bench/bench_gui.py``, eight sessions in one window): the Python objects of a
finished session are all freed (``tracemalloc`` flat at 28 MB), yet the process grew by
about 30 MB per session of 8 x 15 s trials. That is glibc's allocator keeping freed
blocks of the engine's and the analysis workers' threads (one arena per thread, and a
large-block threshold that rises after the first large free) instead of returning them to
the system. ``malloc_trim(0)`` after a session returns them: the growth stops.

OS-dependent through :mod:`nmsid.protocols.os_platform`: on Windows the process heap
decommits freed pages itself and there is no ``malloc_trim``; on other C libraries
(macOS, musl) the call is absent and nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging

from nmsid.protocols.os_platform import is_windows

log = logging.getLogger(__name__)


def release_freed_memory() -> bool:
    """Collect garbage, then return the C heap's free pages to the system (glibc only).

    Returns
    -------
    bool
        True if the C library was asked to return memory.
    """
    gc.collect()
    if is_windows():
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc: nothing to ask
        return False
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    trim(0)
    return True
