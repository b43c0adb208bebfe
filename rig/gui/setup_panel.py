"""Session setup: participant code, joint, backend, simulated participant, configuration,
output file; start or resume.

The output file is never overwritten. If it exists and is an unfinished session, the
panel offers to resume it (the engine skips completed trials and re-runs aborted ones);
if it is finished or not a session file, Start is refused with the reason.
"""

from __future__ import annotations

import enum
import json
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from nmsid.errors import NmsidError
from nmsid.protocols.config import PARTICIPANT_MODELS, config_from_json
from nmsid.protocols.errors import OutputPathError
from nmsid.protocols.joints import DEFAULT_JOINT, JOINTS
from nmsid.protocols.output_paths import check_output as check_output_place
from nmsid.protocols.output_paths import check_session_name, default_sessions_dir
from nmsid.protocols.session_file import PARTICIPANT_PATTERN, SessionWriter, read_session
from nmsid.protocols.user_values import one_line, parse_seed
from nmsid.rig.errors import RequestError
from nmsid.rig.gui.lsl_panel import LslPanel
from nmsid.rig.gui.theme import Colour
from nmsid.rig.session_log import journal_dir
from nmsid.rig.session_service import model_participant_code

log = logging.getLogger(__name__)


class Backend(enum.Enum):
    SIM = "sim"
    HW = "hw"


class OutputState(enum.Enum):
    """What is at the chosen output path."""

    NEW = "new"                  # nothing there: a new session
    UNFINISHED = "unfinished"    # a session with trials still to run: can be resumed
    FINISHED = "finished"        # a complete session: refused
    INVALID = "invalid"          # something that is not a readable session: refused


@dataclass(frozen=True)
class SessionRequest:
    """What the operator asked for on the setup panel."""

    participant: str
    backend: Backend
    output_path: Path
    config_path: Path | None = None
    hw_config_path: Path | None = None
    seed: int | None = None
    realtime: bool = True
    resume: bool = False
    joint: str | None = None
    """The joint the session drives (``--joint``); None: the configuration's (elbow)."""
    lsl_record: tuple[str, ...] = ()
    """LSL streams to record into the session file (``--lsl-record``); empty: none."""
    participant_model: str | None = None
    """The simulated participant (``--participant-model``, a name of
    :data:`~nmsid.protocols.config.PARTICIPANT_MODELS`; sim only); None: the
    configuration's (template by default)."""


@dataclass(frozen=True)
class OutputCheck:
    state: OutputState
    message: str
    n_completed: int = 0
    n_planned: int = 0


def check_output(path: str | os.PathLike) -> OutputCheck:
    """Say whether ``path`` is free, resumable, finished or unusable.

    A session is unfinished if its crash journal (``<file>.journal``) is still there
    (the engine removes it when a run ends cleanly) or if trials of its stored schedule
    are not completed; the engine's resume recovers the journal and re-runs the rest.
    """
    path = Path(path)
    try:  # the CLI's preflight: a name the journal can derive from, a writable folder
        check_session_name(path, option="output file")
        if not path.exists() and not journal_dir(path).is_dir():
            check_output_place(path, kind="file", option="output file")
        elif not os.access(path.absolute().parent, os.W_OK | os.X_OK):
            raise OutputPathError(f"output file {path}: cannot write in "
                                  f"{path.absolute().parent} (permission denied); resume "
                                  "needs to write beside the file")
    except OutputPathError as exc:
        return OutputCheck(OutputState.INVALID, f"{exc}")
    jdir = journal_dir(path)
    if not path.exists():
        if jdir.is_dir():
            return OutputCheck(OutputState.UNFINISHED,
                               f"{path} was being written when the program stopped (its "
                               "journal is there). Press Resume to recover and continue it, "
                               "or choose another output file.")
        return OutputCheck(OutputState.NEW, f"{path} will be created.")
    try:
        session = read_session(path, load_data=False)
    except (ValueError, OSError) as exc:
        try:  # a session file that stopped before its calibration was written
            SessionWriter.open(path)
        except (ValueError, OSError):
            if jdir.is_dir():
                return OutputCheck(OutputState.UNFINISHED,
                                   f"{path} is damaged but its journal is there. Press "
                                   "Resume to recover and continue it.")
            return OutputCheck(OutputState.INVALID,
                               f"{path} exists and is not a readable session file ({exc}); "
                               "choose another output file (or run `nmsid recover` on it).")
        return OutputCheck(OutputState.UNFINISHED,
                           f"{path} holds a session that stopped before its calibration "
                           "was saved. Press Resume to continue it, or choose another "
                           "output file.")
    done = {int(t.extra_attrs["schedule_index"]) if "schedule_index" in t.extra_attrs
            else (round(float(t.sE), 6), t.repeat) for t in session.trials if t.completed}
    planned = _planned_count(session)
    if not jdir.is_dir() and planned and len(done) >= planned:
        return OutputCheck(OutputState.FINISHED,
                           f"{path} holds a finished session ({len(done)} completed trials); "
                           "nmsid never overwrites a session file: choose another output "
                           "file.", len(done), planned)
    return OutputCheck(OutputState.UNFINISHED,
                       f"{path} holds an unfinished session of {session.participant} "
                       f"({len(done)}" + (f" of {planned}" if planned else "") +
                       " trials completed). Press Resume to continue it (completed trials "
                       "are kept, aborted ones re-run), or choose another output file.",
                       len(done), planned)


