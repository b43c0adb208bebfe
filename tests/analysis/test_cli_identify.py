"""nmsid identify / nmsid twin simulate write their outputs; bad input gives one line."""

import csv
import json

import numpy as np

from nmsid.analysis.twin import file_sha256
from nmsid.cli import main


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_identify_one_session_no_figures(small_session, tmp_path, capsys):
    path, truth = small_session
    out = tmp_path / "out"
    assert main(["identify", str(path), "--out", str(out), "--no-figures"]) == 0
    printed = capsys.readouterr().out
    assert "selected model and trend" in printed and "sum of AICc" in printed
    rows = read_csv(out / "parameters.csv")
    assert len(rows) == 6
    assert {"participant", "sE", "Kp", "wn_rad_s", "zeta", "fit_pct", "n_trials", "Kp_se",
            "wn_se", "zeta_se", "resid_whiteness_pass", "resid_independence_pass"} <= set(rows[0])
    for r in rows:
        kp = truth.at(float(r["sE"]))[0]
        assert abs(float(r["Kp"]) / kp - 1) < 0.01 and r["n_trials"] == "2"
    sel = json.loads((out / "model_selection.json").read_text())
    assert sel["participants"] == [truth.participant]
    assert {c["parameter"] for c in sel["comparisons"]} == {"Kp", "wn_rad_s", "zeta"}
    twin = json.loads((out / "twin.json").read_text())
    assert twin["format"] == "nmsid-twin" and twin["participant"] == truth.participant
    # the source session by name and content hash; no path of this machine leaks
    assert twin["source"] == [{"file": path.name, "sha256": file_sha256(path)}]
    assert str(path.parent) not in (out / "twin.json").read_text()
    assert not list(out.glob("*.png"))
    for name in ("tables.txt", "problems.txt"):
        assert (out / name).exists()


def test_identify_group_with_figures_and_a_bad_file(small_session, second_session, tmp_path,
                                                    capsys):
    bad = tmp_path / "not_a_session.h5"
    bad.write_text("hello")
    out = tmp_path / "group"
    code = main(["identify", str(small_session[0]), str(second_session[0]), str(bad),
                 "--out", str(out), "--butter-order", "2"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "not_a_session.h5" in printed and "session skipped" in printed
    rows = read_csv(out / "parameters.csv")
    assert {r["participant"] for r in rows} == {small_session[1].participant, "P02"}
    assert (out / "twin_P02.json").exists() and (out / "twin.json").exists()
    average = json.loads((out / "twin.json").read_text())
    assert average["participant"] == "average"
    assert [s["file"] for s in average["source"]] == [small_session[0].name,
                                                     second_session[0].name]
    for name in ("figure_Kp.png", "figure_wn_rad_s.png", "figure_zeta.png", "fit_P02.png"):
        assert (out / name).stat().st_size > 1000
        assert (out / name).with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"
    sel = json.loads((out / "model_selection.json").read_text())
    assert sel["settings"]["butter_order"] == 2


def test_identify_errors_are_one_line(tmp_path, capsys):
    assert main(["identify", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "missing.h5" in err and "no such file" in err and "Traceback" not in err
    assert main(["identify", str(tmp_path / "x.h5"), "--out", str(tmp_path / "o"),
                 "--savgol-window", "40"]) == 2
    assert "savgol_window = 40" in capsys.readouterr().err


def test_twin_simulate_chirp_and_csv(tmp_path, capsys):
    from nmsid.analysis.twin import Curve, Twin
    tw = Twin("P01", {"Kp": Curve("linear", [1.0, 8.0]), "wn_rad_s": Curve("constant", [30.0]),
                      "zeta": Curve("constant", [0.6])}, (0.3, 1.0))
    tp = tmp_path / "twin.json"
    tw.save(tp)
    out = tmp_path / "force.csv"
    assert main(["twin", "simulate", str(tp), "--sE", "0.5", "--rE-chirp", "--fs-Hz", "1000",
                 "--out", str(out)]) == 0
    rows = read_csv(out)
    assert len(rows) == 15000 and set(rows[0]) == {"t_s", "rE", "sE", "force_N"}
    force = np.array([float(r["force_N"]) for r in rows])
    assert np.max(np.abs(force[:5000])) < 1e-12 and np.max(np.abs(force)) > 1.0
    inp = tmp_path / "in.csv"
    t = np.arange(2000) / 500.0
    with open(inp, "w") as fh:
        fh.write("t_s,rE,sE\n")
        for a, b, c in zip(t, 0.5 + 0.2 * np.sin(2 * np.pi * t), np.linspace(0.3, 0.9, 2000),
                           strict=True):
            fh.write(f"{a},{b},{c}\n")
    out2 = tmp_path / "force2.csv"
    assert main(["twin", "simulate", str(tp), "--input", str(inp), "--out", str(out2)]) == 0
    assert "at 500 Hz" in capsys.readouterr().out
    assert len(read_csv(out2)) == 2000
    assert main(["twin", "simulate", str(tmp_path / "none.json"), "--sE", "0.5",
                 "--rE-chirp", "--out", str(out2)]) == 2
    assert "no such file" in capsys.readouterr().err
    (tmp_path / "bad.csv").write_text("x,y\n1,2\n3,4\n")
    assert main(["twin", "simulate", str(tp), "--input", str(tmp_path / "bad.csv"),
                 "--sE", "0.5", "--out", str(tmp_path / "force3.csv")]) == 2
    assert "no 'rE' column" in capsys.readouterr().err


def test_two_sessions_of_one_participant_are_one_participant(small_session, second_session,
                                                             synthetic, tmp_path, capsys):
    """Issue 39: two sessions of P01 became the participants "P01" and "P01#2" and a group
    twin with no calibration, which `nmsid design --twin` then refused with a KeyError."""
    from nmsid.analysis.design.api import validation_participants
    from nmsid.analysis.design.prior import twin_prior

    path, truth = small_session
    again = tmp_path / "again.h5"
    synthetic.write_synthetic_session(again, seed=9, participant=truth.participant,
                                      sE_levels=[0.3, 0.5, 0.7, 0.9], repeats=2)
    out = tmp_path / "one"
    assert main(["identify", str(path), str(again), "--out", str(out), "--no-figures"]) == 0
    assert "2 session(s) of 1 participant(s)" in capsys.readouterr().out
    sel = json.loads((out / "model_selection.json").read_text())
    assert sel["participants"] == [truth.participant]
    twin = json.loads((out / "twin.json").read_text())
    assert twin["participant"] == truth.participant
    assert twin["calibration"]["Iemin_mA"] > 0       # the participant's own, not empty
    assert [s["file"] for s in twin["source"]] == [path.name, again.name]
    assert not list(out.glob("twin_*.json"))         # no group: one participant
    # a group-average twin (no calibration) is accepted by design's validation
    group = tmp_path / "group"
    assert main(["identify", str(path), str(second_session[0]), "--out", str(group),
                 "--no-figures"]) == 0
    average = group / "twin.json"
    assert json.loads(average.read_text())["calibration"] == {}
    people, label = validation_participants(twin_prior(average), 2, twin_path=average)
    assert len(people) == 2 and "no calibration" in label
