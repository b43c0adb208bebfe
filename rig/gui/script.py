"""Scripted runs: drive the window from a text file as an operator would.

A script is one command per line (``#`` starts a comment; arguments are quoted as in a
shell, but a backslash is an ordinary character, so a Windows path such as
``output=C:\\data\\P07.h5`` is read as typed)::

    start participant=DEMO output=sessions/DEMO.h5   # fill the setup form, press Start
    confirm-calibration                # accept the detected currents (or Iemin_mA=2.5 ...)
    wait-trial 1 running               # schedule index 1 (0-based) is running
    wait-trial-time 0.5                # the running trial is at least 0.5 s in
    estop                              # press E-STOP
    wait tripped                       # engine state
    wait-aborted                       # some trial is recorded as aborted
    rerun                              # the first aborted trial, if any (or: rerun 1)
    rearm                              # clear the latch only (the engine holds)
    continue                           # start the next trial
    end-session                        # end early (the file can be resumed later)
    note "electrode re-taped"
    wait-finished                      # session over and results shown
    tab results                        # show a tab: setup, calibration, live
                                       #   (= identification), results
    screenshot docs/gui-screenshot.png
    quit

Every wait takes an optional last argument, a timeout in s (default 600). The runner
polls from a Qt timer, so the window stays live while a script waits. ``demo`` names a
built-in script (:data:`DEMO_SCRIPT`).
"""

from __future__ import annotations

import enum
import logging
import shlex
import time
from dataclasses import dataclass, field
from pathlib import Path

from PySide6.QtCore import QObject, QTimer, Signal

from nmsid.errors import InputFileMissing, NmsidError, UserError
from nmsid.protocols.config import SEED_MAX
from nmsid.protocols.settings_base import bounded, settings_dataclass, validate_settings
from nmsid.protocols.user_values import one_line

log = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 600.0
POLL_MS = 20


class Command(enum.Enum):
    START = "start"
    CONFIRM_CALIBRATION = "confirm-calibration"
    WAIT = "wait"
    WAIT_TRIAL = "wait-trial"
    WAIT_TRIAL_TIME = "wait-trial-time"
    WAIT_ABORTED = "wait-aborted"
    WAIT_FINISHED = "wait-finished"
    SLEEP = "sleep"
    ESTOP = "estop"
    REARM = "rearm"
    CONTINUE = "continue"
    PAUSE = "pause"
    RESUME = "resume"
    SKIP = "skip"
    RERUN = "rerun"
    END_SESSION = "end-session"
    NOTE = "note"
    TAB = "tab"
    SCREENSHOT = "screenshot"
    QUIT = "quit"


TAB_NAMES = {"setup": 0, "calibration": 1, "live": 2, "identification": 2, "results": 3}
STATES = ("idle", "calibrating", "armed", "stimulating", "resting", "paused", "tripped",
          "finished")

DEMO_SCRIPT = """\
# nmsid gui --script demo: a whole session with an E-stop, re-arm and re-run.
start
confirm-calibration
wait-trial 1 running
wait-trial-time 3.0
estop
wait tripped
sleep 0.5
note "demo: E-stop pressed; participant fine; re-running the aborted trial and re-arming"
rerun
rearm
wait paused
continue
wait-finished
tab live
"""


class ScriptError(UserError):
    """A script line is not understood (names the line) or a wait timed out."""


def script_error(source: str, key: str, value, valid: str) -> ScriptError:
    """The settings layer's factory (``protocols.settings_base``) for script arguments."""
    return ScriptError(f"{source}: {key} = {value!r} is refused: {valid}")


@settings_dataclass(script_error)
class StartArgs:
    """``start key=value ...``: what the setup form takes (all optional).

    Script arguments are words, so these fields are lax: ``seed=3`` is the number 3,
    ``realtime=yes`` is true.
    """

    participant: str | None = None
    backend: str | None = None
    config: str | None = None
    hw_config: str | None = None
    output: str | None = None
    seed: int | None = bounded(None, ge=0, le=SEED_MAX, why=(
        "the session file stores the seed as a 64-bit signed integer"))
    realtime: bool | None = None
    resume: bool = False


