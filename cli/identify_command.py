"""The handlers of ``nmsid identify`` and ``nmsid twin simulate`` (registered by
:mod:`nmsid.cli.identify`)."""

from __future__ import annotations

import csv

import numpy as np

from nmsid.analysis.run import run_identification, summary_line
from nmsid.analysis.settings import IdentificationSettings
from nmsid.analysis.twin import Twin


def settings_from_args(args):
    """IdentificationSettings from the ``identify`` options."""
    return IdentificationSettings(
        detrend=not args.no_detrend, window_start_s=args.window_start_s,
        window_end_s=args.window_end_s, savgol_window=args.savgol_window,
        savgol_order=args.savgol_order, lowpass_Hz=args.lowpass_Hz,
        butter_order=args.butter_order, zero_phase=not args.causal,
        prefilter_input=not args.no_input_prefilter,
        fit_fs_Hz=args.fit_fs_Hz if args.lowpass_Hz is not None else None,
        input_hold=args.input_hold, estimate_trend=not args.no_trend_term,
        iqr_k=args.iqr_k, aicc_count_noise_variance=args.aicc_count_noise,
        qc=not getattr(args, "no_qc", False))


def run_identify(args) -> int:
    """Handler of ``nmsid identify``."""
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
