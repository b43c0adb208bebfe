"""Calibration panel: the live current ramp per muscle and the operator's confirmation.

While the engine ramps each muscle's current, force vs current is drawn per muscle. When
the engine reports the detected currents (Iemin/Iemax/Ifmin/Ifmax), they are marked on the
plot (dashed vertical lines) with each muscle's force thresholds (horizontal lines in the
muscle's colour: the extensor pushes, at +Fmin/+Fmax; the flexor pulls, at -Fmin/-Fmax)
and copied into four editable fields. The operator confirms them as they are or after editing (or
types all four by hand); nothing else runs before that.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from nmsid.protocols.joints import DEFAULT_JOINT, JOINTS, Joint
from nmsid.protocols.session_file import Calibration
from nmsid.rig.gui.theme import Colour

#: (muscle key, label, colour, Imin attribute, Imax attribute)
MUSCLES = (("ext", "Extensor (triceps)", Colour.I_EXT, "Iemin_mA", "Iemax_mA"),
           ("flex", "Flexor (biceps)", Colour.I_FLEX, "Ifmin_mA", "Ifmax_mA"))


def muscle_key(muscle: str) -> str:
    """``ext`` or ``flex`` for whatever name the engine gives a muscle."""
    m = str(getattr(muscle, "value", muscle)).lower()
    return "flex" if m.startswith("f") or "bicep" in m else "ext"


class CalibrationPanel(QWidget):
    """Live ramp plot, detected currents, edit fields and the Confirm button.

    Parameters
    ----------
    on_confirm : callable
        Called with the :class:`~nmsid.protocols.session_file.Calibration` the operator confirmed.
    """

    def __init__(self, on_confirm: Callable[[Calibration], None],
                 parent: QWidget | None = None):
        super().__init__(parent)
        self._on_confirm = on_confirm
        self.detected: Calibration | None = None
        self.points: dict[str, list[tuple[float, float]]] = {"ext": [], "flex": []}

        self.plot = pg.PlotWidget(title="Calibration ramp: force vs current")
        self.plot.setBackground("w")
        self.plot.showGrid(x=True, y=True, alpha=0.3)
        self.plot.setLabel("bottom", "current (mA)")
        self.plot.setLabel("left", "force, muscle alone (N)")
        for axis in ("bottom", "left"):  # one unit: no N/mN flipping with the range
            self.plot.getAxis(axis).enableAutoSIPrefix(False)
        self.plot.addLegend(offset=(10, 10))
        self.curves = {}
        self.lines = {}
        for key, label, colour, lo, hi in MUSCLES:
            self.curves[key] = self.plot.plot([], [], pen=pg.mkPen(colour, width=2),
                                              symbol="o", symbolSize=6,
                                              symbolBrush=colour, name=label)
            for attr in (lo, hi):
                line = pg.InfiniteLine(angle=90, movable=False,
                                       pen=pg.mkPen(colour, width=1.5,
                                                    style=pg.QtCore.Qt.PenStyle.DashLine),
                                       label=attr.replace("_mA", ""),
                                       labelOpts={"color": colour, "position": 0.9})
                line.setVisible(False)
                self.plot.addItem(line)
                self.lines[attr] = line
        self.force_lines: dict[str, pg.InfiniteLine] = {}
        """``ext_Fmin``, ``ext_Fmax``, ``flex_Fmin``, ``flex_Fmax``: the thresholds each
        muscle's ramp is judged by (the flexor's force is negative)."""
        for key, _, colour, _, _ in MUSCLES:
            sign = -1.0 if key == "flex" else 1.0
            for name, value in (("Fmin", 0.5), ("Fmax", 5.0)):
                line = pg.InfiniteLine(pos=sign * value, angle=0,
                                       pen=pg.mkPen(colour, width=1,
                                                    style=pg.QtCore.Qt.PenStyle.DotLine),
                                       label=f"{key} {name}",
                                       labelOpts={"color": colour, "position": 0.05})
                self.plot.addItem(line)
                self.force_lines[f"{key}_{name}"] = line

        self.fields: dict[str, QDoubleSpinBox] = {}
        self.field_labels: dict[str, QLabel] = {}
        form_box = QGroupBox("Currents (edit if needed, then confirm)")
        form = QFormLayout(form_box)
        for *_, lo, hi in MUSCLES:
            for attr in (lo, hi):
                spin = QDoubleSpinBox()
                spin.setRange(0.0, 200.0)
                spin.setDecimals(2)
                spin.setSingleStep(0.5)
                spin.setSuffix(" mA")
                spin.valueChanged.connect(lambda v, a=attr: self._field_changed(a, v))
                self.fields[attr] = spin
                self.field_labels[attr] = QLabel(attr.replace("_mA", ""))
                form.addRow(self.field_labels[attr], spin)
        self.status = QLabel("Waiting for the engine to start the calibration ramp.")
        self.status.setWordWrap(True)
        self.confirm_button = QPushButton("Confirm calibration")
        self.confirm_button.setMinimumHeight(36)
        self.confirm_button.setEnabled(False)
        self.confirm_button.clicked.connect(self.confirm)
        side = QVBoxLayout()
        side.addWidget(form_box)
        side.addWidget(self.status)
        side.addWidget(self.confirm_button)
        side.addStretch(1)
        lay = QHBoxLayout(self)
        lay.addWidget(self.plot, 3)
        lay.addLayout(side, 1)
        self.unit = "N"
        self.set_joint(JOINTS[DEFAULT_JOINT])

    def set_joint(self, joint: Joint) -> None:
        """The session's joint: its muscle groups, what is measured and its unit."""
        self.unit = joint.unit
        self.plot.setLabel("left", f"{joint.quantity}, muscle alone ({joint.unit})")
        names = {"ext": f"{joint.extensor_role.capitalize()} ({joint.extensor_muscles})",
                 "flex": f"{joint.flexor_role.capitalize()} ({joint.flexor_muscles})"}
        legend = self.plot.getPlotItem().legend
        for key, _, _, lo, hi in MUSCLES:
            label = legend.getLabel(self.curves[key]) if legend is not None else None
            if label is not None:
                label.setText(names[key])
            muscles = joint.extensor_muscles if key == "ext" else joint.flexor_muscles
            for attr in (lo, hi):
                self.field_labels[attr].setText(f"{attr.replace('_mA', '')}  ({muscles})")

    # -- engine notifications (GUI thread) -------------------------------------------
    def add_step(self, muscle: str, current_mA: float, force_N: float) -> None:
        """One ramp step: the muscle's current and the force it produced."""
        key = muscle_key(muscle)
        self.points[key].append((current_mA, force_N))
        xy = np.array(self.points[key])
        self.curves[key].setData(xy[:, 0], xy[:, 1])
        self.status.setText(f"Ramping {key}: {current_mA:.1f} mA -> {force_N:.2f} "
                            f"{self.unit}")

    def reset(self) -> None:
        """Forget the previous session's ramps and values."""
        self.detected = None
        self.points = {"ext": [], "flex": []}
        for curve in self.curves.values():
            curve.setData([], [])
        for line in self.lines.values():
            line.setVisible(False)
        self.set_awaiting(False)
        self.status.setStyleSheet("")
        self.status.setText("Waiting for the engine to start the calibration ramp.")

    def set_known(self, calibration: Calibration) -> None:
        """Show a calibration the engine already has (resumed session): nothing to confirm."""
        self.set_result(calibration)
        self.set_awaiting(False)
        self.status.setText("Calibration taken from the session file (resumed session).")

    def set_result(self, calibration: Calibration) -> None:
        """The engine's detected currents: mark them and offer them for confirmation."""
        self.detected = calibration
        for attr, spin in self.fields.items():
            spin.blockSignals(True)
            spin.setValue(float(getattr(calibration, attr)))
            spin.blockSignals(False)
            self._field_changed(attr, float(getattr(calibration, attr)))
        self.set_thresholds(calibration.Fmin_N, calibration.Fmax_N)
        for key in ("ext", "flex"):  # ramps stored with the calibration, if any
            I = calibration.ramps.get(f"{key}_I_mA") if calibration.ramps else None
            F = calibration.ramps.get(f"{key}_force_N") if calibration.ramps else None
            if I is not None and F is not None and not self.points[key]:
                self.points[key] = list(zip(np.asarray(I, float), np.asarray(F, float),
                                            strict=True))
                self.curves[key].setData(np.asarray(I, float), np.asarray(F, float))
        self.status.setText("Detected currents are marked. Check them against the ramp, "
                            "edit if needed, then press Confirm calibration.")
        self.set_awaiting(True)

    def set_thresholds(self, Fmin_N: float, Fmax_N: float) -> None:
        """Move both muscles' Fmin/Fmax lines (the flexor's at the negative forces)."""
        for key in ("ext", "flex"):
            sign = -1.0 if key == "flex" else 1.0
            self.force_lines[f"{key}_Fmin"].setValue(sign * float(Fmin_N))
            self.force_lines[f"{key}_Fmax"].setValue(sign * float(Fmax_N))

    def refused(self, reason: str) -> None:
        """The engine refused the confirmed values (e.g. above a ceiling); ask again."""
        self.set_awaiting(True)
        self.status.setText(f"Refused by the engine: {reason}. Correct the values and "
                            "confirm again.")
        self.status.setStyleSheet(f"color: {Colour.FAULT};")

    def set_awaiting(self, awaiting: bool) -> None:
        """Enable the fields and Confirm button while the engine waits for them."""
        self.confirm_button.setEnabled(awaiting)
        for spin in self.fields.values():
            spin.setReadOnly(not awaiting)

    def _field_changed(self, attr: str, value: float) -> None:
        line = self.lines[attr]
        line.setValue(value)
        line.setVisible(True)

    # -- operator ---------------------------------------------------------------------
    def current_values(self) -> dict[str, Any]:
        return {attr: float(spin.value()) for attr, spin in self.fields.items()}

    def set_values(self, **currents_mA: float) -> None:
        """Type currents into the fields (as an operator would)."""
        for attr, value in currents_mA.items():
            if attr not in self.fields:
                raise ValueError(f"unknown calibration field {attr!r}; valid: "
                                 f"{sorted(self.fields)}")
            self.fields[attr].setValue(float(value))

    def calibration(self) -> Calibration:
        """The calibration as currently shown (detected values with the operator's edits).

        Raises
        ------
        ValueError
            If the values break the contract (e.g. Iemax_mA <= Iemin_mA).
        """
        values = self.current_values()
        if self.detected is not None:
            cal = dataclasses.replace(self.detected, **values)
        else:
            cal = Calibration(**values)
        problems = cal.problems()
        if problems:
            raise ValueError("calibration not accepted: " + "; ".join(problems))
        return cal

    def confirm(self) -> None:
        try:
            cal = self.calibration()
        except ValueError as exc:
            self.status.setText(str(exc))
            self.status.setStyleSheet(f"color: {Colour.FAULT};")
            return
        self.status.setStyleSheet("")
        self._on_confirm(cal)
        self.set_awaiting(False)
        self.status.setText("Calibration confirmed: "
                            + ", ".join(f"{k.replace('_mA', '')}={v:.2f} mA"
                                        for k, v in self.current_values().items()))
