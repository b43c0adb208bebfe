"""``nmsid identify`` and ``nmsid twin simulate``.

    nmsid identify SESSION.h5 [SESSION.h5 ...] --out DIR [--no-figures] [settings]
    nmsid twin simulate TWIN.json --sE 0.6 --rE-chirp --out force.csv
    nmsid twin simulate TWIN.json --input input.csv --out force.csv
    nmsid twin simulate LEG1.json --joint knee --sE 0.6 --rE-chirp --out torque.csv
    nmsid twin export TWIN.json --fmu --out P01.fmu

Registration only (argparse); the handlers are in :mod:`nmsid.cli.identify_command`.
"""

from __future__ import annotations

import argparse

from nmsid.cli.arguments import folder_to_write, input_file, output_path


def _float_or_none(text: str):
    if text.lower() in ("none", "off", "no"):
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number or 'none'") from None


def _int_or_none(text: str):
    if text.lower() in ("none", "off", "no"):
        return None
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer or 'none'") from None


def register(sub) -> None:
    """Add the ``identify`` and ``twin`` sub-commands."""
    p = sub.add_parser(
        "identify", help="identify the second-order model per sE and select models across sE",
        description="Identify G(s) = Kp wn^2/(s^2 + 2 zeta wn s + wn^2) from rE to force "
                    "for every sE level of each session, select linear / quadratic / "
                    "exponential curves of each parameter by AICc, write the twin. Several "
                    "sessions give the group analysis. See docs/identification.md.")
    p.add_argument("sessions", nargs="+", metavar="SESSION.h5", type=input_file,
                   help="session file(s)")
    p.add_argument("--out", required=True, metavar="DIR", type=folder_to_write,
                   help="output folder")
    p.add_argument("--force", action="store_true",
                   help="replace an existing --out folder (atomically; never one holding "
                        "a session file)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-qc", action="store_true",
                   help="average every completed repeat as the paper does (default: only "
                        "the trials the quality control keeps; see `nmsid qc`)")
    g = p.add_argument_group("settings (defaults follow the paper; see docs/identification.md)")
    g.add_argument("--lowpass-Hz", type=_float_or_none, default=25.0, metavar="F|none",
                   help="Butterworth low-pass cut-off of force (and rE), none to skip "
                        "(default %(default)s Hz, the paper's)")
    g.add_argument("--butter-order", type=int, default=4, metavar="N",
                   help="order of that low-pass, 1-12 (default %(default)s)")
    g.add_argument("--savgol-window", type=_int_or_none, default=41, metavar="N|none",
                   help="Savitzky-Golay window in samples, odd, none to skip (default "
                        "%(default)s, the paper's)")
    g.add_argument("--savgol-order", type=int, default=3, metavar="N",
                   help="Savitzky-Golay polynomial order (default %(default)s, the paper's)")
    g.add_argument("--causal", action="store_true",
                   help="causal (one-pass) low-pass instead of zero-phase (adds delay; "
                        "default zero-phase)")
    g.add_argument("--no-input-prefilter", action="store_true",
                   help="do not apply the force filters to rE (default: applied, so both "
                        "sides of the fit see the same filter)")
    g.add_argument("--no-detrend", action="store_true",
                   help="skip the linear detrend of each raw trial (default: detrended, as "
                        "the paper)")
    g.add_argument("--no-trend-term", action="store_true",
                   help="do not estimate an output ramp along with the offset (default: "
                        "estimated)")
    g.add_argument("--fit-fs-Hz", type=_float_or_none, default=200.0, metavar="F|none",
                   help="rate of the fit after decimation, at least 4x the low-pass "
                        "(default %(default)s Hz; none = the raw rate)")
    g.add_argument("--window-start-s", type=float, default=None, metavar="S",
                   help="start of the analysed window, s after stimulation onset (default: "
                        "the trial's steady_s, 5 s in the paper)")
    g.add_argument("--window-end-s", type=float, default=None, metavar="S",
                   help="end of the analysed window (default: steady_s + chirp_s, or the "
                        "end of the data)")
    g.add_argument("--input-hold", choices=("smooth", "linear"), default="smooth",
                   help="how the model sees rE between samples at the fit rate (default "
                        "%(default)s)")
    g.add_argument("--iqr-k", type=float, default=1.5, metavar="K",
                   help="outlier fence of the model selection, [Q1 - k IQR, Q3 + k IQR] "
                        "(default %(default)s, the paper's)")
    g.add_argument("--aicc-count-noise", action="store_true",
                   help="count the noise variance as a parameter in AICc (default: not "
                        "counted)")
    p.set_defaults(handler="nmsid.cli.identify_command:run_identify")

    t = sub.add_parser("twin", help="use a twin file (twin.json)",
                       description="Use a digital twin written by `nmsid identify`.")
    tsub = t.add_subparsers(dest="twin_command", metavar="ACTION")
    sim = tsub.add_parser(
        "simulate", help="predict force (or a joint's torque) for an rE(t) and sE",
        description="Predict the force of the twin (a torque joint's twin: its torque in "
                    "N m) for an input rE(t) at a constant sE (--sE) or a per-sample sE (an "
                    "'sE' column of --input). A twin file of several joints: --joint says "
                    "which joint's twin. See docs/twin-file.md.")
    sim.add_argument("twin", metavar="TWIN.json", type=input_file)
    sim.add_argument("--joint", default=None, metavar="NAME",
                     help="the joint whose twin to simulate, in a twin file of several "
                          "joints (default: the file's one twin)")
    src = sim.add_mutually_exclusive_group(required=True)
    src.add_argument("--rE-chirp", action="store_true",
                     help="the paper's input: steady rE = 0.5, then a 0.5 + 0.5 sin chirp")
    src.add_argument("--input", metavar="CSV",
                     help="CSV with a header: column rE, optional sE and t_s")
    sim.add_argument("--sE", type=float, default=None, help="constant sE")
    sim.add_argument("--fs-Hz", type=float, default=None,
                     help="sampling rate (default 2000, or from the t_s column)")
    sim.add_argument("--steady-s", type=float, default=5.0)
    sim.add_argument("--chirp-s", type=float, default=10.0)
    sim.add_argument("--f0-Hz", type=float, default=1.0)
    sim.add_argument("--f1-Hz", type=float, default=10.0)
    sim.add_argument("--extrapolate", action="store_true",
                     help="evaluate the curves outside the tested sE range (default: clip)")
    sim.add_argument("--without-effects", action="store_true",
                     help="simulate the parameter curves alone when the twin lists effects "
                          "(by default its effects are simulated as its FMU steps them; an "
                          "effect that cannot be, such as baseline_drift, is refused)")
    sim.add_argument("--out", required=True, metavar="CSV", type=output_path)
    sim.add_argument("--force", action="store_true",
                     help="replace an existing --out file (never a session file)")
    sim.set_defaults(handler="nmsid.cli.identify_command:run_twin_simulate")
    exp = tsub.add_parser(
        "export", help="write the twin as an FMI 2.0 FMU (co-simulation + model exchange)",
        description="Write the twin as a Functional Mock-up Unit (FMI 2.0, co-simulation and "
                    "model exchange): C sources plus a binary for this platform built with "
                    "the system's C compiler (cc, gcc or clang; on Windows cl or MinGW gcc; "
                    "or $CC). See docs/fmu.md.")
    add_fmu_export_arguments(exp, fmu_flag=True)
    t.set_defaults(handler="nmsid.cli.identify_command:run_twin_help")


def add_fmu_export_arguments(parser: argparse.ArgumentParser, *, fmu_flag: bool) -> None:
    """The FMU export's arguments, for ``nmsid twin export --fmu`` and ``nmsid export fmu``
    (the same handler)."""
    parser.add_argument("twin", metavar="TWIN.json", type=input_file)
    if fmu_flag:
        parser.add_argument("--fmu", action="store_true", required=True,
                            help="the format to write (FMI 2.0 FMU; the only one today)")
    parser.add_argument("--out", required=True, metavar="P01.fmu", type=output_path)
    parser.add_argument("--force", action="store_true", help="replace an existing --out")
    parser.add_argument("--extrapolate", action="store_true",
                        help="start value of the FMU's extrapolate parameter(s): evaluate "
                             "the curves outside the tested sE range (default: clamp sE)")
    parser.add_argument("--sources-only", action="store_true",
                        help="no binary: C sources only (the importer builds them)")
    parser.set_defaults(handler="nmsid.cli.twin_export_command:run_twin_export")