def _seed_of(text: str) -> int | None:
    """The seed field's value (None: random, recorded); a bad value names what is valid."""
    value, problem = parse_seed(text, empty_is_random=True)
    if problem:
        raise RequestError(problem)
    return value


def _planned_count(session) -> int:
    """Number of planned trials of a stored session (0 if unknown)."""
    text = session.attrs.get("schedule_json")
    if text is not None:
        try:
            return len(json.loads(text if isinstance(text, str) else bytes(text).decode()))
        except (ValueError, TypeError):
            pass
    try:
        if session.config_json:
            cfg = config_from_json(session.config_json)
            return len(cfg.protocol.sE_levels) * cfg.protocol.repeats
    except ValueError:
        pass
    return 0


def default_output(participant: str, outdir: str | os.PathLike | None = None) -> Path:
    """``sessions/<participant>-<UTC time>.h5`` (the name ``nmsid run`` uses; the folder
    is ``default_sessions_dir()``, never inside the Windows folder)."""
    import datetime as dt
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    return Path(outdir or default_sessions_dir()) / f"{participant}-{stamp}.h5"


class SetupPanel(QWidget):
    """The form shown before a session starts.

    Parameters
    ----------
    on_start : callable
        Called with a :class:`SessionRequest` when the operator presses Start or Resume.
    lsl_panel : LslPanel, optional
        The LSL stream list (default: a new one; tests pass one with a fake resolver).
    """

    def __init__(self, on_start: Callable[[SessionRequest], None],
                 parent: QWidget | None = None, lsl_panel: LslPanel | None = None):
        super().__init__(parent)
        self._on_start = on_start
        self.participant = QLineEdit("P01")
        self.participant.setMaxLength(64)
        self.backend = QComboBox()
        self.backend.addItem("Simulated rig (sim)", Backend.SIM)
        self.backend.addItem("Hardware (hw)", Backend.HW)
        self.config_path = QLineEdit()
        self.config_path.setPlaceholderText("built-in defaults (15 sE x 3 repeats)")
        self.hw_config_path = QLineEdit()
        self.hw_config_path.setPlaceholderText("hardware chain configuration (hw only)")
        self.output_path = QLineEdit()
        self.seed = QLineEdit()  # 0 ... 2**63-1 as on the command line (a QSpinBox is int32)
        self.seed.setPlaceholderText("random (recorded)")
        self.seed.textChanged.connect(lambda _: self.refresh())
        self.realtime = QCheckBox("pace the simulator in real time")
        self.realtime.setChecked(True)
        self.joint = QComboBox()   # the CLI's --joint (protocols/joints.py)
        self.joint.addItem("as the configuration says (elbow by default)", None)
        for name, j in JOINTS.items():
            self.joint.addItem(f"{name}: {j.extensor_muscles} vs {j.flexor_muscles}, "
                               f"{j.quantity_label}", name)
        self.joint.setToolTip("The joint the session drives: its labels, unit and default "
                              "limits (docs/joints.md); as nmsid run --joint")
        self.participant_model = QComboBox()   # the CLI's --participant-model (built-ins)
        self.participant_model.addItem("as the configuration says (template by default)",
                                       None)
        for name in PARTICIPANT_MODELS:   # the one registry; plug-ins are never offered
            self.participant_model.addItem(name, name)
        self.participant_model.setToolTip(
            "The simulated participant (sim only), as nmsid run --participant-model: "
            "template: the paper's second-order model; musculoskeletal: MyoSuite's MuJoCo "
            "elbow, or at the knee and the ankle MuJoCo's MyoLeg on a dynamometer (needs "
            "the 'mujoco' extra). A lab's plug-in runs with nmsid run only (docs/gui.md)")
        self.lsl = lsl_panel if lsl_panel is not None else LslPanel()
        self.message = QLabel("")
        self.message.setWordWrap(True)
        self.start_button = QPushButton("Start new session")
        self.resume_button = QPushButton("Resume session")
        self.start_button.setMinimumHeight(40)
        self.resume_button.setMinimumHeight(40)
        self.resume_button.setVisible(False)
        self.start_button.clicked.connect(lambda: self.press_start(resume=False))
        self.resume_button.clicked.connect(lambda: self.press_start(resume=True))
        self._out_touched = False
        self._participant_touched = False   # typed or given: the model's code never replaces it
        self.participant.textEdited.connect(self._participant_edited)
        self.participant.textChanged.connect(self._participant_changed)
        self.output_path.textEdited.connect(self._output_edited)
        self.output_path.textChanged.connect(lambda _: self.refresh())
        self.backend.currentIndexChanged.connect(lambda _: self._model_changed())
        self.joint.currentIndexChanged.connect(lambda _: self._model_changed())
        self.participant_model.currentIndexChanged.connect(lambda _: self._model_changed())

        box = QGroupBox("New session")
        form = QFormLayout(box)
        form.addRow("Participant code", self.participant)
        form.addRow("Joint", self.joint)
        form.addRow("Rig", self.backend)
        form.addRow("Simulated participant", self.participant_model)
        form.addRow("Configuration (TOML)", self._with_browse(self.config_path, "toml"))
        form.addRow("Hardware configuration", self._with_browse(self.hw_config_path, "toml"))
        form.addRow("Output file (.h5)", self._with_browse(self.output_path, "h5", save=True))
        form.addRow("Schedule seed", self.seed)
        form.addRow("", self.realtime)
        buttons = QHBoxLayout()
        buttons.addWidget(self.start_button)
        buttons.addWidget(self.resume_button)
        lay = QVBoxLayout(self)
        lay.addWidget(box)
        lay.addWidget(self.lsl)
        lay.addWidget(self.message)
        lay.addLayout(buttons)
        lay.addStretch(1)
        self._participant_changed(self.participant.text())

    def _with_browse(self, edit: QLineEdit, ext: str, save: bool = False) -> QWidget:
        w = QWidget()
        row = QHBoxLayout(w)
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(edit, 1)
        b = QPushButton("Browse...")

        def browse():
            if save:
                path, _ = QFileDialog.getSaveFileName(self, "Session file", edit.text(),
                                                      f"*.{ext}",
                                                      options=QFileDialog.Option.DontConfirmOverwrite)
            else:
                path, _ = QFileDialog.getOpenFileName(self, "Open", edit.text(), f"*.{ext}")
            if path:
                if save:
                    self._out_touched = True
                edit.setText(path)
        b.clicked.connect(browse)
        row.addWidget(b)
        return w

    def _participant_changed(self, text: str) -> None:
        if not self._out_touched:
            self.output_path.setText(str(default_output(text or "P01")))
        self.refresh()

    def new_session(self) -> None:
        """Make the form ready for the next session (a fresh default output file)."""
        self._out_touched = False
        self._participant_changed(self.participant.text())
        self.setEnabled(True)

    def _output_edited(self, _text: str) -> None:
        self._out_touched = True

    def _participant_edited(self, _text: str) -> None:
        self._participant_touched = True

    def chosen_model(self) -> str | None:
        """The simulated participant the form asks for (None: the configuration's; always
        None on the hardware rig)."""
        if self.backend.currentData() != Backend.SIM:
            return None
        return self.participant_model.currentData()

    def _model_changed(self) -> None:
        """A participant code nobody typed follows the simulated participant, as ``nmsid
        run --participant-model`` without ``--participant`` does (MK01 on the MyoLeg
        knee, not the template's P01)."""
        if not self._participant_touched:
            code = model_participant_code(self.chosen_model(),
                                          self.joint.currentData() or DEFAULT_JOINT)
            self.participant.setText(code or "P01")
        self.refresh()

    # -- state ------------------------------------------------------------------------
    def set_values(self, *, participant: str | None = None, backend: str | None = None,
                   config: str | os.PathLike | None = None,
                   hw_config: str | os.PathLike | None = None,
                   output: str | os.PathLike | None = None, seed: int | None = None,
                   realtime: bool | None = None, joint: str | None = None,
                   lsl_record=None, participant_model: str | None = None) -> None:
        """Fill the form (from the command line, a script or a test); ``joint``: a name of
        :data:`~nmsid.protocols.joints.JOINTS`; ``lsl_record``: stream names to record
        (LSL on); ``participant_model``: a name of
        :data:`~nmsid.protocols.config.PARTICIPANT_MODELS` (a plug-in spec is refused)."""
        if participant is not None:
            self._participant_touched = True
            self.participant.setText(participant)
        if participant_model is not None:
            at = self.participant_model.findData(str(participant_model))
            if at < 0:
                raise RequestError(f"participant model {participant_model!r} is not one of "
                                   f"{', '.join(PARTICIPANT_MODELS)} (a lab's plug-in "
                                   "runs with nmsid run --participant-model)")
            self.participant_model.setCurrentIndex(at)
        if joint is not None:
            at = self.joint.findData(str(joint))
            if at < 0:
                raise RequestError(f"joint {joint!r} is not one of {', '.join(JOINTS)}")
            self.joint.setCurrentIndex(at)
        if lsl_record is not None:
            self.lsl.set_on(bool(lsl_record))
            self.lsl.set_wanted(lsl_record)
        if backend is not None:
            self.backend.setCurrentIndex(self.backend.findData(Backend(backend)))
        if config is not None:
            self.config_path.setText(str(config))
        if hw_config is not None:
            self.hw_config_path.setText(str(hw_config))
        if output is not None:
            self._out_touched = True
            self.output_path.setText(str(output))
        if seed is not None:
            self.seed.setText(str(int(seed)))
        if realtime is not None:
            self.realtime.setChecked(bool(realtime))
        self.refresh()

    def refresh(self) -> OutputCheck | None:
        """Re-check the participant code and the output file; enable the buttons."""
        code = self.participant.text()
        self.realtime.setEnabled(self.backend.currentData() == Backend.SIM)
        self.participant_model.setEnabled(self.backend.currentData() == Backend.SIM)
        self.hw_config_path.setEnabled(self.backend.currentData() == Backend.HW)
        if not PARTICIPANT_PATTERN.match(code):
            self._show(f"Participant code {code!r} is not valid: use 1 to 64 letters, digits, "
                       "'_' or '-' (a code, never a name).", error=True)
            self.start_button.setEnabled(False)
            self.resume_button.setVisible(False)
            return None
        out = self.output_path.text().strip()
        if not out:
            self._show("Choose an output file.", error=True)
            self.start_button.setEnabled(False)
            return None
        _, seed_problem = parse_seed(self.seed.text(), empty_is_random=True)
        if seed_problem:
            self._show(f"Schedule {seed_problem}.", error=True)
            self.start_button.setEnabled(False)
            self.resume_button.setVisible(False)
            return None
        check = check_output(out)
        self.start_button.setEnabled(check.state == OutputState.NEW)
        self.resume_button.setVisible(check.state == OutputState.UNFINISHED)
        self._show(check.message, error=check.state in (OutputState.FINISHED,
                                                         OutputState.INVALID))
        return check

    def _show(self, text: str, error: bool = False) -> None:
        self.message.setText(text)
        self.message.setStyleSheet(f"color: {Colour.FAULT};" if error else "")

    def request(self, resume: bool = False) -> SessionRequest:
        """The request the form describes (raises ValueError naming a bad field)."""
        code = self.participant.text()
        if not PARTICIPANT_PATTERN.match(code):
            raise RequestError(f"participant code {code!r} is not [A-Za-z0-9_-]{{1,64}}")
        cfg = self.config_path.text().strip()
        hw = self.hw_config_path.text().strip()
        out = self.output_path.text().strip()
        if not out:
            raise RequestError("no output file chosen")
        return SessionRequest(
            participant=code, backend=self.backend.currentData(), output_path=Path(out),
            config_path=Path(cfg) if cfg else None, hw_config_path=Path(hw) if hw else None,
            seed=_seed_of(self.seed.text()),
            realtime=self.realtime.isChecked(), resume=resume,
            joint=None if resume else self.joint.currentData(),
            participant_model=None if resume else self.chosen_model(),
            lsl_record=tuple(self.lsl.wanted()))

    def press_start(self, resume: bool = False) -> None:
        """Press Start (or Resume): check the form, then hand the request on. Problems
        are shown on the panel, never raised."""
        check = self.refresh()
        if check is None:
            return
        if resume and check.state != OutputState.UNFINISHED:
            self._show("Nothing to resume at this output file.", error=True)
            return
        if not resume and check.state != OutputState.NEW:
            self._show(check.message, error=True)
            return
        try:
            req = self.request(resume=resume)
            self._on_start(req)
        except (NmsidError, ValueError, OSError) as exc:  # one line on the panel and log
            log.error("start refused: %s", one_line(exc))
            self._show(one_line(exc), error=True)
