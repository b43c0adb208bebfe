"""``nmsid control``: a force controller from the twin, and the report of tracking sessions.

    nmsid control design TWIN.json --out DIR [--sE X] [--update-hz F] [--learning-gain G]
    nmsid control report SESSION.h5 --out DIR

Registration only (argparse); the handlers are in :mod:`nmsid.cli.control_command`.
Tracking trials run with ``nmsid run --track DIR/controller.json`` (``docs/control.md``).
"""

from __future__ import annotations


def register(sub) -> None:
    """Add the ``control`` sub-command and its two actions."""
    p = sub.add_parser("control", help="closed-loop force control: design a controller from "
                                       "the twin, report tracking sessions",
                       description="Design a force controller from a twin (feedforward "
                                   "inverse of the twin, Smith predictor, PI with "
                                   "anti-windup), or report a tracking session (nmsid run "
                                   "--track) against its twin-free baseline.")
    actions = p.add_subparsers(dest="control_action", metavar="ACTION", required=True)
    d = actions.add_parser("design", help="controller.json and a design report from a twin",
                           description="Write DIR/controller.json and DIR/design.md: the "
                                       "controller, its limits, and per sE its stability "
                                       "margins and predicted tracking.")
    d.add_argument("twin", metavar="TWIN.json", help="the twin (nmsid identify / twin)")
    d.add_argument("--out", required=True, metavar="DIR", help="folder to write (must not "
                   "exist unless --force)")
    d.add_argument("--force", action="store_true", help="replace an existing --out folder")
    d.add_argument("--sE", type=float, metavar="X", help="operating co-activation (default: "
                   "where the twin's wn peaks)")
    d.add_argument("--update-hz", type=float, default=200.0, metavar="F",
                   help="stimulation update rate of the loop (default 200)")
    d.add_argument("--lambda-s", type=float, metavar="S",
                   help="closed-loop time constant of the PI (default: from the loop delay)")
    d.add_argument("--learning-gain", type=float, default=0.0, metavar="G",
                   help="trial-to-trial learning of a repeated target, 0-1 (default 0: off)")
    d.set_defaults(handler="nmsid.cli.control_command:design")
    r = actions.add_parser("report", help="tracking error per trial and per controller",
                           description="Write DIR/tracking.json, DIR/report.md and "
                                       "DIR/figures/: RMSE in % of the target range, "
                                       "overshoot and settling time per trial and per "
                                       "controller (twin vs baseline). Several sessions: "
                                       "one such folder per session, DIR/<session name>/.")
    r.add_argument("session", metavar="SESSION.h5", nargs="+",
                   help="one or more sessions of nmsid run --track")
    r.add_argument("--out", required=True, metavar="DIR", help="folder to write (must not "
                   "exist unless --force)")
    r.add_argument("--force", action="store_true", help="replace an existing --out folder")
    r.set_defaults(handler="nmsid.cli.control_command:report")
