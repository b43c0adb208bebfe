"""The GUI's QObjects do not shadow QObject's own methods with their attributes.

``EngineSignals.event`` (a Signal) hid ``QObject.event()``, the handler Qt calls for every
event, and ``SessionController.thread`` (the engine's worker) hid ``QObject.thread()``;
they were renamed ``event_logged`` (now a mailbox behind ``notified``) and ``worker``.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6")

from PySide6.QtCore import QObject  # noqa: E402

from nmsid.rig.gui.live_buffer import LiveBuffer  # noqa: E402
from nmsid.rig.gui.observer import EngineSignals  # noqa: E402
from nmsid.rig.gui.session_controller import SessionController  # noqa: E402

#: PySide puts these of QObject's own into each subclass's namespace (not shadowing)
QT_COPIES = {"staticMetaObject", "destroyed", "objectNameChanged"}
QOBJECT_NAMES = {n for n in dir(QObject) if not n.startswith("__")} - QT_COPIES


def test_engine_signals_do_not_shadow_qobject_methods():
    own = {n for n in vars(EngineSignals) if not n.startswith("__")}
    assert "notified" in own
    assert not own & QOBJECT_NAMES


def test_the_session_controller_does_not_shadow_qobject_methods():
    controller = SessionController(EngineSignals(), LiveBuffer())
    own = {n for n in vars(controller) if not n.startswith("_")} \
        | {n for n in vars(SessionController) if not n.startswith("_")}
    assert "worker" in own
    assert not own & QOBJECT_NAMES
    assert callable(controller.thread)   # Qt's own QObject.thread()
