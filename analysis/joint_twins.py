"""One participant's twin of several joints: one twin per joint in one file.

A twin file (``docs/twin-file.md``) may hold, instead of one twin's items at the top, an
optional ``joints`` mapping from joint name to that joint's twin (each the items of a
one-joint twin: ``calibration``, ``sE_range``, ``parameters``, ``offset_N``, ``effects``,
``measured_quantity``, ...)::

    {"format": "nmsid-twin", "format_version": 1, "participant": "P01",
     "joints": {"elbow": {...}, "knee": {...}, "ankle": {...}}}

Each joint's twin is read with the same checks as a one-joint file
(:meth:`nmsid.analysis.twin.Twin.from_dict`) and simulates on its own
(:meth:`Twin.simulate`: rE and sE of that joint in, its force or torque out). A reader that
does not know ``joints`` refuses such a file in one line (no top-level ``parameters``);
:func:`load_joint_twins` reads both kinds (a one-joint file gives one entry).

Examples
--------
>>> from nmsid.analysis.twin import Curve, Twin
>>> c = {"Kp": Curve("constant", [5.0]), "wn_rad_s": Curve("constant", [30.0]),
...      "zeta": Curve("constant", [0.7])}
>>> d = joint_twins_to_dict([Twin("P01", c, (0.3, 1.0)),
...                          Twin("P01", c, (0.3, 1.0), joint="knee",
...                               measured_quantity="torque", measured_unit="N m")])
>>> sorted(d["joints"]), d["joints"]["knee"]["measured_unit"]
(['elbow', 'knee'], 'N m')
"""

from __future__ import annotations

import os
from pathlib import Path

from nmsid.analysis.errors import TwinFileError, TwinInputError
from nmsid.analysis.twin import FORMAT, FORMAT_VERSION, Twin
from nmsid.sim_backends.twin_file import TwinReadError, read_twin_file, write_twin_file

__all__ = ["joint_twin", "joint_twins_to_dict", "load_joint_twins", "pick_joint",
           "save_joint_twins"]

_HEAD = ("format", "format_version", "participant")


def joint_twins_to_dict(twins) -> dict:
    """The file content of ``twins`` (one per joint, one participant).

    Raises
    ------
    TwinFileError
        Two twins of one joint, twins of different participants, or none.
    """
    twins = list(twins)
    if not twins:
        raise TwinFileError("<twins>", "no twin to write")
    names = [t.joint for t in twins]
    if len(set(names)) != len(names):
        raise TwinFileError("<twins>", f"joints {names}: one twin per joint")
    who = {t.participant for t in twins}
    if len(who) != 1:
        raise TwinFileError("<twins>", f"twins of participants {sorted(who)}: a file holds "
                                       "one participant's joints")
    joints = {}
    for t in twins:
        body = {k: v for k, v in t.to_dict().items() if k not in _HEAD}
        body.update(joint=t.joint, measured_quantity=t.measured_quantity,
                    measured_unit=t.measured_unit)
        joints[t.joint] = body
    return {"format": FORMAT, "format_version": FORMAT_VERSION,
            "participant": twins[0].participant, "joints": joints}


def save_joint_twins(path: str | os.PathLike, twins) -> Path:
    """Write one participant's twins (one per joint) as one file."""
    write_twin_file(path, joint_twins_to_dict(twins))
    return Path(path)


def load_joint_twins(path: str | os.PathLike) -> dict[str, Twin]:
    """Every joint's twin in a file, by joint name (a one-joint file: its one twin).

    Raises
    ------
    TwinFileError
        Naming the file and the item (``joints.knee.parameters.Kp is missing``).
    """
    p = Path(path)
    try:
        data = read_twin_file(p)
    except TwinReadError as exc:
        raise TwinFileError(p, exc.problem) from None
    if not isinstance(data, dict) or "joints" not in data:
        twin = Twin.from_dict(data, p)
        return {twin.joint: twin}
    joints = data["joints"]
    if not isinstance(joints, dict) or not joints:
        raise TwinFileError(p, "joints must be a non-empty object {joint name: twin}")
    out = {}
    for name, body in joints.items():
        if not isinstance(body, dict):
            raise TwinFileError(p, f"joints.{name} is not a JSON object")
        if body.get("joint", name) != name:
            raise TwinFileError(p, f"joints.{name} says joint {body.get('joint')!r}")
        head = {k: data.get(k) for k in _HEAD}
        try:
            out[name] = Twin.from_dict({**body, **head, "joint": name}, p)
        except TwinFileError as exc:
            raise TwinFileError(p, f"joints.{name}: {exc.problem}") from None
    return out


def pick_joint(twins: dict[str, Twin], joint: str | None, where, *,
               how: str = "--joint NAME") -> Twin:
    """The twin of ``joint`` among a file's (:func:`load_joint_twins`); ``None``: the one
    twin of a file that holds one.

    Parameters
    ----------
    twins : dict
        Joint name -> twin, as :func:`load_joint_twins` gives them.
    joint : str or None
        The joint wanted.
    where : path or str
        The file, for the message.
    how : str
        How the user names a joint, for the message (``--joint NAME``, ``joint=``).

    Raises
    ------
    TwinInputError
        One line naming the file, the joint asked and the joints it holds.

    Examples
    --------
    >>> from nmsid.analysis.twin import Curve
    >>> c = {"Kp": Curve("constant", [5.0]), "wn_rad_s": Curve("constant", [30.0]),
    ...      "zeta": Curve("constant", [0.7])}
    >>> twins = {"elbow": Twin("P01", c, (0.3, 1.0)),
    ...          "knee": Twin("P01", c, (0.3, 1.0), joint="knee")}
    >>> pick_joint(twins, "knee", "P01.json").joint
    'knee'
    >>> pick_joint(twins, "hip", "P01.json")
    Traceback (most recent call last):
    ...
    nmsid.analysis.errors.TwinInputError: P01.json has no twin of joint 'hip'; it holds elbow, knee
    """
    held = ", ".join(twins)
    if joint is None:
        if len(twins) == 1:
            return next(iter(twins.values()))
        raise TwinInputError(f"{where} holds the twins of joints {held}: say which one "
                             f"({how})")
    if joint not in twins:
        raise TwinInputError(f"{where} has no twin of joint {joint!r}; it holds {held}")
    return twins[joint]


def joint_twin(path: str | os.PathLike, joint: str | None = None, *,
               how: str = "--joint NAME") -> Twin:
    """The twin of one joint in a twin file of one or several joints (:func:`pick_joint`:
    ``None`` for a file of one twin)."""
    return pick_joint(load_joint_twins(path), joint, path, how=how)
