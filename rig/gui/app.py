"""Start the operator GUI: the QApplication, the window, an optional scripted run."""

from __future__ import annotations

import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyqtgraph as pg
from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QApplication

from nmsid.rig.errors import DisplayUnavailable, RequestError
from nmsid.rig.gui.main_window import MainWindow
from nmsid.rig.gui.script import ScriptRunner, load_script
from nmsid.rig.session_signals import SessionSignals

#: How often the Qt loop hands control to Python so a signal handler can run, ms.
SIGNAL_POLL_MS = 100

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GuiOptions:
    """What ``nmsid gui`` was asked to do (see ``rig.cli_gui``)."""

    backend: str = "sim"
    config: Path | None = None
    hw_config: Path | None = None
    participant: str | None = None
    out: Path | None = None
    seed: int | None = None
    realtime: bool = True
    joint: str | None = None
    participant_model: str | None = None
    script: str | None = None
    screenshot: Path | None = None


def _application():
    app = QApplication.instance()
    if app is None:
        app = QApplication(sys.argv[:1])
        app.setApplicationName("nmsid")
    return app


def build_window(options: GuiOptions, **window_kwargs):
    """Create the main window with the setup form filled from ``options``."""
    pg.setConfigOptions(antialias=False, foreground="k")
    window = MainWindow(**window_kwargs)
    values: dict[str, Any] = {"backend": options.backend, "realtime": options.realtime}
    if options.participant:
        values["participant"] = options.participant
    if options.config:
        values["config"] = options.config
    if options.hw_config:
        values["hw_config"] = options.hw_config
    if options.out:
        values["output"] = options.out
    if options.seed is not None:
        values["seed"] = options.seed
    if options.joint:
        values["joint"] = options.joint
    if options.participant_model:
        values["participant_model"] = options.participant_model
    window.setup_panel.set_values(**values)
    return window


def run_gui(options: GuiOptions) -> int:
    """Show the window and run the Qt event loop; returns the exit code.

    With ``options.script`` the script runs once the window is shown; with
    ``options.screenshot`` the window is saved as PNG after the script and the
    application quits. Exit code 1 if the script failed.
    """
    if options.screenshot is not None and options.script is None:
        raise RequestError("--screenshot saves the window after a scripted run; give "
                         "--script FILE (or --script demo) too")
    if options.backend not in ("sim", "hw"):
        raise RequestError(f"--backend {options.backend!r} is not valid: use sim or hw")
    steps = load_script(options.script) if options.script else None
    if os.environ.get("QT_QPA_PLATFORM") is None and not os.environ.get("DISPLAY") \
            and not os.environ.get("WAYLAND_DISPLAY") and sys.platform.startswith("linux"):
        if steps is None:
            raise DisplayUnavailable("no display found (DISPLAY and WAYLAND_DISPLAY are unset): "
                          "nmsid gui needs a screen; to run it without one give --script "
                          "(and --screenshot), or use `nmsid run` for a headless session")
        log.warning("no display found; running the script on the offscreen Qt platform")
        os.environ["QT_QPA_PLATFORM"] = "offscreen"
    app = _application()
    window = build_window(options)
    window.show()
    result: dict[str, int] = {"code": 0}
    if steps is not None:
        runner = ScriptRunner(window, steps, screenshot=options.screenshot, parent=window)

        def done(ok: bool, message: str) -> None:
            if result.get("signal"):  # the signal's own line says how it ended
                return
            print(("nmsid gui: " if ok else "nmsid gui: error: ") + message,
                  file=sys.stdout if ok else sys.stderr)
            result["code"] = 0 if ok else (runner.exit_code or 1)
            if options.screenshot is not None or runner.quit_requested or not ok \
                    and os.environ.get("QT_QPA_PLATFORM") == "offscreen":
                window.close()
                app.quit()
        runner.finished.connect(done)
        runner.start()

    def on_signal(signum, reason):  # main (Qt) thread, between Python bytecodes
        # output to zero first, then end the session; the window closes on the next turn
        # of the event loop (closing joins the engine thread, which writes the end record)
        result["signal"] = signum
        if steps is not None:
            runner.interrupted = True
        controller = window.controller
        controller.estop(reason)
        if controller.engine is not None:
            controller.engine.commands.abort(reason)
        QTimer.singleShot(0, lambda: (window.close(), app.quit()))

    with SessionSignals(on_signal) as signals:
        # Qt's loop runs in C++: a short timer gives the interpreter control, so the
        # handler runs within SIGNAL_POLL_MS of the signal
        wake = QTimer(window)
        wake.timeout.connect(lambda: None)
        wake.start(SIGNAL_POLL_MS)
        app.exec()
        wake.stop()
        session = window.controller.session_path if window.controller else None
        _dispose(app, window)
    signal_code = signals.exit_code  # None unless a signal was received
    if signal_code is not None:
        print(signals.stderr_line(session), file=sys.stderr, flush=True)
        return signal_code
    return result["code"]


def _dispose(app, window) -> None:
    """Destroy the window's Qt objects while the QApplication still exists (otherwise
    Python's finalisation may delete them in an order that crashes Qt at exit)."""
    import gc
    window.close()
    window.deleteLater()
    app.processEvents()
    app.sendPostedEvents(None, 0)
    del window
    gc.collect()
