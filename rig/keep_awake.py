"""Keep a Windows PC from sleeping while a session runs (issue 24, 5).

An hour-long session with no keyboard or mouse input would otherwise let Windows' idle
timer put the PC to sleep mid-trial. ``SetThreadExecutionState(ES_CONTINUOUS |
ES_SYSTEM_REQUIRED)`` tells the system the thread needs it awake until the same thread
calls ``SetThreadExecutionState(ES_CONTINUOUS)``; it does not keep the display on
(ES_DISPLAY_REQUIRED is not asked) and does not stop a sleep the user chooses
(learn.microsoft.com/windows/win32/api/winbase/nf-winbase-setthreadexecutionstate). The
state belongs to the calling thread, so :class:`SystemAwake` is entered and left on the
engine's thread. Elsewhere it does nothing (chosen by
:func:`nmsid.protocols.os_platform.is_windows`).
"""

from __future__ import annotations

import ctypes
import logging
from typing import Any, Self

from nmsid.protocols import os_platform

log = logging.getLogger(__name__)

ES_SYSTEM_REQUIRED = 0x00000001
ES_CONTINUOUS = 0x80000000


class SystemAwake:
    """``with SystemAwake(): ...`` keeps the system awake on Windows; a no-op elsewhere.

    Attributes
    ----------
    active : bool
        True while the request is in force.
    """

    def __init__(self) -> None:
        self.active = False
        self._kernel32: Any = None

    def _set(self, flags: int) -> int:
        # EXECUTION_STATE is a DWORD: pass it unsigned (0x80000001 overflows a C int)
        return int(self._kernel32.SetThreadExecutionState(ctypes.c_uint(flags)) or 0)

    def __enter__(self) -> Self:
        if not os_platform.is_windows():
            return self
        try:
            self._kernel32 = os_platform.windows_api("kernel32")
            previous = self._set(ES_CONTINUOUS | ES_SYSTEM_REQUIRED)
        except (OSError, RuntimeError, AttributeError) as exc:
            log.warning("could not ask Windows to stay awake during the session (%s): set "
                        "the power plan's sleep to Never", exc)
            return self
        if previous == 0:  # NULL: the call failed
            log.warning("SetThreadExecutionState failed: Windows may sleep during the "
                        "session; set the power plan's sleep to Never")
            return self
        self.active = True
        return self

    def __exit__(self, *exc: object) -> None:
        if self.active:
            self.active = False
            self._set(ES_CONTINUOUS)  # back to normal: the system may sleep again
