"""``nmsid identify`` and ``nmsid twin simulate``.

    nmsid identify SESSION.h5 [SESSION.h5 ...] --out DIR [--no-figures] [settings]
    nmsid twin simulate TWIN.json --sE 0.6 --rE-chirp --out force.csv
    nmsid twin simulate TWIN.json --input input.csv --out force.csv

Registering imports nothing heavy; the handlers import the analysis when they run.
"""

from __future__ import annotations

import argparse


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
    p.add_argument("sessions", nargs="+", metavar="SESSION.h5", help="session file(s)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    g = p.add_argument_group("settings (defaults follow the paper; see docs/identification.md)")
    g.add_argument("--lowpass-Hz", type=_float_or_none, default=25.0, metavar="F|none")
    g.add_argument("--butter-order", type=int, default=4, metavar="N")
    g.add_argument("--savgol-window", type=_int_or_none, default=41, metavar="N|none")
    g.add_argument("--savgol-order", type=int, default=3, metavar="N")
    g.add_argument("--causal", action="store_true",
                   help="causal (one-pass) low-pass instead of zero-phase (adds delay)")
    g.add_argument("--no-input-prefilter", action="store_true",
                   help="do not apply the force filters to rE")
    g.add_argument("--no-detrend", action="store_true", help="skip the linear detrend")
    g.add_argument("--no-trend-term", action="store_true",
                   help="do not estimate an output ramp along with the offset")
    g.add_argument("--fit-fs-Hz", type=_float_or_none, default=200.0, metavar="F|none",
                   help="rate of the fit after decimation (default 200; none = raw rate)")
    g.add_argument("--window-start-s", type=float, default=None, metavar="S")
    g.add_argument("--window-end-s", type=float, default=None, metavar="S")
    g.add_argument("--input-hold", choices=("smooth", "linear"), default="smooth")
    g.add_argument("--iqr-k", type=float, default=1.5, metavar="K")
    g.add_argument("--aicc-count-noise", action="store_true",
                   help="count the noise variance as a parameter in AICc")
    p.set_defaults(handler="analysis.cli_identify:run_identify")

    t = sub.add_parser("twin", help="use a twin file (twin.json)",
                       description="Use a digital twin written by `nmsid identify`.")
    tsub = t.add_subparsers(dest="twin_command", metavar="ACTION")
    sim = tsub.add_parser(
        "simulate", help="predict force for an rE(t) and sE",
        description="Predict the force of the twin for an input rE(t) at a constant sE "
                    "(--sE) or a per-sample sE (an 'sE' column of --input).")
    sim.add_argument("twin", metavar="TWIN.json")
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
    sim.add_argument("--out", required=True, metavar="CSV")
    sim.set_defaults(handler="analysis.cli_identify:run_twin_simulate")
    t.set_defaults(handler="analysis.cli_identify:run_twin_help")


def settings_from_args(args):
    """IdentificationSettings from the ``identify`` options."""
    from analysis.settings import IdentificationSettings

    return IdentificationSettings(
        detrend=not args.no_detrend, window_start_s=args.window_start_s,
        window_end_s=args.window_end_s, savgol_window=args.savgol_window,
        savgol_order=args.savgol_order, lowpass_Hz=args.lowpass_Hz,
        butter_order=args.butter_order, zero_phase=not args.causal,
        prefilter_input=not args.no_input_prefilter,
        fit_fs_Hz=args.fit_fs_Hz if args.lowpass_Hz is not None else None,
        input_hold=args.input_hold, estimate_trend=not args.no_trend_term,
        iqr_k=args.iqr_k, aicc_count_noise_variance=args.aicc_count_noise)


def run_identify(args) -> int:
    """Handler of ``nmsid identify``."""
    from analysis.run import run_identification, summary_line

    settings = settings_from_args(args)
    out = run_identification(args.sessions, args.out, settings, figures=not args.no_figures)
    print(out.tables_text)
    if out.problems:
        print(f"\n{len(out.problems)} problem(s) (also in {args.out}/problems.txt):")
        for p in out.problems:
            print(f"  - {p}")
    print(f"\n{summary_line(out)}; outputs in {args.out}")
    return 0


def run_twin_help(args) -> int:
    print("usage: nmsid twin simulate TWIN.json (--rE-chirp | --input CSV) [--sE X] --out CSV")
    return 2


def _read_input_csv(path: str):
    import csv

    import numpy as np

    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise OSError(f"{path}: cannot read the input CSV ({exc.strerror or exc})") from None
    if len(rows) < 3:
        raise ValueError(f"{path}: needs a header row and at least 2 samples")
    header = [h.strip() for h in rows[0]]
    if "rE" not in header:
        raise ValueError(f"{path}: header {header} has no 'rE' column (columns: rE, "
                         "optional sE and t_s)")
    cols = {}
    for name in ("rE", "sE", "t_s"):
        if name in header:
            j = header.index(name)
            try:
                cols[name] = np.array([float(r[j]) for r in rows[1:] if r], dtype=float)
            except (ValueError, IndexError):
                raise ValueError(f"{path}: column {name!r} holds a non-number") from None
    return cols


def run_twin_simulate(args) -> int:
    """Handler of ``nmsid twin simulate``."""
    import numpy as np

    from analysis.twin import Twin

    twin = Twin.load(args.twin)
    if args.rE_chirp:
        fs = args.fs_Hz or 2000.0
        n = int(round((args.steady_s + args.chirp_s) * fs))
        t = np.arange(n) / fs
        tc = np.clip(t - args.steady_s, 0.0, None)
        if not (args.f1_Hz > 0 and args.f0_Hz > 0 and args.f1_Hz != args.f0_Hz):
            raise ValueError(f"--f0-Hz {args.f0_Hz} and --f1-Hz {args.f1_Hz} must be "
                             "different positive frequencies")
        k = args.f1_Hz / args.f0_Hz
        phi = 2 * np.pi * args.f0_Hz * args.chirp_s / np.log(k) * (k ** (tc / args.chirp_s) - 1)
        rE = np.where(t < args.steady_s, 0.5, 0.5 + 0.5 * np.sin(phi))
        sE = None
    else:
        cols = _read_input_csv(args.input)
        rE = cols["rE"]
        sE = cols.get("sE")
        if args.fs_Hz:
            fs = args.fs_Hz
        elif "t_s" in cols and len(cols["t_s"]) > 1:
            dt = np.diff(cols["t_s"])
            if not np.all(dt > 0) or np.ptp(dt) > 1e-6 * np.mean(dt):
                raise ValueError(f"{args.input}: t_s must be uniformly increasing")
            fs = 1.0 / float(np.mean(dt))
        else:
            fs = 2000.0
        t = np.arange(len(rE)) / fs
    if args.sE is not None:
        sE = np.full(len(rE), args.sE)
    if sE is None:
        raise ValueError("give --sE, or an 'sE' column in the --input CSV")
    force = twin.simulate(rE, sE, fs, clip=not args.extrapolate)
    with open(args.out, "w", encoding="utf-8") as fh:
        fh.write("t_s,rE,sE,force_N\n")
        for row in zip(t, rE, sE, force):
            fh.write(f"{row[0]:.6f},{row[1]:.9g},{row[2]:.9g},{row[3]:.9g}\n")
    print(f"wrote {len(rE)} samples at {fs:g} Hz to {args.out} "
          f"(force {force.min():.3f} to {force.max():.3f} N)")
    return 0