@settings_dataclass(script_error)
class CalibrationArgs:
    """``confirm-calibration Iemin_mA=... ...``: currents replacing the detected ones."""

    Iemin_mA: float | None = bounded(None, ge=0.0, le=100.0, why="a current of the rig")
    Iemax_mA: float | None = bounded(None, ge=0.0, le=100.0, why="a current of the rig")
    Ifmin_mA: float | None = bounded(None, ge=0.0, le=100.0, why="a current of the rig")
    Ifmax_mA: float | None = bounded(None, ge=0.0, le=100.0, why="a current of the rig")


_ARGS = {"start": StartArgs, "confirm-calibration": CalibrationArgs}


@dataclass(frozen=True)
class Step:
    command: Command
    args: tuple[str, ...] = ()
    kwargs: dict = field(default_factory=dict)
    line: int = 0
    text: str = ""


def _split_kwargs(words: list[str]) -> tuple[tuple[str, ...], dict[str, str]]:
    args: list[str] = []
    kwargs: dict[str, str] = {}
    for w in words:
        if "=" in w and not w.startswith("="):
            k, v = w.split("=", 1)
            kwargs[k] = v
        else:
            args.append(w)
    return tuple(args), kwargs


def _words(raw: str) -> list[str]:
    """One line's words: quotes and ``#`` comments as in a POSIX shell, backslashes kept
    (``shlex.split`` reads them as escapes: ``C:\\data\\P07.h5`` became ``C:dataP07.h5``)."""
    lex = shlex.shlex(raw, posix=True)
    lex.whitespace_split = True
    lex.escape = ""
    return list(lex)


def parse_script(text: str, source: str = "script") -> list[Step]:
    """Parse a script into steps.

    Raises
    ------
    ScriptError
        Naming the source, the line and what is valid.
    """
    steps = []
    for n, raw in enumerate(text.splitlines(), start=1):
        try:
            words = _words(raw)
        except ValueError as exc:
            raise ScriptError(f"{source}:{n}: cannot parse {raw.strip()!r}: {exc}") from None
        if not words:
            continue
        try:
            cmd = Command(words[0].lower())
        except ValueError:
            raise ScriptError(f"{source}:{n}: unknown command {words[0]!r}; known: "
                              + ", ".join(c.value for c in Command)) from None
        args: tuple[str, ...]
        kwargs: dict[str, str]
        if cmd is Command.NOTE:
            args, kwargs = (" ".join(words[1:]),), {}
        else:
            args, kwargs = _split_kwargs(words[1:])
        _check(cmd, args, kwargs, f"{source}:{n}")
        steps.append(Step(cmd, args, kwargs, n, raw.strip()))
    return steps


def _check(cmd: Command, args, kwargs, where: str) -> None:
    def need(lo, hi):
        if not lo <= len(args) <= hi:
            raise ScriptError(f"{where}: {cmd.value} takes {lo}..{hi} arguments, got "
                              f"{len(args)}")

    def number(text, what):
        try:
            return float(text)
        except ValueError:
            raise ScriptError(f"{where}: {cmd.value}: {what} must be a number, got "
                              f"{text!r}") from None
    if cmd is Command.WAIT:
        need(1, 2)
        if args[0].lower() not in STATES:
            raise ScriptError(f"{where}: wait: unknown state {args[0]!r}; states: "
                              + ", ".join(STATES))
    elif cmd is Command.WAIT_TRIAL:
        need(2, 3)
        number(args[0], "the schedule index")
        if args[1] not in ("pending", "running", "done", "aborted"):
            raise ScriptError(f"{where}: wait-trial: status must be pending, running, done "
                              f"or aborted, got {args[1]!r}")
    elif cmd in (Command.WAIT_TRIAL_TIME, Command.SLEEP):
        need(1, 2)
    elif cmd in (Command.WAIT_FINISHED, Command.WAIT_ABORTED):
        need(0, 1)
    elif cmd is Command.RERUN:
        need(0, 1)
    elif cmd is Command.TAB:
        need(1, 1)
        if args[0] not in TAB_NAMES:
            raise ScriptError(f"{where}: tab: unknown tab {args[0]!r}; tabs: "
                              + ", ".join(TAB_NAMES))
    elif cmd is Command.SCREENSHOT:
        need(1, 1)
    elif cmd is Command.NOTE:
        if not args[0]:
            raise ScriptError(f"{where}: note needs a text")
    elif cmd in (Command.START, Command.CONFIRM_CALIBRATION):
        need(0, 0)
        validate_settings(_ARGS[cmd.value], kwargs, source=f"{where}: {cmd.value}",
                          make_error=script_error)
    else:
        need(0, 0)
    if cmd in (Command.WAIT_TRIAL_TIME, Command.SLEEP, Command.WAIT_FINISHED,
               Command.WAIT_ABORTED, Command.RERUN):
        for a in args:
            number(a, "the number")
    if cmd in (Command.WAIT, Command.WAIT_TRIAL):
        for a in args[1 if cmd is Command.WAIT else 2:]:
            number(a, "the timeout")


