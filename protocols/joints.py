"""Joints: the agonist/antagonist pair a session drives and what it measures, as data.

The paper's method (an agonist/antagonist pair driven through rE and sE, a second-order
model per sE) holds for any joint with an antagonist pair; the paper measured the elbow. A
:class:`Joint` is everything nmsid needs to know about one: its two muscle groups and their
roles (the "extensor" channel drives the agonist whose action is positive), what is
measured (a force at a strap, in N, or a dynamometer's torque, in N m) and its sign, the
posture, and the defaults that depend on the joint (the interlock's limit, the calibration's
Fmin / Fmax / ceiling), each with its source. :data:`JOINTS` is the registry: a lab adds a
joint with one entry (``docs/joints.md``). Labels ("extensor", "torque (N m)") and limits
come from here and nowhere else.

The session's joint is the configuration's ``joint`` (default ``elbow``) and is recorded in
the session file as optional root attributes (:func:`joint_attrs`); a file without them is
an elbow force session (:func:`recorded_quantity`). Arrays keep their contract names
(``force_N``): for a torque joint that column holds N m (``docs/joints.md``).

Examples
--------
>>> knee = JOINTS["knee"]
>>> knee.unit, knee.quantity_label, knee.extensor_role
('N m', 'torque (N m)', 'knee extensor')
>>> JOINTS["elbow"].limit
25.0
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass

__all__ = ["DEFAULT_JOINT", "JOINTS", "QUANTITY_UNITS", "Joint", "joint_attrs", "joint_named",
           "recorded_quantity"]

QUANTITY_UNITS = {"force": "N", "torque": "N m"}
"""What a joint's sensor measures, and its unit."""

DEFAULT_JOINT = "elbow"
"""The joint of a configuration or a session file that names none (the paper's)."""


@dataclass(frozen=True)
class Joint:
    """One joint: its antagonist pair, what is measured, its posture and its defaults.

    Parameters
    ----------
    name : str
        Registry key, recorded in the session file (``[a-z][a-z0-9_]{0,31}``).
    extensor_muscles, flexor_muscles : str
        The muscle groups on the "extensor" (stimulator channel ``extensor_channel``,
        ``I_ext_mA``) and "flexor" (``I_flex_mA``) channels.
    extensor_role, flexor_role : str
        What each channel's action is called in labels (``knee extensor``,
        ``plantarflexor``).
    quantity : str
        ``force`` (N, at a strap ``lever_arm_m`` from the joint centre) or ``torque``
        (N m, from a dynamometer).
    lever_arm_m : float or None
        Force joints: the strap's distance from the joint centre (m); torque joints: None.
    sign : str
        Which direction is positive (always the extensor channel's action).
    posture : str
        The posture the defaults assume.
    limit : float
        Default interlock limit on |measured|, in :attr:`unit`.
    Fmin, Fmax, ceiling : float
        Default calibration thresholds and the ramp's end (``[calibration] Fmin_N``,
        ``Fmax_N``, ``force_ceiling_N``), in :attr:`unit`.
    sensor_range : float
        The measuring device's rated range, in :attr:`unit` (a limit above it never trips).
    extensor_channel, flexor_channel : int
        The stimulator channels (1-based) of each muscle group, for labels and set-up text.
    sources : tuple of str
        Where the defaults come from.
    """

    name: str
    extensor_muscles: str
    flexor_muscles: str
    extensor_role: str
    flexor_role: str
    quantity: str
    lever_arm_m: float | None
    sign: str
    posture: str
    limit: float
    Fmin: float
    Fmax: float
    ceiling: float
    sensor_range: float
    extensor_channel: int = 1
    flexor_channel: int = 2
    sources: tuple[str, ...] = ()

    def __post_init__(self):
        if not re.fullmatch(r"[a-z][a-z0-9_]{0,31}", str(self.name)):
            raise ValueError(f"joint name {self.name!r} must match [a-z][a-z0-9_]{{0,31}}")
        if self.quantity not in QUANTITY_UNITS:
            raise ValueError(f"joint {self.name}: quantity {self.quantity!r} is not one of "
                             f"{', '.join(QUANTITY_UNITS)}")
        if (self.quantity == "force") != (self.lever_arm_m is not None):
            raise ValueError(f"joint {self.name}: a force joint needs lever_arm_m (the strap's "
                             "distance from the joint centre), a torque joint has none")
        if self.lever_arm_m is not None and not (math.isfinite(self.lever_arm_m)
                                                 and 0 < self.lever_arm_m < 2):
            raise ValueError(f"joint {self.name}: lever_arm_m {self.lever_arm_m!r} is not in "
                             "(0, 2) m")
        values = (self.Fmin, self.Fmax, self.ceiling, self.limit, self.sensor_range)
        if not (all(math.isfinite(v) for v in values)
                and 0 < self.Fmin < self.Fmax < self.ceiling <= 1000.0
                and 0 < self.limit <= self.sensor_range):
            raise ValueError(f"joint {self.name}: needs 0 < Fmin < Fmax < ceiling <= 1000 and "
                             f"0 < limit <= sensor_range, got Fmin {self.Fmin:g}, Fmax "
                             f"{self.Fmax:g}, ceiling {self.ceiling:g}, limit {self.limit:g}, "
                             f"sensor_range {self.sensor_range:g}")
        if {self.extensor_channel, self.flexor_channel} != {1, 2}:
            raise ValueError(f"joint {self.name}: channels must be 1 and 2 (one each)")

    @property
    def unit(self) -> str:
        """``N`` or ``N m``."""
        return QUANTITY_UNITS[self.quantity]

    @property
    def quantity_label(self) -> str:
        """Axis label: ``force (N)``, ``torque (N m)``."""
        return f"{self.quantity} ({self.unit})"

    @property
    def title(self) -> str:
        """Title text: ``elbow force``, ``knee torque``."""
        return f"{self.name} {self.quantity}"

    def role(self, channel: str) -> str:
        """The role of channel ``ext`` / ``flex`` (``knee extensor``)."""
        return self.extensor_role if channel in ("ext", "extensor") else self.flexor_role

    def to_json(self) -> str:
        """The whole definition as JSON (recorded with a session: ``joint_json``)."""
        return json.dumps(asdict(self), sort_keys=True)

    def __repr__(self) -> str:
        return (f"Joint({self.name}: {self.extensor_muscles} vs {self.flexor_muscles}, "
                f"{self.quantity_label}, limit {self.limit:g} {self.unit})")


