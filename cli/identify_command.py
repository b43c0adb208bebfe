"""The handlers of ``nmsid identify`` and ``nmsid twin simulate`` (registered by
:mod:`nmsid.cli.identify`)."""

from __future__ import annotations

import csv
import math
import os
import sys

import numpy as np

from nmsid.analysis.errors import SimulateOptionError
from nmsid.analysis.joint_twins import joint_twin
from nmsid.analysis.run import run_identification, summary_line
from nmsid.analysis.settings import IdentificationSettings
from nmsid.cli.errors import InputFileError, UsageError
from nmsid.protocols.output_paths import check_output, output_dir, output_file

#: Exit status of ``nmsid identify`` when no sE level could be identified (docs/cli.md).
EXIT_NOTHING_IDENTIFIED = 3


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


def unique_sessions(paths) -> list[str]:
    """The session paths with repeats of one file removed (the same file given twice,
    by the same or another name, e.g. a symbolic link, counts once); prints a note per
    repeat."""
    seen: dict[tuple, str] = {}
    kept = []
    for p in paths:
        key: tuple[object, object]
        try:
            st = os.stat(p)
            key = (st.st_dev, st.st_ino)
        except OSError:  # unreadable: identify reports it by name
            key = ("path", os.path.realpath(p))
        if key in seen:
            print(f"note: {p} is the same file as {seen[key]}; counted once")
            continue
        seen[key] = p
        kept.append(p)
    return kept


def run_identify(args) -> int:
    """Handler of ``nmsid identify``: exit 0, or :data:`EXIT_NOTHING_IDENTIFIED` when no
    sE level of any session could be identified (the outputs are still written)."""
    settings = settings_from_args(args)
    sessions = unique_sessions(args.sessions)
    with output_dir(args.out, force=args.force, command="identify") as tmp:
        out = run_identification(sessions, tmp, settings, figures=not args.no_figures,
                                 progress=True)
    print(out.tables_text)
    if out.problems:
        print(f"\n{len(out.problems)} problem(s) (also in {args.out}/problems.txt):")
        for p in out.problems:
            print(f"  - {p}")
    print(f"\n{summary_line(out)}; outputs in {args.out}")
    n_ok = sum(1 for r in out.sessions for lv in r.levels if lv.fit is not None)
    if n_ok == 0:
        print(f"nmsid: identify: no sE level could be identified in "
              f"{', '.join(map(str, sessions))} (see {args.out}/problems.txt)",
              file=sys.stderr)
        return EXIT_NOTHING_IDENTIFIED
    return 0


def run_twin_help(args) -> int:
    print("usage: nmsid twin simulate TWIN.json (--rE-chirp | --input CSV) [--sE X] --out CSV")
    return 2


def _read_input_csv(path: str):
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read the input CSV ({exc.strerror or exc})") from None
    if len(rows) < 3:
        raise InputFileError(f"{path}: needs a header row and at least 2 samples")
    header = [h.strip() for h in rows[0]]
    if "rE" not in header:
        raise InputFileError(f"{path}: header {header} has no 'rE' column (columns: rE, "
                         "optional sE and t_s)")
    cols = {}
    for name in ("rE", "sE", "t_s"):
        if name in header:
            j = header.index(name)
            try:
                cols[name] = np.array([float(r[j]) for r in rows[1:] if r], dtype=float)
            except (ValueError, IndexError):
                raise InputFileError(f"{path}: column {name!r} holds a non-number") from None
    return cols


#: Bounds of ``nmsid twin simulate`` (docs/cli-safety.md): the rig samples at 2 kHz; 100
#: kHz is far above any muscle's bandwidth, and 5 million samples keep the CSV under
#: ~250 MB and the memory under ~0.5 GB.
FS_RANGE_HZ = (1.0, 100_000.0)
DURATION_MAX_S = 3600.0
MAX_SAMPLES = 5_000_000


def _bounded(option: str, value, lo: float, hi: float, *, lo_open: bool = False,
             unit: str = "") -> float:
    """``value`` as a float inside [lo, hi] (or (lo, hi]), else one clear refusal."""
    v = float(value)
    ok = math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi
    if not ok:
        left = "(" if lo_open else "["
        raise SimulateOptionError(f"{option} {value!r}: must be a finite value in "
                                  f"{left}{lo:g}, {hi:g}]{unit}")
    return v


def _check_simulate_options(args) -> None:
    if args.fs_Hz is not None:
        _bounded("--fs-Hz", args.fs_Hz, *FS_RANGE_HZ, unit=" Hz")
    if args.sE is not None:
        _bounded("--sE", args.sE, 0.0, 10.0, lo_open=True)
    if args.rE_chirp:
        _bounded("--steady-s", args.steady_s, 0.0, DURATION_MAX_S, unit=" s")
        _bounded("--chirp-s", args.chirp_s, 0.0, DURATION_MAX_S, lo_open=True, unit=" s")
        fs = args.fs_Hz or 2000.0
        for opt, v in (("--f0-Hz", args.f0_Hz), ("--f1-Hz", args.f1_Hz)):
            _bounded(opt, v, 0.0, fs / 2, lo_open=True, unit=f" Hz (below fs/2 = {fs / 2:g})")
        n = (args.steady_s + args.chirp_s) * fs
        if n > MAX_SAMPLES:
            raise SimulateOptionError(
                f"--steady-s {args.steady_s:g} + --chirp-s {args.chirp_s:g} at --fs-Hz "
                f"{fs:g} is {n:.3g} samples; at most {MAX_SAMPLES:,} (shorten it or lower "
                "--fs-Hz)")


