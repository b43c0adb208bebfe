"""``nmsid gui``: the operator window (registration only; Qt is imported when it runs)."""

from __future__ import annotations

from pathlib import Path

from nmsid.cli.arguments import input_file, output_path, seed
from nmsid.protocols.config import PARTICIPANT_MODELS
from nmsid.protocols.joints import JOINTS
from nmsid.rig.qt_platform import check_xcb


def register(sub) -> None:
    p = sub.add_parser(
        "gui", help="operator window: set up, calibrate, run and watch a session with a "
        "big E-STOP (docs/gui.md)")
    p.add_argument("--backend", choices=("sim", "hw"), default="sim",
                   help="simulated rig (default) or the hardware chain")
    p.add_argument("--config", metavar="FILE", type=input_file,
                   help="protocol configuration (TOML); default: built-in (15 sE x 3 repeats)")
    p.add_argument("--hw-config", metavar="FILE", type=input_file,
                   help="hardware chain configuration (with --backend hw)")
    p.add_argument("--participant", metavar="P", help="participant code "
                   "([A-Za-z0-9_-]{1,64})")
    p.add_argument("--out", metavar="FILE", type=output_path, help="session file to write (never "
                   "overwritten; an unfinished one is offered for resume); default "
                   "sessions/<participant>-<UTC time>.h5")
    p.add_argument("--seed", type=seed, metavar="N", help="schedule randomisation seed, "
                   "0 ... 2**63-1 as in `nmsid run` (default: drawn and recorded)")
    p.add_argument("--joint", choices=tuple(JOINTS), metavar="JOINT",
                   help="the joint the session drives: " + ", ".join(JOINTS) + " (as "
                        "`nmsid run --joint`; the set-up panel's Joint)")
    p.add_argument("--participant-model", choices=PARTICIPANT_MODELS, metavar="MODEL",
                   help="sim: the simulated participant: " + ", ".join(PARTICIPANT_MODELS)
                        + " (as `nmsid run --participant-model`; the set-up panel's "
                        "Simulated participant; with --joint knee|ankle musculoskeletal is "
                        "MuJoCo's MyoLeg). A lab's plug-in (package.module:factory) runs "
                        "with `nmsid run` only")
    p.add_argument("--fast", action="store_true", help="run the simulator as fast as "
                   "possible instead of in real time")
    p.add_argument("--script", metavar="SCRIPT", help="drive the window from a script "
                   "file, or 'demo' for the built-in one (docs/gui.md)")
    p.add_argument("--screenshot", metavar="PATH", help="after the scripted run, save a "
                   "PNG of the window here and quit")
    p.set_defaults(handler="nmsid.cli.gui:run")


def run(args) -> int:
    # before Qt loads: a missing X11 library is one line naming the package, not a Qt abort
    check_xcb()
    # lazy: PySide6 and pyqtgraph (the optional gui extra) load only when the window opens
    from nmsid.rig.gui.app import GuiOptions, run_gui

    options = GuiOptions(
        backend=args.backend,
        config=Path(args.config) if args.config else None,
        hw_config=Path(args.hw_config) if args.hw_config else None,
        participant=args.participant,
        out=Path(args.out) if args.out else None,
        seed=args.seed,
        joint=args.joint,
        participant_model=args.participant_model,
        realtime=not args.fast,
        script=args.script,
        screenshot=Path(args.screenshot) if args.screenshot else None)
    return run_gui(options)
