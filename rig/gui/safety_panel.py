"""The always-visible safety strip: E-STOP button, interlock lights, trip banner, re-arm.

The E-STOP button is never disabled and calls its handler directly (the engine's
``estop`` is thread-safe and returns at once); Space and Escape are bound to it by
:func:`install_estop_shortcuts`. After a trip, the banner shows the reason and the
interlock stays latched until the operator presses RE-ARM.
"""

from __future__ import annotations

from typing import Callable

from PySide6.QtCore import Qt
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (QFrame, QGridLayout, QHBoxLayout, QLabel, QPushButton,
                               QSizePolicy, QVBoxLayout, QWidget)

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


class SafetyPanel(QFrame):
    """E-STOP, interlock lights, engine state, trip banner and the RE-ARM button.

    Parameters
    ----------
    on_estop, on_rearm : callable
        Called (in the GUI thread) when the operator presses the button.
    """

    def __init__(self, on_estop: Callable[[], None], on_rearm: Callable[[], None],
                 parent: QWidget | None = None):
        super().__init__(parent)
        self.setFrameShape(QFrame.Shape.StyledPanel)
        self.estop_button = EStopButton()
        self.estop_button.clicked.connect(on_estop)
        self.rearm_button = QPushButton("RE-ARM")
        self.rearm_button.setToolTip("Release the latched interlock after a trip; "
                                     "stimulation stays off until you press this.")
        self.rearm_button.setMinimumHeight(40)
        self.rearm_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.rearm_button.setEnabled(False)
        self.rearm_button.clicked.connect(on_rearm)
        self.state_label = QLabel("IDLE")
        self.state_label.setObjectName("state")
        self.state_label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.state_label.setMinimumWidth(150)
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
        left.addLayout(top)
        left.addWidget(self.banner)
        left.addWidget(self.weakened)
        lay = QHBoxLayout(self)
        lay.addLayout(left, 1)
        lay.addWidget(self.estop_button)
        self.set_state("idle")

    def _add_light(self, label: str) -> Light:
        light = Light(label)
        self.lights[label] = light
        self._lights_box.addWidget(light)
        return light

    def set_state(self, state: str, reason: str = "") -> None:
        """Show the engine state; a trip shows the banner and enables RE-ARM."""
        colour = Colour.STATE.get(state, Colour.UNKNOWN)
        self.state_label.setText(state.upper())
        self.state_label.setStyleSheet(
            f"background: {colour}; color: white; font-size: 18px; font-weight: bold;"
            " padding: 6px; border-radius: 6px;")
        tripped = state == "tripped"
        self.rearm_button.setEnabled(tripped)
        if tripped:
            self.banner.setText(f"INTERLOCK TRIPPED: {reason or 'no reason given'}. "
                                "Stimulation is off. Check the participant and the rig, "
                                "then press RE-ARM.")
            self.banner.setStyleSheet(f"background: {Colour.FAULT}; color: white; "
                                      "font-weight: bold; padding: 6px;")
            self.banner.setVisible(True)
        elif is_rerun_wait(state, reason):
            self.banner.setText(f"{reason[0].upper()}{reason[1:]}: select an aborted trial "
                                "in the schedule and press Re-run aborted, or press End "
                                "session. Stimulation is off.")
            self.banner.setStyleSheet(f"background: {Colour.WARN}; color: white; "
                                      "font-weight: bold; padding: 6px;")
            self.banner.setVisible(True)
        elif state in ("armed", "stimulating", "resting", "calibrating", "finished"):
            self.banner.setVisible(False)

    def set_weakened(self, settings: list[str]) -> None:
        """Show (or hide, if empty) the confirmed settings that weaken the interlock."""
        self.weakened.setText("WEAKENED SAFETY (confirmed in the configuration): "
                              + "; ".join(settings))
        self.weakened.setVisible(bool(settings))

    def set_interlock(self, status: dict) -> None:
        """Update the lights from ``engine.interlock_status()`` (rule -> (ok, detail))."""
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
