"""Guard against a reference-count bug of some PySide6 builds on Python 3.11.

Observed with PySide6 6.12.0 on CPython 3.11: ``SignalInstance.emit()`` returns ``True``
and ``QObject.property()`` of an unset property returns ``None`` without taking a
reference, so every emit and such lookup (ours and pyqtgraph's, many per frame) drops one
reference to ``True`` / ``None``; after some seconds of plotting the interpreter aborts
with "Fatal Python error: bool_dealloc" or "none_dealloc". On Python >= 3.12 these
singletons are immortal and the bug is harmless.

:func:`protect_against_emit_refcount_bug` measures the leak once with a private object
and, only if it is there, adds a large reserve to the reference counts of ``True``,
``False`` and ``None`` (the interpreter's static singletons, which are never deallocated;
this is what Python 3.12 does for them by design). It runs when ``rig.gui.observer`` or
``rig.gui.main_window`` is imported. The real fix is a PySide6 without the bug.
"""

from __future__ import annotations

import ctypes
import logging
import sys

log = logging.getLogger(__name__)

#: References added to True/False/None when the leak is present (2**40: about 35 years of
#: emits at 1000 per second).
RESERVE = 2 ** 40
_PROBE_EMITS = 64
_checked: bool | None = None


def emit_leaks_bool_reference() -> bool:
    """True if ``Signal.emit`` drops a reference to ``True`` on this PySide6 build."""
    from PySide6.QtCore import QObject, Signal

    class _Probe(QObject):
        sig = Signal()

    probe = _Probe()
    before = sys.getrefcount(True)
    for _ in range(_PROBE_EMITS):
        probe.sig.emit()
    lost = before - sys.getrefcount(True)
    return lost >= _PROBE_EMITS // 2


def property_leaks_none_reference() -> bool:
    """True if ``QObject.property`` of an unset name drops a reference to ``None``."""
    from PySide6.QtCore import QObject

    probe = QObject()
    before = sys.getrefcount(None)
    for _ in range(_PROBE_EMITS):
        probe.property("nmsid_unset")
    lost = before - sys.getrefcount(None)
    return lost >= _PROBE_EMITS // 2


def protect_against_emit_refcount_bug() -> bool:
    """Apply the reserve if needed (once per process); return whether it was applied."""
    global _checked
    if _checked is not None:
        return _checked
    _checked = False
    if sys.version_info >= (3, 12) or sys.implementation.name != "cpython":
        return False
    if emit_leaks_bool_reference() or property_leaks_none_reference():
        for obj in (True, False, None):
            ctypes.c_ssize_t.from_address(id(obj)).value += RESERVE
        import PySide6
        log.warning("PySide6 %s drops references to True/None (Signal.emit, "
                    "QObject.property) on Python "
                    "%d.%d; applied a reference reserve so the GUI cannot crash. Use "
                    "another PySide6 version to remove this workaround.",
                    PySide6.__version__, *sys.version_info[:2])
        _checked = True
    return _checked


protect_against_emit_refcount_bug()
