"""The always-visible safety strip: E-STOP button, interlock lights, trip banner, re-arm.

The E-STOP button is never disabled and calls its handler directly (the engine's
``estop`` is thread-safe and returns at once); Space and Escape are bound to it by
:func:`install_estop_shortcuts`. After a trip, the banner shows the reason and the
interlock stays latched until the operator presses RE-ARM. RE-ARM clears the latch only
(LabVIEW's "clear latch"); the engine then holds, output off, until CONTINUE starts the
next trial. The strip also carries the large readouts of the commanded currents and the
force (:class:`nmsid.rig.gui.live_plots.Readouts`) and a notice line for an E-stop that
nothing could record.
"""

from __future__ import annotations

from collections.abc import Callable

from PySide6.QtCore import Qt
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QFrame,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSizePolicy,
    QVBoxLayout,
    QWidget,
)

from nmsid.rig.gui.theme import Colour
from nmsid.rig.observer import is_rerun_wait

#: The interlock rules shown as lights, in display order: (substring of the engine's rule
#: name, label). Rules the engine reports that match none of these are shown too.
LIGHTS = (("sensor", "Sensor stream"), ("acquisition", "Sensor stream"),
          ("force", "Force limit"), ("stim", "Stimulator"), ("estop", "E-stop"),
          ("latch", "Interlock latch"))

ESTOP_KEYS = (Qt.Key.Key_Space, Qt.Key.Key_Escape)


