"""nmsid study: a folder or STUDY.toml of sessions, Dask workers, a failing session."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from nmsid.study.config import load_study  # noqa: E402
from nmsid.study.errors import StudyConfigError  # noqa: E402
from nmsid.study.group import gap_summary  # noqa: E402
from nmsid.study.runner import run_study  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from nmsid.testing.platforms import WINE_DASK_CLUSTER  # noqa: E402
from nmsid.testing.sessions import write_synthetic_session  # noqa: E402

LEVELS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("study")
    truths = {}
    for i, fs in enumerate((1000.0, 800.0, 1000.0)):
        truths[f"S{i}"] = write_synthetic_session(
            d / "site" / f"S{i}.h5", seed=10 + i, sE_levels=LEVELS, repeats=2, fs_Hz=fs,
            steady_s=2.0, chirp_s=5.0)
    (d / "site" / "broken.h5").write_bytes(b"this is not HDF5")
    return d, truths


def _rows(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def dask_run(folder, tmp_path_factory):
    d, _ = folder
    out = tmp_path_factory.mktemp("out")
    lines = []
    result = run_study(load_study(d), out, workers=2, progress=lines.append)
    return result, out, lines


@pytest.mark.wine_gap(WINE_DASK_CLUSTER)
def test_two_workers_report_and_failing_session(folder, dask_run):
    d, truths = folder
    result, out, lines = dask_run
    assert len(lines) == 4 and all(line.startswith("[") for line in lines)
    assert sum("FAILED" in line and "broken.h5" in line for line in lines) == 1
    rows = {Path(r["session"]).name: r for r in _rows(out / "sessions.csv")}
    assert rows["broken.h5"]["ok"] == "False" and "broken.h5" in rows["broken.h5"]["error"]
    for i in range(3):
        r = rows[f"S{i}.h5"]
        assert r["ok"] == "True" and r["levels_identified"] == str(len(LEVELS))
        # exact second-order sessions: nothing beyond the nominal model to name
        assert r["gap_best_effect"] == "none" and float(r["gap_shrink_pct"]) == 0.0
    html = (out / "report.html").read_text()
    assert "broken.h5" in html and "Tables 1-9" in html and "data:image/png;base64" in html
    sel = json.loads((out / "model_selection.json").read_text())
    assert sorted(sel["participants"]) == sorted(t.participant for t in truths.values())
    for name in ("aicc.csv", "selected_models.csv", "aicc_sums.csv", "gap_summary.json",
                 "study.json", "figure_Kp.png", "figure_zeta.png", "figure_Kp.pdf"):
        assert (out / name).is_file()
    assert len(list((out / "sessions").glob("*/identify/parameters.csv"))) == 3
    assert len(list((out / "sessions").glob("*/gap/gap_report.json"))) == 3
    # identified parameters are close to the generator's (each session's own truth)
    for i in range(3):
        res = next(r for r in result.results if r["path"].endswith(f"S{i}.h5"))
        truth = truths[f"S{i}"]
        np.testing.assert_allclose(res["values"]["Kp"], truth.Kp, rtol=0.05)
        np.testing.assert_allclose(res["values"]["wn_rad_s"], truth.wn_rad_s, rtol=0.05)


@pytest.mark.wine_gap(WINE_DASK_CLUSTER)
def test_serial_matches_dask_and_aicc_sums_add_up(folder, dask_run, tmp_path):
    d, _ = folder
    result, _, _ = dask_run
    cfg = load_study(d)
    cfg.gap = False
    serial = run_study(cfg, tmp_path / "serial", workers=0, progress=None)
    by_path = {r["path"]: r for r in result.results if r["ok"]}
    for r in serial.results:
        if r["ok"]:
            assert r["values"] == by_path[r["path"]]["values"]
    sel = serial.group.selection
    for name in ("Kp", "wn_rad_s", "zeta"):
        for m in sel.settings.models:
            parts = [c.fits[m].aicc for c in sel.comparisons
                     if c.parameter == name and c.label != "average" and m in c.fits
                     and c.fits[m].selectable]
            assert sel.aicc_sums[name][m] == pytest.approx(sum(parts))
    assert serial.group.gap["n_sessions_diagnosed"] == 0


def test_study_toml_globs_overrides_and_settings(folder, tmp_path):
    d, _ = folder
    toml = d / "STUDY.toml"
    toml.write_text('sessions = ["site/S*.h5", "site/S0.h5"]\n'
                    '[participants]\n"S1" = "P-ONE"\n'
                    '[settings]\ngap = false\nfigures = false\n'
                    '[identification]\nlowpass_Hz = 20.0\n')
    cfg = load_study(toml)
    assert [p.name for p in cfg.sessions] == ["S0.h5", "S1.h5", "S2.h5"]
    assert cfg.identification_settings().lowpass_Hz == 20.0 and cfg.gap_sessions() == set()
    out = run_study(cfg, tmp_path / "o", workers=0, progress=None)
    assert "P-ONE" in out.group.selection.participants
    assert "<td>P-ONE</td>" in (tmp_path / "o" / "report.html").read_text()
    assert [r["participant"] for r in _rows(tmp_path / "o" / "sessions.csv")].count("P-ONE") == 1
    assert not (tmp_path / "o" / "figure_Kp.png").exists()


@pytest.mark.parametrize("text,match", [
    ('sessions = "a.h5"\n', "sessions = 'a.h5' is refused: a list"),
    ('sessions = ["nothing-*.h5"]\n', "matches no file"),
    ('sessions = ["site/*.h5"]\n[settings]\nworkers = 3\n', "settings.workers = 3 is "
     "refused: unknown setting"),
    ('sessions = ["site/*.h5"]\n[settings]\ngap = "yes"\n', "settings.gap = 'yes' is "
     "refused: true or false"),
    ('sessions = ["site/*.h5"]\nsesions = 1\n', "sesions = 1 is refused: unknown setting"),
    ('sessions = ["site/*.h5"]\n[participants]\nS0 = "P01\\n"\n', "participants.S0 = "
     "'P01\\\\n' is refused: a participant code"),
    ('sessions = [\n', "not valid TOML"),
])
def test_bad_study_files_name_the_problem(folder, text, match):
    d, _ = folder
    p = d / "bad.toml"
    p.write_text(text)
    with pytest.raises(StudyConfigError, match=match) as exc:
        load_study(p)
    assert "bad.toml" in str(exc.value)


def test_unknown_identification_setting(folder):
    d, _ = folder
    p = d / "bad2.toml"
    p.write_text('sessions = ["site/S0.h5"]\n[identification]\nlowpas_Hz = 3\n')
    with pytest.raises(StudyConfigError, match="lowpas_Hz"):
        load_study(p).identification_settings()


def test_cli_missing_folder_is_one_line(tmp_path, capsys):
    from nmsid.cli import main
    assert main(["study", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and err.count("\n") == 1


def test_gap_summary_counts_and_medians():
    def r(best, shrink, supported):
        return {"ok": True, "gap": {"best_effect": best,
                                    "heldout": {"shrink_pct": shrink, "nominal_nrmse_pct": 10.0,
                                                "augmented_nrmse_pct": 10.0 - shrink / 10},
                                    "supported": [{"effect": e, "shrink_pct": s}
                                                  for e, s in supported]}}
    s = gap_summary([r("delay", 30.0, [("delay", 30.0)]), r("delay", 50.0, [("delay", 40.0)]),
                     r("fatigue", 10.0, [("fatigue", 10.0), ("delay", 5.0)]),
                     {"ok": False, "gap": None}])
    assert s["n_sessions_diagnosed"] == 3
    assert s["best_effect"]["delay"] == {"sessions": 2, "median_shrink_pct": 40.0}
    assert s["supported"]["delay"] == {"sessions": 3, "median_shrink_pct": 30.0}
    assert s["median_nominal_heldout_nrmse_pct"] == 10.0


@pytest.mark.wine_gap(WINE_DASK_CLUSTER)
def test_existing_scheduler_address(folder, tmp_path):
    """--scheduler: the tasks go to a cluster the study did not start (and leaves up)."""
    from distributed import LocalCluster
    d, _ = folder
    cfg = load_study(d)
    cfg.gap, cfg.figures = False, False
    cfg.sessions = [p for p in cfg.sessions if p.name in ("S0.h5", "broken.h5")]
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        out = run_study(cfg, tmp_path / "o", scheduler=cluster.scheduler_address,
                        progress=None)
        assert cluster.scheduler.status.name == "running"
    assert out.mode.startswith("Dask scheduler tcp://")
    assert [r["ok"] for r in out.results] == [True, False]
    assert out.results[1]["error"].startswith("reading failed")
