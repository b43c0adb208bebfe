"""``nmsid run`` (a whole session, headless) and ``nmsid recover FILE``.

``nmsid run --backend sim`` runs calibration and the schedule on the simulated rig as fast
as possible (``--realtime`` paces it like hardware), prints a progress line per trial, then
runs the identification on the file. Ctrl+C is an E-stop: output to zero, the session ends
cleanly and the file stays valid; ``--resume FILE`` continues it.

Registration only (argparse): ``nmsid --help`` imports nothing else; the handlers are in
:mod:`nmsid.cli.run_command`.
"""

from __future__ import annotations

import argparse

from nmsid.cli.arguments import (
    folder_to_write,
    input_file,
    output_path,
    session_to_continue,
)
from nmsid.protocols.joints import JOINTS

#: Seeds are stored as 64-bit signed integers in the session file.
SEED_MAX = 2 ** 63 - 1


def _seed(text: str) -> int:
    """argparse type of a seed: a whole number in [0, 2**63 - 1]."""
    try:
        value = int(text, 10)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number; give a seed in "
                                         f"[0, {SEED_MAX}]") from None
    if not 0 <= value <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"{value} is outside [0, {SEED_MAX}] (seeds are "
                                         "stored as 64-bit integers)")
    return value


def _fraction(text: str) -> float:
    """argparse type of rE: a number in [0, 1]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number; give rE in [0, 1]") \
            from None
    if not 0.0 <= value <= 1.0:    # also refuses nan
        raise argparse.ArgumentTypeError(f"{text} is outside [0, 1] (rE = Ie / sE)")
    return value


def register(sub) -> None:
    p = sub.add_parser("run", help="run a whole session (calibration + schedule) headless, "
                       "then identify it",
                       description="Run calibration and the trial schedule on the simulated "
                       "rig (--backend sim, fast clock by default) or on hardware (--backend "
                       "hw), write the session file, then run the identification.")
    p.add_argument("--backend", choices=("sim", "hw"), default="sim",
                   help="sim: the simulated rig; hw: the hardware in --hw-config")
    p.add_argument("--participant", metavar="CODE",
                   help="participant code [A-Za-z0-9_-]{1,64} (overrides the config)")
    p.add_argument("--config", metavar="FILE", type=input_file,
                   help="protocol configuration (TOML)")
    p.add_argument("--joint", choices=tuple(JOINTS), metavar="JOINT",
                   help="the joint the session drives: " + ", ".join(JOINTS) + " (its "
                        "labels, unit and default limits, docs/joints.md; overrides the "
                        "config's joint; default elbow)")
    p.add_argument("--seed", type=_seed, metavar="N",
                   help="schedule randomisation seed (overrides the config; default: drawn "
                        "and recorded)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--out", metavar="FILE", type=output_path,
                     help="session file to write (must not exist)")
    out.add_argument("--outdir", metavar="DIR", type=folder_to_write,
                     help="folder for <participant>-<UTC time>.h5 (default: sessions)")
    out.add_argument("--resume", metavar="FILE", type=session_to_continue,
                     help="continue this session (recovering it first if needed): skip its "
                          "completed trials, re-run its aborted ones; on the rig it started "
                          "on (same --backend, the same --hw-config file, the recorded "
                          "simulated participant and seed), else refused")
    p.add_argument("--realtime", action="store_true",
                   help="sim: pace the simulation in real time (default: as fast as possible)")
    p.add_argument("--hw-config", metavar="FILE", type=input_file,
                   help="hw: the rig's hardware configuration (refused without --backend "
                        "hw: a hardware file never runs a simulated session; its "
                        "acquisition.fs_Hz must equal the protocol's fs_Hz)")
    p.add_argument("--participant-model", metavar="MODEL",
                   help="sim: the virtual participant: the paper's second-order model "
                        "(template, default), MyoSuite's MuJoCo elbow under FES, or with "
                        "--joint knee|ankle MuJoCo's MyoLeg on a dynamometer "
                        "(musculoskeletal; needs the 'mujoco' extra) or a lab's own model "
                        "package.module:factory (docs/control.md); overrides the "
                        "config's [participant] model")
    p.add_argument("--sim-seed", type=_seed, metavar="N",
                   help="sim: seed of the virtual participant and its noise (default: from "
                        "the participant code; on --resume the recorded one)")
    p.add_argument("--resume-after-reconnect", action="store_true",
                   help="hw: after a USB glitch between trials, resume as soon as the device "
                        "is reconnected (default: ask on a terminal, else end the session "
                        "for --resume)")
    p.add_argument("--lsl", action="store_true",
                   help="publish force, commanded currents and event markers as Lab "
                        "Streaming Layer streams (needs pylsl: the 'lsl' extra; "
                        "docs/lsl.md); a failing stream never stops the session; "
                        "the protocol file's [lsl] publish = true is the same")
    p.add_argument("--lsl-record", action="append", metavar="NAME_OR_TYPE",
                   help="record this LSL stream (by name or type: EMG, Markers, MoCap; "
                        "repeatable) into the session file under /lsl with its clock "
                        "offset (docs/lsl.md); replaces the protocol file's [lsl] "
                        "record list")
    p.add_argument("--allow-weakened-safety", action="store_true",
                   help="confirm settings that weaken the interlock (a trip_on_* = false, a "
                        "force_limit_N above the sensor's range); recorded in the session")
    p.add_argument("--track", metavar="CONTROLLER.json", type=input_file,
                   help="run force-tracking trials instead of the identification schedule: "
                        "the controller of nmsid control design against a relay-tuned PID "
                        "baseline, interleaved (docs/control.md); needs a stimulator that "
                        "streams (the simulated one does)")
    p.add_argument("--target", metavar="FILE.csv", type=input_file,
                   help="with --track: track this target (columns t_s,force_N) instead of "
                        "the default steps, ramp and sines")
    p.add_argument("--cocontraction", type=_fraction, metavar="RE",
                   help="run a co-contraction sweep instead of the identification "
                        "schedule: the protocol's sE levels in their listed order, each "
                        "held for steady_s + chirp_s at this fixed rE, the sweep repeated "
                        "'repeats' times (docs/joints.md); not identified")
    p.add_argument("--no-identify", action="store_true",
                   help="do not run the identification after the schedule")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(handler="nmsid.cli.run_command:run")

    r = sub.add_parser("recover", help="rebuild a session file from its journal after a crash",
                       description="Bring a session file in line with its write-ahead journal "
                       "(<file>.journal/): append trials missing from it, or rebuild a damaged "
                       "file (kept aside as <file>.damaged-<time>). The trial in progress when "
                       "the program ended becomes an aborted trial.")
    r.add_argument("file", metavar="FILE", type=session_to_continue, help="the session file (.h5)")
    r.set_defaults(handler="nmsid.cli.run_command:recover_cmd")