class EStopButton(QPushButton):
    """A large red button that is always enabled (``setEnabled(False)`` is refused)."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__("E-STOP\n(Space / Esc)", parent)
        self.setObjectName("estop")
        self.setMinimumSize(220, 110)
        self.setSizePolicy(QSizePolicy.Policy.Fixed, QSizePolicy.Policy.Expanding)
        self.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.setStyleSheet(
            "QPushButton#estop { background: #d00000; color: white; font-size: 26px;"
            " font-weight: bold; border: 4px solid #700000; border-radius: 12px; }"
            "QPushButton#estop:pressed { background: #900000; }")

    def setEnabled(self, enabled: bool) -> None:  # noqa: N802 (Qt naming)
        super().setEnabled(True)

    def setDisabled(self, disabled: bool) -> None:  # noqa: N802
        super().setEnabled(True)


class Light(QWidget):
    """A coloured dot with a label and a detail line."""

    def __init__(self, label: str, parent: QWidget | None = None):
        super().__init__(parent)
        self.dot = QLabel("\u25cf")
        self.dot.setStyleSheet(f"color: {Colour.UNKNOWN}; font-size: 22px;")
        self.label = QLabel(label)
        self.label.setStyleSheet("font-weight: bold;")
        self.detail = QLabel("")
        self.detail.setStyleSheet("color: #555; font-size: 11px;")
        self.ok: bool | None = None
        lay = QGridLayout(self)
        lay.setContentsMargins(2, 0, 2, 0)
        lay.addWidget(self.dot, 0, 0, 2, 1)
        lay.addWidget(self.label, 0, 1)
        lay.addWidget(self.detail, 1, 1)

    def set_state(self, ok: bool | None, detail: str = "") -> None:
        self.ok = ok
        colour = Colour.UNKNOWN if ok is None else (Colour.OK if ok else Colour.FAULT)
        self.dot.setStyleSheet(f"color: {colour}; font-size: 22px;")
        self.detail.setText(detail[:60])
        self.setToolTip(detail)


def _match_light(rule: str) -> str | None:
    key = rule.lower().replace("_", "").replace("-", "").replace(" ", "")
    for needle, label in LIGHTS:
        if needle in key:
            return label
    return None


#: The states the state badge shows with the trial's name (``STIMULATING t004``).
TRIAL_STATES = ("stimulating", "resting")


class SafetyPanel(QFrame):
    """E-STOP, interlock lights, engine state, trip banner and the RE-ARM button.

    Parameters
    ----------
    on_estop, on_rearm : callable
        Called (in the GUI thread) when the operator presses the button.
    on_continue : callable, optional
        Called when the operator presses CONTINUE (after a re-arm or a pause).
    """

    def __init__(self, on_estop: Callable[[], None], on_rearm: Callable[[], None],
                 on_continue: Callable[[], None] | None = None,
                 parent: QWidget | None = None):
        super().__init__(parent)
        self.setFrameShape(QFrame.Shape.StyledPanel)
        self.estop_button = EStopButton()
        self.estop_button.clicked.connect(on_estop)
        self.rearm_button = QPushButton("RE-ARM")
        self.rearm_button.setToolTip("Clear the latched interlock after a trip (only "
                                     "that: stimulation stays off until CONTINUE).")
        self.rearm_button.setMinimumHeight(40)
        self.rearm_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.rearm_button.setEnabled(False)
        self.rearm_button.clicked.connect(on_rearm)
        self.continue_button = QPushButton("CONTINUE")
        self.continue_button.setToolTip("Start the next trial (after a re-arm or a pause)")
        self.continue_button.setMinimumHeight(40)
        self.continue_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.continue_button.setEnabled(False)
        if on_continue is not None:
            self.continue_button.clicked.connect(on_continue)
        self.notice = QLabel("")
        self.notice.setWordWrap(True)
        self.notice.setObjectName("notice")
        self.notice.setStyleSheet(f"background: {Colour.WARN}; color: white; "
                                  "font-weight: bold; padding: 6px;")
        self.notice.setVisible(False)
        self.state_label = QLabel("IDLE")
        self.state_label.setObjectName("state")
        self.state_label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.state_label.setMinimumWidth(240)   # "STIMULATING t045" in full
        self.banner = QLabel("")
        self.banner.setWordWrap(True)
        self.banner.setObjectName("banner")
        self.banner.setVisible(False)
        self.weakened = QLabel("")
        self.weakened.setWordWrap(True)
        self.weakened.setObjectName("weakened")
        self.weakened.setStyleSheet(f"background: {Colour.WARN}; color: white; "
                                    "font-weight: bold; padding: 6px;")
        self.weakened.setVisible(False)
        self.lights: dict[str, Light] = {}
        self._lights_box = QHBoxLayout()
        for _, label in LIGHTS:
            if label not in self.lights:
                self._add_light(label)

        left = QVBoxLayout()
        top = QHBoxLayout()
        top.addWidget(self.state_label)
        top.addLayout(self._lights_box)
        top.addStretch(1)
        top.addWidget(self.rearm_button)
        top.addWidget(self.continue_button)
        left.addLayout(top)
        left.addWidget(self.banner)
        left.addWidget(self.notice)
        left.addWidget(self.weakened)
        lay = QHBoxLayout(self)
        self._body = lay
        lay.addLayout(left, 1)
        lay.addWidget(self.estop_button)
        self.set_state("idle")

    def _add_light(self, label: str) -> Light:
        light = Light(label)
        self.lights[label] = light
        self._lights_box.addWidget(light)
        return light

    def add_readouts(self, widget: QWidget) -> None:
        """Put the large numeric readouts between the lights and the E-STOP button."""
        self._body.insertWidget(1, widget)

    def show_notice(self, text: str) -> None:
        """A message that stays until the next session (e.g. an E-stop nothing recorded)."""
        self.notice.setText(text)
        self.notice.setVisible(True)

    def clear_notice(self) -> None:
        self.notice.setText("")
        self.notice.setVisible(False)

    def set_state(self, state: str, reason: str = "", held: bool = False) -> None:
        """Show the engine state; a trip shows the banner and enables RE-ARM. ``held``:
        the engine holds in ``paused`` after a re-arm (CONTINUE starts the next trial)."""
        colour = Colour.STATE.get(state, Colour.UNKNOWN)
        self._state = state
        self.state_label.setText(self._state_text(state, held))
        style = (f"background: {colour}; color: white; font-size: 18px; font-weight: bold;"
                 " padding: 6px; border-radius: 6px;")
        if self.state_label.styleSheet() != style:  # a restyle costs; states repeat colours
            self.state_label.setStyleSheet(style)
        tripped = state == "tripped"
        self.rearm_button.setEnabled(tripped)
        self.continue_button.setEnabled(state == "paused" and not is_rerun_wait(state, reason))
        if tripped:
            self.banner.setText(f"INTERLOCK TRIPPED: {reason or 'no reason given'}. "
                                "Stimulation is off. Check the participant and the rig, "
                                "then press RE-ARM (clears the latch only).")
            self.banner.setStyleSheet(f"background: {Colour.FAULT}; color: white; "
                                      "font-weight: bold; padding: 6px;")
            self.banner.setVisible(True)
        elif held:
            self.banner.setText("Latch cleared. Stimulation stays off: press CONTINUE to "
                                "start the next trial.")
            self.banner.setStyleSheet(f"background: {Colour.OK}; color: white; "
                                      "font-weight: bold; padding: 6px;")
            self.banner.setVisible(True)
        elif is_rerun_wait(state, reason):
            self.banner.setText(f"{reason[0].upper()}{reason[1:]}: select an aborted trial "
                                "in the schedule and press Re-run aborted, or press End "
                                "session. Stimulation is off.")
            self.banner.setStyleSheet(f"background: {Colour.WARN}; color: white; "
                                      "font-weight: bold; padding: 6px;")
            self.banner.setVisible(True)
        elif state in ("armed", "stimulating", "resting", "calibrating", "finished",
                       "paused"):
            self.banner.setVisible(False)

    def _state_text(self, state: str, held: bool = False) -> str:
        """``STIMULATING t004``: a trial's state names it as the session file does."""
        if held:
            return "RE-ARMED"
        name = getattr(self, "trial_name", "")
        return f"{state.upper()} {name}" if name and state in TRIAL_STATES else state.upper()

    def set_trial(self, name: str) -> None:
        """The running trial's name in the session file (``t004``; '' for none)."""
        self.trial_name = str(name)
        state = getattr(self, "_state", "idle")
        if state in TRIAL_STATES:
            self.state_label.setText(self._state_text(state))

    def set_weakened(self, settings: list[str]) -> None:
        """Show (or hide, if empty) the confirmed settings that weaken the interlock."""
        self.weakened.setText("WEAKENED SAFETY (confirmed in the configuration): "
                              + "; ".join(settings))
        self.weakened.setVisible(bool(settings))

    def set_interlock(self, status: dict) -> None:
        """Update the lights from ``engine.interlock_status()`` (rule -> (ok, detail));
        an empty ``status`` (no session running) greys them all."""
        if not status:
            for light in self.lights.values():
                light.set_state(None, "no session running")
            return
        seen = set()
        for rule, value in status.items():
            try:
                ok, detail = value
            except (TypeError, ValueError):
                ok, detail = bool(value), ""
            label = _match_light(str(rule)) or str(rule)
            light = self.lights.get(label) or self._add_light(label)
            if label in seen:  # several rules on one light: any fault shows
                if light.ok and not ok:
                    light.set_state(False, str(detail))
                continue
            seen.add(label)
            light.set_state(bool(ok), str(detail))

    def light_states(self) -> dict[str, bool | None]:
        return {label: light.ok for label, light in self.lights.items()}


def install_estop_shortcuts(window: QWidget, on_estop: Callable[[], None]) -> list[QShortcut]:
    """Bind Space and Escape to the E-stop for the whole application.

    Returns the shortcut objects (kept alive by their parent ``window``). A text field
    that has the keyboard focus keeps Space for typing; Escape always stops.
    """
    out = []
    for key in ESTOP_KEYS:
        sc = QShortcut(QKeySequence(key), window)
        sc.setContext(Qt.ShortcutContext.ApplicationShortcut)
        sc.setAutoRepeat(False)
        sc.activated.connect(on_estop)
        out.append(sc)
    return out