def load_script(name_or_path: str) -> list[Step]:
    """A built-in script by name (``demo``) or a script file."""
    if name_or_path == "demo":
        return parse_script(DEMO_SCRIPT, "demo")
    path = Path(name_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputFileMissing(f"{path}: cannot read the GUI script ({exc.strerror}); give a "
                               "script file or 'demo'") from None
    return parse_script(text, str(path))


class ScriptRunner(QObject):
    """Runs steps against a :class:`~nmsid.rig.gui.main_window.MainWindow` from a Qt timer.

    Signals
    -------
    finished(ok: bool, message: str)
        After the last step, a failed step or a timeout.
    """

    finished = Signal(bool, str)

    def __init__(self, window, steps: list[Step], *, screenshot: str | Path | None = None,
                 parent: QObject | None = None):
        super().__init__(parent)
        self.window = window
        self.steps = list(steps)
        self.screenshot = screenshot
        self.pos = 0
        self.done = False
        self.ok: bool | None = None
        self.exit_code = 0
        """How ``nmsid gui --script`` ends (as the README's exit statuses): 0 done, 2 a
        script or operator mistake, 3 a device fault, 4 a safety refusal, 1 a bug."""
        self.message = ""
        self.quit_requested = False
        #: set when the session was ended from outside (a signal): a step that fails
        #: because of it is not reported as a script failure
        self.interrupted = False
        self._waiting: Step | None = None
        self._deadline = 0.0
        self._sleep_until = 0.0
        self.timer = QTimer(self)
        self.timer.setInterval(POLL_MS)
        self.timer.timeout.connect(self._tick)

    def start(self) -> None:
        self.timer.start()

    # -- stepping ---------------------------------------------------------------------
    def _tick(self) -> None:
        try:
            while not self.done:
                if self._waiting is not None:
                    if not self._poll(self._waiting):
                        if time.monotonic() > self._deadline:
                            raise ScriptError(f"line {self._waiting.line}: "
                                              f"{self._waiting.text!r} timed out")
                        return
                    self._waiting = None
                if self.pos >= len(self.steps):
                    self._finish(True, "script completed")
                    return
                step = self.steps[self.pos]
                self.pos += 1
                log.info("script line %d: %s", step.line, step.text)
                if self._execute(step):
                    self._waiting = step
                    self._deadline = time.monotonic() + _timeout(step)
        except Exception as exc:  # report, stop the script, leave the window usable
            if self.interrupted:  # the signal's own line says how the session ended
                log.debug("GUI script stopped by an interrupted session: %s", exc)
            elif isinstance(exc, (NmsidError, ValueError, OSError)):
                # an operator's or a device's mistake: one line, no traceback
                log.error("GUI script failed: %s", one_line(exc))
            else:
                log.exception("GUI script failed")
            self.exit_code = int(getattr(exc, "exit_code", 0)) or (
                2 if isinstance(exc, (ValueError, OSError)) else 1)
            self._finish(False, f"GUI script failed: {exc}")

    def _finish(self, ok: bool, message: str) -> None:
        self.timer.stop()
        if self.screenshot is not None:
            try:
                self.window.save_screenshot(self.screenshot)
                message += f"; screenshot saved to {self.screenshot}"
            except OSError as exc:
                ok, message = False, f"{message}; {exc}"
        self.done, self.ok, self.message = True, ok, message
        self.finished.emit(ok, message)

    def _execute(self, step: Step) -> bool:
        """Do the step; return True if it must then be waited for."""
        w = self.window
        c = step.command
        if c is Command.START:
            args = validate_settings(StartArgs, step.kwargs, source=f"line {step.line}",
                                     make_error=script_error)
            kw = {k: v for k, v in vars(args).items() if v is not None and k != "resume"}
            w.start_session(resume=args.resume, **kw)
            if w.controller.engine is None:
                raise ScriptError(f"line {step.line}: the session did not start: "
                                  f"{w.setup_panel.message.text()}")
            return False
        if c is Command.CONFIRM_CALIBRATION:
            return True  # waits until the calibration result is shown, then confirms
        if c in (Command.WAIT, Command.WAIT_TRIAL, Command.WAIT_TRIAL_TIME,
                 Command.WAIT_FINISHED, Command.WAIT_ABORTED):
            return True
        if c is Command.SLEEP:
            self._sleep_until = time.monotonic() + float(step.args[0])
            return True
        if c is Command.ESTOP:
            w.press_estop()
        elif c is Command.REARM:
            w.rearm()
        elif c is Command.CONTINUE:
            w.continue_session()
        elif c is Command.PAUSE:
            w.pause()
        elif c is Command.RESUME:
            w.resume()
        elif c is Command.SKIP:
            w.skip()
        elif c is Command.RERUN:
            if step.args:
                w.rerun(int(step.args[0]))
            elif "aborted" in w.trial_statuses():
                w.rerun(None)
            else:  # on a fast clock an E-stop can fall between two trials
                log.info("script line %d: rerun: no aborted trial, nothing to re-run",
                         step.line)
        elif c is Command.END_SESSION:
            w.end_session()
        elif c is Command.NOTE:
            w.add_note(step.args[0])
        elif c is Command.TAB:
            w.tabs.setCurrentIndex(TAB_NAMES[step.args[0]])
        elif c is Command.SCREENSHOT:
            w.save_screenshot(step.args[0])
        elif c is Command.QUIT:
            self.quit_requested = True
            self.pos = len(self.steps)
        return False

    def _poll(self, step: Step) -> bool:
        w = self.window
        c = step.command
        if c not in (Command.WAIT_FINISHED, Command.SLEEP) and w.run_result is not None \
                and w.controller.worker is not None and not w.controller.running:
            raise ScriptError(f"line {step.line}: {step.text!r}: the session ended before "
                              "this happened (on the fast clock trials pass quicker than a "
                              "script can react; use the real-time clock)")
        if c is Command.CONFIRM_CALIBRATION:
            if not w.calibration_panel.confirm_button.isEnabled():
                return False
            args = validate_settings(CalibrationArgs, step.kwargs, source=f"line {step.line}",
                                     make_error=script_error)
            w.confirm_calibration(**{k: v for k, v in vars(args).items() if v is not None})
            return True
        if c is Command.SLEEP:
            return time.monotonic() >= self._sleep_until
        if c is Command.WAIT:
            state = w.state
            return getattr(state, "value", state) == step.args[0].lower()
        if c is Command.WAIT_TRIAL:
            statuses = w.trial_statuses()
            i = int(float(step.args[0]))
            if i >= len(statuses):
                return False
            if step.args[1] == "running":  # "has started": it may be over already
                return statuses[i] in ("running", "done", "aborted")
            return statuses[i] == step.args[1]
        if c is Command.WAIT_ABORTED:
            return "aborted" in w.trial_statuses()
        if c is Command.WAIT_TRIAL_TIME:
            snap = w.buffer.snapshot()
            return (w.state is not None and getattr(w.state, "value", "") == "stimulating"
                    and snap.n > 0 and snap.t_s[-1] >= float(step.args[0]))
        if c is Command.WAIT_FINISHED:
            if w.run_error is not None:
                raise ScriptError(f"the engine stopped with an error: {w.run_error}")
            return (w.controller.worker is not None and not w.controller.running
                    and w.run_result is not None and not w.results.busy
                    and w.identification.pending == 0)
        return True


def _timeout(step: Step) -> float:
    if step.command is Command.SLEEP:
        return float(step.args[0]) + DEFAULT_TIMEOUT_S
    if step.command is Command.WAIT_TRIAL and len(step.args) > 2:
        return float(step.args[2])
    if step.command in (Command.WAIT, Command.WAIT_TRIAL_TIME) and len(step.args) > 1:
        return float(step.args[1])
    if step.command in (Command.WAIT_FINISHED, Command.WAIT_ABORTED) and step.args:
        return float(step.args[0])
    return DEFAULT_TIMEOUT_S