_HARBO = ("Harbo T, Brincks J, Andersen H. Maximal isokinetic and isometric muscle strength "
          "of major muscle groups related to age, body mass, height, and sex in 178 healthy "
          "subjects. Eur J Appl Physiol 2012;112:267-275 (isometric knee and ankle moments "
          "on a dynamometer)")
_MAFFIULETTI = ("Maffiuletti NA. Physiological and methodological considerations for the "
                "use of neuromuscular electrical stimulation. Eur J Appl Physiol "
                "2010;110:223-234 (evoked torque a fraction of the voluntary maximum)")
_BIODEX = ("Biodex System 4 Pro specifications: isometric torque up to 680 N m "
           "(dynamometer range)")

JOINTS: dict[str, Joint] = {
    "elbow": Joint(
        "elbow", "triceps brachii", "biceps brachii", "extensor", "flexor",
        quantity="force", lever_arm_m=0.25, sign="elbow extension positive",
        posture="seated, upper arm horizontal, elbow at 90 deg, wrist strapped to a 6-axis "
                "force sensor",
        limit=25.0, Fmin=0.5, Fmax=5.0, ceiling=10.0, sensor_range=500.0,
        sources=("the paper (Fmin 0.5 N, Fmax 5 N; reference/paper-fes-nms-identification"
                 ".txt)", "Leptrino PFS080YA501G6 rated 500 N per force axis")),
    "knee": Joint(
        "knee", "quadriceps", "hamstrings", "knee extensor", "knee flexor",
        quantity="torque", lever_arm_m=None, sign="knee extension positive",
        posture="seated on an isokinetic dynamometer (e.g. Biodex), hip ~85 deg, knee "
                "~60 deg of flexion, shank strapped to the dynamometer arm, held isometric",
        limit=150.0, Fmin=5.0, Fmax=50.0, ceiling=100.0, sensor_range=680.0,
        sources=(_HARBO + ": voluntary isometric knee extension ~150-300 N m in adults",
                 _MAFFIULETTI + ": a limit of 150 N m is above FES co-contraction torques "
                 "and below a healthy adult's maximum", _BIODEX)),
    "ankle": Joint(
        "ankle", "triceps surae", "tibialis anterior", "plantarflexor", "dorsiflexor",
        quantity="torque", lever_arm_m=None, sign="plantarflexion positive",
        posture="seated or prone on a dynamometer, knee extended or 90 deg, ankle neutral "
                "(0 deg), foot strapped to the footplate, held isometric",
        limit=80.0, Fmin=2.0, Fmax=20.0, ceiling=40.0, sensor_range=680.0,
        sources=(_HARBO + ": voluntary isometric plantarflexion ~100-200 N m, dorsiflexion "
                 "~30-50 N m in adults", _MAFFIULETTI + ": a limit of 80 N m stays below a "
                 "healthy adult's plantarflexion maximum", _BIODEX)),
}
"""The joints nmsid knows, by name. A lab adds one with one entry here (``docs/joints.md``)."""


def joint_named(name: str) -> Joint:
    """The registered joint ``name``.

    Raises
    ------
    KeyError
        With the valid names (callers turn it into their own one-line error).
    """
    try:
        return JOINTS[str(name)]
    except KeyError:
        raise KeyError(f"joint {name!r} is unknown; valid: {', '.join(JOINTS)}") from None


def joint_attrs(joint: Joint) -> dict:
    """The optional root attributes a session records for its joint."""
    return {"joint": joint.name, "measured_quantity": joint.quantity,
            "measured_unit": joint.unit, "joint_json": joint.to_json()}


def recorded_quantity(attrs) -> tuple[str, str, str]:
    """``(joint, quantity, unit)`` a session file records (root attributes ``attrs``); a
    file without them is an elbow force session: ``("elbow", "force", "N")``. Unknown
    values are returned as text (a reader labels with them; it never runs anything by
    them), an unknown quantity as ``force``."""
    joint = str(attrs.get("joint") or DEFAULT_JOINT)
    quantity = str(attrs.get("measured_quantity") or "force")
    if quantity not in QUANTITY_UNITS:
        quantity = "force"
    return joint, quantity, QUANTITY_UNITS[quantity]
