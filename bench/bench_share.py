"""Compact session files and NWB export: sizes, times, nwbinspector findings.

1. The demo session (simulated rig, 45 trials, calibration, wrench, sync) recorded three
   times in this process: without the simulated A/D (``SensorModel(adc_bits=None)``,
   float64 noise: the chain before), with the 16-bit A/D (the default: every wrench
   sample is a count times the LSB, as on the real rig), and with an amplifier
   sensitivity whose LSB is not float32-exact. Each is rewritten through
   ``SessionWriter`` plain (no filters), with shuffle + gzip 4 and floats only (the writer
   before the counts), and with gzip + integer counts for the optional signals on an
   exact grid (the default; levels 1 and 9 for the level choice): file size, write time
   (one open/close per trial, as the rig writes), the time to read all force data
   (``read_session(datasets=("force_N",))``, best of 3, each read paired with one of the
   old file so that the ratio sees the same machine load; best of 5 before, ~30 s more of
   the whole run) and all datasets; every file
   checked bit for bit against its recording. Ratios ("vs old") are against the old
   file: the float chain's recording, float64 everywhere, no filters (114.1 MB).
2. The default file exported to NWB: time, size, nwbinspector's findings.

    python bench/bench_share.py
"""

from __future__ import annotations

import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.protocols.session_file import SessionWriter, read_session, validate_session  # noqa: E402
from nmsid.rig.engine import Engine, TripPolicy  # noqa: E402
from nmsid.sim_backends import make_sim_rig  # noqa: E402
from nmsid.sim_backends.participant import default_participant  # noqa: E402
from nmsid.sim_backends.sensor import SensorModel  # noqa: E402

KEYS = ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync")


def demo_session(tmp: Path, name: str, sensor: SensorModel) -> Path:
    """A whole simulated session as ``nmsid run --backend sim`` writes it."""
    rig = make_sim_rig(default_participant(seed=0, sensor=sensor))
    cfg = config_from_dict({"participant": "DEMO", "seed": 0, "protocol": {"rest_s": 0.0}})
    path = tmp / f"{name}.h5"
    Engine(cfg, rig, path, trip_policy=TripPolicy.END_SESSION).run()
    return path


def rewrite(session, path: Path, level, counts: bool) -> float:
    t0 = time.perf_counter()
    w = SessionWriter.create(path, participant=session.participant,
                             created_utc=session.created_utc, config_json=session.config_json,
                             seed=session.seed, backend=session.backend, gzip_level=level,
                             store_counts=counts)
    w.write_calibration(session.calibration)
    for t in session.trials:
        w.append_trial(t)
    w.append_events(session.events)
    return time.perf_counter() - t0


def bit_exact(a, b) -> bool:
    for ta, tb in zip(a.trials, b.trials, strict=True):
        for key in KEYS:
            x, y = getattr(ta, key), getattr(tb, key)
            if (x is None) != (y is None):
                return False
            if x is not None and not (x.shape == y.shape and y.dtype == np.float64 and
                                      np.array_equal(np.asarray(x, np.float64).view(np.int64),
                                                     y.view(np.int64))):
                return False
    return True


def stored_as(path: Path, key: str) -> str:
    import h5py  # the bench looks inside the file; the product reads through read_session
    with h5py.File(path, "r") as f:
        return str(f[f"trials/t001/{key}"].dtype)


ROWS = (("old: plain float64", None, False), ("gzip 4, floats", 4, False),
        ("gzip 1 + counts", 1, True), ("gzip 4 + counts", 4, True),
        ("gzip 9 + counts", 9, True))


def paired(path: Path, old: Path, datasets) -> tuple[float, float]:
    """Best-of-3 read time of ``path`` and its ratio to the old file's, the two read
    alternately (the machine is shared: load changes between rows, not within a pair)."""
    t_new, t_old = [], []
    for _ in range(3):
        for p, out in ((path, t_new), (old, t_old)):
            t0 = time.perf_counter()
            read_session(p, datasets=datasets)
            out.append(time.perf_counter() - t0)
    return min(t_new), min(t_new) / min(t_old)


def files(tmp: Path) -> Path:
    keep = None
    print(f"{'recording / file':<34}{'size MB':>9}{'vs old':>8}{'write s':>9}"
          f"{'read force s':>14}{'vs old':>8}{'read all s':>12}{'vs old':>8}  wrench  "
          "valid bit-exact")
    old = None
    for chain, sensor in (("float chain (before the A/D model)", SensorModel(adc_bits=None)),
                          ("A/D chain (16 bit, the default)", SensorModel()),
                          ("A/D chain, 0.0197 V/N, 0.49 V/N*m",
                           SensorModel(volts_per_N=0.0197, volts_per_Nm=0.49))):
        src = demo_session(tmp, f"rec{len(list(tmp.glob('rec*')))}", sensor)
        session = read_session(src)
        n = sum(t.n_samples for t in session.trials)
        print(f"{chain}: {len(session.trials)} trials, {n} samples; as the rig wrote it "
              f"{src.stat().st_size / 1e6:.1f} MB")
        for label, level, counts in ROWS:
            if not chain.startswith("A/D chain (") and level in (1, 9):
                continue
            path = tmp / f"{src.stem}-{level}{counts}.h5"
            t_write = rewrite(session, path, level, counts)
            size = path.stat().st_size / 1e6
            if old is None:   # the old file: float chain, float64 everywhere, no filters
                old, old_size = path, size
            t_force, r_force = paired(path, old, ("force_N",))
            t_all, r_all = paired(path, old, None)
            if label.startswith("old") and not chain.startswith("float"):
                label = "plain (no filters)"
            exact = bit_exact(session, read_session(path))
            print(f"  {label:<32}{size:9.1f}{size / old_size:8.2f}{t_write:9.2f}"
                  f"{t_force:14.3f}{r_force:8.2f}{t_all:12.3f}{r_all:8.2f}"
                  f"  {stored_as(path, 'wrench'):<7} {validate_session(path) == []!s:<5} "
                  f"{exact}")
            if chain.startswith("A/D chain (") and level == 4 and counts:
                keep = path
            elif path != old:
                path.unlink()
    return keep


def nwb(src: Path, tmp: Path) -> None:
    try:
        import pynwb  # noqa: F401

        from nmsid.export.nwb import export_nwb, inspect_nwb
    except ImportError as exc:
        print(f"NWB export skipped: {exc}")
        return
    t0 = time.perf_counter()
    out = export_nwb(src, tmp / "DEMO.nwb")
    t_export = time.perf_counter() - t0
    t0 = time.perf_counter()
    findings = inspect_nwb(out.path)
    t_inspect = time.perf_counter() - t0
    print(f"NWB export: {out.n_trials} trials, {out.n_series} time series, {out.n_events} "
          f"events, {out.path.stat().st_size / 1e6:.1f} MB in {t_export:.1f} s; "
          f"nwbinspector {t_inspect:.1f} s, {len(findings)} finding(s):")
    for m in findings:
        print(f"  {m.importance.name}: {m.check_function_name}: {m.message}")
    crit = [m for m in findings if m.importance.name in ("CRITICAL", "PYNWB_VALIDATION",
                                                          "ERROR")]
    print(f"  critical: {len(crit)} (experimenter / institution are not known to nmsid: "
          "give --experimenter / --institution)")


def main() -> None:
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        src = files(tmp)
        nwb(src, tmp)


if __name__ == "__main__":
    main()
