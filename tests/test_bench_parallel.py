"""The benchmarks that run their items in worker processes print every item's row.

Each bench's per-item work (a participant, a setting, a session) is replaced by a small
fake, so these tests check the pool, the assembly of the results and the printed rows in
about a second each, not the figures. The benches' pools spawn their workers on every
platform (bench/workers.py), and a spawned worker would not see the fakes: the items run
in-process here (one job); the pool itself is tested in tests/test_bench_spawn.py.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
JOBS = 1


@pytest.fixture
def bench(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCH))

    def load(name: str):
        return importlib.import_module(name)
    return load


def fake_control_one(model, seed, tmp, n):
    if model == "musculoskeletal" and seed == 2:
        raise RuntimeError("fake failure")
    return {"twin": 1.0 + seed, "baseline": 5.0, "aborted": 0, "above_cmd": 0,
            "above_dlv": 0, "latency_s": 0.0055, "sE": 0.8, "code": f"{model[0]}{seed}",
            "seconds": 1.0}


def fake_realtime(tmp):
    return {"median": 0.006, "p99": 0.01, "max": 0.02, "late": 0, "n": 100,
            "underruns_last": 0, "compute_max": 0.001, "compute_median": 0.0001,
            "design": 0.0055}


def test_control_prints_every_participant(bench, monkeypatch, capsys):
    b = bench("bench_control")
    monkeypatch.setattr(b, "one", fake_control_one)
    monkeypatch.setattr(b, "realtime_latency", fake_realtime)
    b.main(["--jobs", str(JOBS)])
    out = capsys.readouterr().out
    for code in ("t0", "t1", "t2", "m0", "m1"):
        assert f" {code} " in out
    assert "musculoskeletal seed 2: FAILED (RuntimeError: fake failure)" in out
    assert "worst ratio 0.600 over 5 participants: missed" in out   # t2: 3.0 / 5.0


def fake_msk_participant(args):
    from nmsid.analysis.design.candidates import Candidate
    k, _ = args
    e = {"level": np.full((15, 3), 0.01 * (k + 1)), "curve": np.full((15, 3), 0.02 * (k + 1)),
         "right": np.array([True, False, True])}
    sc = {"part1": {"paper": e, "2s-lead-in": e, "proposal": e}, "lab": e, "paper": e,
          "proposal": Candidate(steady_s=2.0, chirp_s=10.0, rest_s=48.0, label="lab"),
          "measured": {"Kp": 0.1, "wn_rad_s": 0.05, "zeta": 0.0}, "fit_pct": 80.0 + k}
    return {"code": f"M0{k + 1}", "family": ["quadratic"] * 3, "scenarios": [sc, sc],
            "runs": 6}


def test_design_msk_prints_every_participant(bench, monkeypatch, capsys):
    b = bench("bench_design_msk")
    monkeypatch.setattr(b, "participant", fake_msk_participant)
    b.main(3, jobs=JOBS)
    out = capsys.readouterr().out
    for k in range(3):
        assert out.count(f"  M0{k + 1}  ") == 2   # one row per scenario
        assert out.count(f"{80.0 + k:6.1f} 15 lv x3") == 2
    assert "18 protocol runs simulated and identified" in out


def fake_qc_setting(args):
    kind, sc = args
    return (1 if sc else 0, 40, 135)


def test_qc_physiology_totals(bench, monkeypatch, capsys):
    pytest.importorskip("mujoco")
    b = bench("bench_qc_physiology")
    monkeypatch.setattr(b, "setting", fake_qc_setting)
    b.main(jobs=JOBS)
    out = capsys.readouterr().out
    assert out.count("template x3 ") == 5 and out.count("MuJoCo x3 ") == 2
    assert "all, clean trials excluded: 5/945 = 0.53 %" in out
    assert "280/945 = 29.6 %, x56 the default's" in out


def fake_session_of(args):
    spec, code, tmp = args
    rows = [{"sE": s, "got": (1.0, 2.0, 3.0), "truth": (1.0, 2.0, 3.0), "fit": 90.0,
             "ceiling": 90.0, "err": [0.01, 0.02, 2.0 if code == "M02" else 0.03]}
            for s in (0.3, 1.0)]
    return {"code": code, "wall": 10.0, "cpu": 9.0, "valid": True, "cal_ok": True,
            "cal": (1, 2, 3, 4), "t_ident": 1.0, "t_truth": 2.0, "rows": rows,
            "path": Path(tmp) / f"{code}.h5"}


def test_musculoskeletal_prints_every_session(bench, monkeypatch, capsys):
    b = bench("bench_musculoskeletal")
    monkeypatch.setattr(b, "_session_of", fake_session_of)
    for name in ("_cli_session", "_realtime"):
        monkeypatch.setattr(b, name, lambda *a: None)
    monkeypatch.setattr(b, "_gap", lambda path, tmp: print(f"gap on {path.name}"))
    b.main(jobs=JOBS)
    out = capsys.readouterr().out
    for label in ("template (default, seed 11)", "musculoskeletal (default)",
                  "musculoskeletal M01 (pop 1)", "musculoskeletal M02 (pop 1)"):
        assert label in out
    assert "identification within 1 % of the truth: missed (worst 2.000 %)" in out
    assert "gap on MSK.h5" in out   # part 5 on the default musculoskeletal session
