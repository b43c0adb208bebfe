"""Runs one session's engine in a worker thread and relays operator commands to it.

The controller owns the engine, its devices and the thread that runs ``engine.run()``.
Every operator command (E-stop, re-arm, pause, ...) is a direct call of the engine's
thread-safe command methods; none waits for the engine thread. The engine's notifications
arrive through :class:`~nmsid.rig.gui.observer.QtEngineObserver` as queued Qt signals.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QObject, Qt, Signal

from nmsid.drivers.interfaces import RigDevices
from nmsid.errors import NmsidError
from nmsid.protocols.config import Config, config_from_json, load_config
from nmsid.protocols.session_file import read_session
from nmsid.protocols.user_values import one_line
from nmsid.rig.engine import Engine
from nmsid.rig.gui.live_buffer import LiveBuffer
from nmsid.rig.gui.observer import EngineSignals, Mailbox, QtEngineObserver
from nmsid.rig.gui.setup_panel import Backend, SessionRequest
from nmsid.rig.lsl import finish_recording, start_recording
from nmsid.rig.observer import RunSummary
from nmsid.rig.session_service import (
    PreparedRig,
    RigRequest,
    prepare_rig,
    stored_session,
    with_participant_model,
)

log = logging.getLogger(__name__)

#: ``devices_factory(request, config) -> RigDevices``; tests and the bench pass their own.
DevicesFactory = Callable[[SessionRequest, Config], RigDevices]


def rig_request(request: SessionRequest) -> RigRequest:
    """The session service's request for what the setup panel asked (the recorded rig of a
    resumed session read from its file)."""
    stored, backend = stored_session(request.output_path) if request.resume else ({}, "")
    return RigRequest(backend="sim" if request.backend is Backend.SIM else "hw",
                      session_path=Path(request.output_path), resume=request.resume,
                      hw_config=None if request.hw_config_path is None
                      else Path(request.hw_config_path),
                      sim_seed=None if request.resume else request.seed,
                      realtime=request.realtime, stored=stored, stored_backend=backend)


def default_devices(request: SessionRequest, config: Config) -> RigDevices:
    """Build the rig the request names, as ``nmsid run`` does (the session service)."""
    return prepare_rig(rig_request(request), config).devices


def load_session_config(request: SessionRequest, *, confirm_calibration: bool = True) -> Config:
    """The validated protocol configuration for ``request``.

    A resumed session keeps the configuration stored in its file (the engine uses that
    one; the form's configuration file is not read). Otherwise the GUI always asks the
    operator to confirm the calibration (``calibration.confirm = true``) unless
    ``confirm_calibration`` is False.
    """
    if request.resume:
        try:
            stored = read_session(request.output_path, load_data=False).config_json
        except (ValueError, OSError):
            stored = ""  # damaged file: the engine recovers it from its journal
        if stored:
            return config_from_json(stored, source=f"{request.output_path} (stored "
                                                   "configuration)")
    overrides = {"participant": request.participant, "seed": request.seed,
                 "joint": request.joint}
    cfg = load_config(request.config_path, overrides=overrides)
    # the form always names the participant code (the model's own one unless typed)
    cfg = with_participant_model(cfg, request.participant_model, participant_given=True)
    if confirm_calibration and not cfg.calibration.confirm:
        cfg = cfg.replace(calibration=dataclasses.replace(cfg.calibration, confirm=True))
    return cfg


class _RunRelay(QObject):
    run_ended = Signal(object, object)


class SessionController(QObject):
    """One session: configuration, devices, engine and its worker thread.

    Parameters
    ----------
    signals : EngineSignals
        Where the engine's notifications are emitted (connected by the window).
    buffer : LiveBuffer
        Filled with the running trial's samples.
    devices_factory : callable, optional
        ``(request, config) -> RigDevices``; default :func:`default_devices`.
    engine_factory : callable, optional
        ``(config, devices, path, resume=..., observer=...) -> Engine``; default
        ``rig.engine.Engine``.
    """

    def __init__(self, signals: EngineSignals, buffer: LiveBuffer,
                 devices_factory: DevicesFactory | None = None,
                 engine_factory: Callable | None = None, parent: QObject | None = None):
        super().__init__(parent)
        self.signals = signals
        self.buffer = buffer
        self.devices_factory = devices_factory or default_devices
        self.engine_factory = engine_factory
        self.engine: Engine | None = None
        self.devices: RigDevices | None = None
        self.config: Config | None = None
        self.request: SessionRequest | None = None
        self.observer: QtEngineObserver | None = None
        self.worker: threading.Thread | None = None
        """The thread running ``engine.run()`` (not ``thread``: QObject.thread() is Qt's)."""
        self.summary: RunSummary | None = None
        self.error: BaseException | None = None
        self.mailbox = Mailbox()
        """The engine's notifications (the window takes them in batches)."""
        self._relay = _RunRelay()
        self._relay.run_ended.connect(self.signals.run_ended,
                                      Qt.ConnectionType.QueuedConnection)

    # -- lifecycle --------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self.worker is not None and self.worker.is_alive()

    def start(self, request: SessionRequest, config=None) -> None:
        """Build config, devices and engine, then run the engine in a worker thread.

        Raises
        ------
        ValueError, OSError
            On a bad configuration, an output file that may not be used, or a device
            that cannot be opened (nothing is stimulated in that case).
        """
        if self.running:
            raise RuntimeError("a session is already running in this window")
        self.request = request
        cfg = config if config is not None else load_session_config(request)
        self.config = cfg
        self.buffer.fs_Hz = float(cfg.protocol.fs_Hz)
        self.observer = QtEngineObserver(self.signals, self.buffer, self.mailbox)
        extra: dict = {}
        if self.devices_factory is default_devices:   # the session service, as the CLI
            rig = self.prepare(request, cfg)
            devices, cfg, extra = rig.devices, rig.config, rig.extra_attrs
            self.config = cfg
        else:
            devices = self.devices_factory(request, cfg)
        self.devices = devices
        try:
            if self.engine_factory is not None:
                self.engine = self.engine_factory(cfg, devices,
                                                  request.output_path, resume=request.resume,
                                                  observer=self.observer)
            else:
                self.engine = Engine(cfg, devices, request.output_path,
                                     resume=request.resume, observer=self.observer,
                                     extra_attrs=extra)
        except BaseException:
            devices.close()
            self.devices = None
            raise
        self.summary, self.error = None, None
        self.worker = threading.Thread(target=self._run, name="nmsid-engine", daemon=True)
        self.worker.start()
        log.info("session started: %s -> %s", request.participant, request.output_path)

    @staticmethod
    def prepare(request: SessionRequest, config) -> PreparedRig:
        """Devices, paced configuration and recorded attributes for ``request`` (the
        session service: a resume on another rig is refused in one line)."""
        return prepare_rig(rig_request(request), config)

    def _run(self) -> None:
        summary, error = None, None
        engine, devices = self.engine, self.devices
        try:
            if engine is None or devices is None:
                raise RuntimeError("the session controller's worker started without an "
                                   "engine (start() builds it)")
            recorder = self._start_lsl()
            try:
                summary = engine.run()
            finally:   # the streams recorded go into the file (never raises)
                if recorder is not None and self.request is not None:
                    finish_recording(recorder, Path(self.request.output_path),
                                     self.observer)
        except BaseException as exc:  # reported to the operator; output is already off
            if isinstance(exc, NmsidError):  # a user, device or safety stop: one line
                log.error("engine run ended: %s", one_line(exc))
            else:
                log.exception("engine run ended with an error")
            error = exc
        finally:
            try:
                if devices is not None:
                    devices.close()
            except Exception:  # close() never raises by contract; be sure anyway
                log.exception("closing devices")
        self.summary, self.error = summary, error
        self._relay.run_ended.emit(summary, error)

    def _start_lsl(self):
        """The LSL recorder of the streams the operator ticked (``--lsl-record``), or None;
        a recorder that cannot start is logged and the session runs without it."""
        wanted = list(getattr(self.request, "lsl_record", ()) or ())
        if not wanted:
            return None
        try:
            return start_recording(wanted)
        except NmsidError as exc:   # pylsl missing: the panel offered nothing to record
            log.warning("LSL recording not started: %s", one_line(exc))
            return None

    def shutdown(self, timeout_s: float = 5.0) -> None:
        """E-stop and abort a running session, then wait for its thread (window closing)."""
        if self.engine is not None and self.running:
            self.engine.commands.estop("operator closed the GUI window")
            self.engine.commands.abort()
        if self.worker is not None:
            self.worker.join(timeout_s)

    # -- operator commands (GUI thread; each returns at once) --------------------------
    def estop(self, reason: str = "operator E-stop (GUI)") -> bool:
        """E-stop the running engine (output to zero in this thread, latch; the engine
        writes the trip to the file at its next check). Never raises: if the engine's
        E-stop failed, the stimulator is stopped directly.

        Returns
        -------
        bool
            True if a running engine took the E-stop; False if no session is running (its
            file is closed or there is none: nothing can record it, and nothing latches;
            the stimulator is told to stop anyway if its devices are still open).
        """
        engine = self.engine
        running = engine is not None and self.running
        if engine is not None and running:
            try:
                engine.commands.estop(reason)
                return True
            except Exception:
                log.exception("engine.commands.estop failed; stopping the stimulator directly")
        if self.devices is not None:
            try:
                self.devices.stimulator.stop_now()
            except Exception:
                log.exception("stimulator.stop_now failed")
        return running

    def _call(self, name: str, *args) -> None:
        if self.engine is None:
            raise RuntimeError(f"cannot {name.replace('_', ' ')}: no session is running")
        getattr(self.engine.commands, name)(*args)

    def rearm(self) -> None:
        """Clear the latch only (LabVIEW's "clear latch"): the engine is asked to hold
        (``pause``) before it re-arms, so after the re-arm it waits in ``paused``, output
        off, until :meth:`continue_session` (the engine's own ``rearm`` would go on with
        the next trial at once)."""
        self._call("pause")
        self._call("rearm")

    def continue_session(self) -> None:
        """Go on after a re-arm (or a pause): the next trial starts."""
        self._call("resume")

    def pause(self) -> None:
        self._call("pause")

    def resume(self) -> None:
        self._call("resume")

    def skip_trial(self) -> None:
        self._call("skip_trial")

    def abort(self) -> None:
        self._call("abort")

    def rerun(self, schedule_index: int) -> None:
        self._call("rerun", int(schedule_index))

    def repeat_trial(self, schedule_index: int, reason: str) -> None:
        self._call("repeat_trial", int(schedule_index), str(reason))

    def confirm_calibration(self, calibration) -> None:
        self._call("confirm_calibration", calibration)

    def add_note(self, text: str) -> None:
        self._call("add_note", text)

    # -- queries ----------------------------------------------------------------------
    def state(self):
        return None if self.engine is None else self.engine.state

    def schedule(self) -> list:
        return [] if self.engine is None else list(self.engine.schedule)

    def interlock_status(self) -> dict:
        if self.engine is None:
            return {}
        return dict(self.engine.interlock_status())

    @property
    def session_path(self) -> Path | None:
        return None if self.request is None else Path(self.request.output_path)