def _check_input_columns(path, rE: np.ndarray, sE: np.ndarray) -> None:
    """Refuse, in one line naming the row, an rE outside [0, 1] (a ratio, the paper's
    Eq. 3) or an sE that is not finite and > 0, before any force is simulated."""
    for name, values, ok, valid in (
            ("rE", rE, lambda v: np.isfinite(v) & (v >= 0.0) & (v <= 1.0), "in [0, 1]"),
            ("sE", sE, lambda v: np.isfinite(v) & (v > 0.0), "finite and > 0")):
        bad = np.flatnonzero(~ok(np.asarray(values, dtype=float)))
        if bad.size:
            raise InputFileError(f"{path}: column {name!r} row {int(bad[0]) + 2} is "
                                 f"{float(values[bad[0]])!r} ({bad.size} bad row(s)); valid: "
                                 f"{valid}")


def _check_effects(twin, args) -> None:
    """A twin's effects are simulated with the FMU's own definition of them
    (:class:`nmsid.export.fmu.reference.TwinStepper`, one definition for both); an effect
    it does not model is refused by name unless the user says to leave effects out."""
    if not twin.effects or args.without_effects:
        return
    # `twin simulate` only, and only for a twin with effects: `nmsid identify` (this
    # module's other handler) must not load the FMU exporter and scipy.linalg
    from nmsid.export.fmu.build import SUPPORTED_EFFECTS, unsupported_effects
    unsupported = sorted(unsupported_effects(twin.effects))
    if unsupported:
        raise SimulateOptionError(
            f"{args.twin}: the twin's effect(s) {', '.join(unsupported)} cannot be simulated "
            f"here (simulated: {', '.join(SUPPORTED_EFFECTS)}); give --without-effects to "
            "simulate the curves alone, or run the twin as a participant in `nmsid run`")


def _simulate(twin, rE, sE, fs: float, args) -> np.ndarray:
    """The twin's force: with its effects (when it has them and they are wanted) as the
    FMU steps it, else the curves alone (:meth:`Twin.simulate`, which also runs a
    muscle-model twin)."""
    if twin.effects and not args.without_effects and twin.muscle_model is None:
        # lazy, as in _check_effects: scipy.linalg stays out of `nmsid identify`
        from nmsid.export.fmu.reference import TwinStepper
        return TwinStepper(twin, extrapolate=args.extrapolate).simulate(rE, sE, fs)
    return twin.simulate(rE, sE, fs, clip=not args.extrapolate)


def run_twin_simulate(args) -> int:
    """Handler of ``nmsid twin simulate``."""
    _check_simulate_options(args)
    twin = joint_twin(args.twin, getattr(args, "joint", None))
    _check_effects(twin, args)
    check_output(args.out, force=args.force, kind="file")
    if args.rE_chirp:
        fs = args.fs_Hz or 2000.0
        n = int(round((args.steady_s + args.chirp_s) * fs))
        t = np.arange(n) / fs
        tc = np.clip(t - args.steady_s, 0.0, None)
        if not (args.f1_Hz > 0 and args.f0_Hz > 0 and args.f1_Hz != args.f0_Hz):
            raise UsageError(f"--f0-Hz {args.f0_Hz} and --f1-Hz {args.f1_Hz} must be "
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
                raise InputFileError(f"{args.input}: t_s must be uniformly increasing")
            fs = 1.0 / float(np.mean(dt))
            _bounded(f"{args.input}: the t_s column's rate", fs, *FS_RANGE_HZ, unit=" Hz")
        else:
            fs = 2000.0
        t = np.arange(len(rE)) / fs
    if args.sE is not None:
        sE = np.full(len(rE), args.sE)
    if sE is None:
        raise UsageError("give --sE, or an 'sE' column in the --input CSV")
    _check_input_columns(args.input, rE, sE)
    force = _simulate(twin, rE, sE, fs, args)
    # a torque joint's twin (docs/joints.md) gives its torque in N m: the column says so
    column, what, unit = (("torque_Nm", f"{twin.joint} torque", "N m")
                          if twin.measured_unit == "N m" else ("force_N", "force", "N"))
    with output_file(args.out, force=args.force) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(f"t_s,rE,sE,{column}\n")
            for row in zip(t, rE, sE, force, strict=True):
                fh.write(f"{row[0]:.6f},{row[1]:.9g},{row[2]:.9g},{row[3]:.9g}\n")
    print(f"wrote {len(rE)} samples at {fs:g} Hz to {args.out} "
          f"({what} {force.min():.3f} to {force.max():.3f} {unit})")
    return 0
