"""Trial QC on hand-made artefacts of each kind, on clean trials of varied shape, and the
guarantee that nothing QC excludes reaches a fit."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from scipy.signal import lsim

from nmsid.analysis import identify as identify_module
from nmsid.analysis.identify import identify_session
from nmsid.analysis.qc import QCSettings, assess_level, assess_session
from nmsid.analysis.settings import IdentificationSettings
from nmsid.cli import main
from nmsid.protocols.session_file import Calibration, SessionWriter, Trial, read_session

FS = 2000.0
STEADY, CHIRP = 5.0, 10.0


def chirp(t, hold: bool):
    tc = np.clip(t - STEADY, 0, None)
    phi = 2 * np.pi * CHIRP / math.log(10) * (10 ** (tc / CHIRP) - 1)
    r = np.where(t < STEADY, 0.5, 0.5 + 0.5 * np.sin(phi))
    if hold:  # the rig holds each sample: the muscle sees it one sample late
        r = np.concatenate([[0.5], r[:-1]])
    return r


def make_level(sE=0.6, n=3, Kp=6.0, wn=25.0, zeta=0.6, noise=0.02, mains_Hz=50.0,
               mains=0.03, hold=False, seed=0):
    """Repeats of one level: an exact second-order response plus a sensor's noise, mains,
    offset and drift, drawn per trial."""
    rng = np.random.default_rng(seed)
    t = np.arange(int((STEADY + CHIRP) * FS)) / FS
    r = chirp(t, False)
    _, y, _ = lsim(([Kp * wn * wn], [1, 2 * zeta * wn, wn * wn]), chirp(t, hold) - 0.5, t)
    trials = []
    for k in range(n):
        f = (y + rng.normal(0, noise, t.size) + mains * np.sin(2 * np.pi * mains_Hz * t
                                                                + rng.uniform(0, 6.3))
             + rng.uniform(-1, 1) + rng.uniform(-0.03, 0.03) * t)
        trials.append(Trial(sE=sE, repeat=k + 1, fs_Hz=FS, rE=r, I_ext_mA=3 + 0 * r,
                            I_flex_mA=3 + 0 * r, force_N=f, name=f"t{k + 1:03d}"))
    return trials, t


def bump(t, t0, dur, amp):
    return amp * np.where((t > t0) & (t < t0 + dur), np.sin(np.pi * (t - t0) / dur) ** 2, 0)


def verdicts(level):
    return {v.trial: v for v in level.verdicts}


@pytest.mark.parametrize("kw", [
    {"noise": 0.005, "mains": 0.01}, {"noise": 0.06, "mains": 0.05, "mains_Hz": 60.0},
    {"Kp": 0.8, "noise": 0.01}, {"Kp": 18.0, "wn": 55.0, "zeta": 0.25}, {"wn": 8.0, "zeta": 1.1},
    {"hold": True, "noise": 0.005}, {"n": 2}, {"n": 5, "seed": 3}])
def test_clean_repeats_are_all_used(kw):
    trials, _ = make_level(**kw)
    lv = assess_level(trials)
    assert [v.decision for v in lv.verdicts] == ["used"] * len(trials), \
        [v.reasons for v in lv.verdicts]
    assert not lv.flag and len(lv.kept) == len(trials)


@pytest.mark.parametrize("amp,t0", [(3.0, 9.0), (-2.0, 12.5), (5.0, 6.0)])
def test_voluntary_contraction_excluded_and_located(amp, t0):
    trials, t = make_level(seed=1)
    trials[1].force_N = trials[1].force_N + bump(t, t0, 1.5, amp)
    v = verdicts(assess_level(trials))
    assert v["t002"].decision == "excluded"
    assert "response not explained by rE" in v["t002"].reasons[0]
    (a, b), = v["t002"].spans
    assert a <= t0 + 0.3 and b >= t0 + 1.2 and b - a < 3.0
    assert v["t001"].decision == v["t003"].decision == "used"


def test_contraction_in_the_lead_in_is_noted_not_excluded():
    trials, t = make_level(seed=2)
    trials[0].force_N = trials[0].force_N + bump(t, 2.0, 1.5, 3.0)
    v = verdicts(assess_level(trials))
    assert v["t001"].decision == "used"
    assert "lead-in only" in v["t001"].reasons[0]


def test_spike_is_bridged():
    trials, t = make_level(seed=4)
    clean = trials[2].force_N.copy()
    trials[2].force_N = clean.copy()
    trials[2].force_N[20001:20004] += 4.0
    lv = assess_level(trials)
    v = verdicts(lv)["t003"]
    assert v.decision == "repaired" and "spike" in v.reasons[0]
    repaired = [tr for tr in lv.kept if tr.name == "t003"][0].force_N
    assert np.max(np.abs(repaired[19990:20010] - clean[19990:20010])) < 0.3


def test_nonfinite_short_gap_bridged_long_gap_excluded():
    trials, _ = make_level(seed=5)
    trials[0].force_N = trials[0].force_N.copy()
    trials[0].force_N[15000:15004] = np.nan
    trials[1].force_N = trials[1].force_N.copy()
    trials[1].force_N[15000:15400] = np.nan
    v = verdicts(assess_level(trials))
    assert v["t001"].decision == "repaired" and "non-finite" in v["t001"].reasons[0]
    assert v["t002"].decision == "excluded" and "non-finite" in v["t002"].reasons[0]


def test_clipping_excluded():
    trials, _ = make_level(seed=6)
    f = trials[0].force_N
    top = np.quantile(f[int(STEADY * FS):], 0.97)
    trials[0].force_N = np.minimum(f, top)
    v = verdicts(assess_level(trials))
    assert v["t001"].decision == "excluded" and v["t001"].reasons[0].startswith("clipping")


def test_stalled_stream_excluded():
    trials, _ = make_level(seed=7)
    f = trials[2].force_N.copy()
    f[18000:18400] = f[18000]
    trials[2].force_N = f
    v = verdicts(assess_level(trials))
    assert v["t003"].decision == "excluded" and v["t003"].reasons[0].startswith("stalled")


@pytest.mark.parametrize("height", [0.8, -1.5])
def test_baseline_jump_removed(height):
    trials, t = make_level(seed=8)
    clean = trials[1].force_N.copy()
    trials[1].force_N = clean + height * (t >= 8.0)
    lv = assess_level(trials)
    v = verdicts(lv)["t002"]
    assert v.decision == "repaired" and "baseline jump" in v.reasons[0], v.reasons
    fixed = [tr for tr in lv.kept if tr.name == "t002"][0].force_N
    # the jump is gone: what remains of it is a small fraction of its height
    assert abs(np.median(fixed[t > 9] - clean[t > 9])) < 0.1 * abs(height)


def test_fewer_than_two_usable_repeats_keeps_the_level_flagged():
    trials, t = make_level(n=2, seed=9)
    trials[0].force_N = trials[0].force_N.copy()
    trials[0].force_N[15000:15400] = np.nan
    lv = assess_level(trials)
    assert len(lv.kept) == 1 and "only 1 usable repeat" in lv.flag
    assert all(v.level_flag == lv.flag for v in lv.verdicts)


def _write_session(path, levels):
    w = SessionWriter.create(path, participant="QC01")
    w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0))
    for trials in levels:
        for tr in trials:
            w.append_trial(Trial(sE=tr.sE, repeat=tr.repeat, fs_Hz=FS, rE=tr.rE,
                                 I_ext_mA=tr.I_ext_mA, I_flex_mA=tr.I_flex_mA,
                                 force_N=tr.force_N, steady_s=STEADY, chirp_s=CHIRP))
    return path


@pytest.fixture
def contaminated(tmp_path):
    """Four levels x 2 repeats; one contraction at sE 0.5, one noisy lead-in at sE 0.6."""
    levels = []
    for i, sE in enumerate((0.4, 0.5, 0.6, 0.7)):
        trials, t = make_level(sE=sE, n=2, Kp=3 + 4 * sE, wn=20 + 10 * sE, seed=20 + i)
        levels.append(trials)
    t = np.arange(levels[0][0].force_N.size) / FS
    levels[1][1].force_N = levels[1][1].force_N + bump(t, 10.0, 1.6, 3.0)
    levels[2][0].force_N = levels[2][0].force_N + np.random.default_rng(0).normal(
        0, 0.5, t.size)
    return _write_session(tmp_path / "qc.h5", levels)


def test_session_two_repeats_decided_by_neighbours_and_lead_in_noise(contaminated):
    qc = assess_session(contaminated)
    by = {(v.sE, v.repeat): v for v in qc.trials}
    assert by[(0.5, 2)].decision == "excluded", by[(0.5, 2)].reasons
    assert by[(0.5, 1)].decision == "used", by[(0.5, 1)].reasons
    assert by[(0.6, 1)].decision == "excluded"
    assert "lead-in noise" in by[(0.6, 1)].reasons[0]
    assert sum(v.decision == "excluded" for v in qc.trials) == 2


def test_nothing_excluded_reaches_a_fit(contaminated, monkeypatch):
    seen = []
    real = identify_module.fit_level

    def spy(trials, settings, *args, **kwargs):
        seen.extend((t.sE, t.repeat) for t in trials)
        return real(trials, settings, *args, **kwargs)

    monkeypatch.setattr(identify_module, "fit_level", spy)
    res = identify_session(read_session(contaminated))
    assert (0.5, 2) not in seen and (0.6, 1) not in seen and len(seen) == 6
    rows = {round(r["sE"], 2): r for r in res.rows()}
    assert rows[0.5]["n_repeats_used"] == 1 and rows[0.5]["n_repeats_excluded"] == 1
    assert "only 1 usable repeat" in rows[0.5]["qc_flag"]
    seen.clear()
    identify_session(read_session(contaminated), IdentificationSettings(qc=False))
    assert len(seen) == 8  # the paper's plain average uses every repeat


def test_cli_qc_and_identify_qc_csv(contaminated, tmp_path, capsys):
    assert main(["qc", str(contaminated)]) == 1
    out = capsys.readouterr().out
    assert "excluded" in out and "2 excluded of 8" in out
    assert main(["qc", str(contaminated), "--json"]) == 1
    assert '"decision": "excluded"' in capsys.readouterr().out
    bad = tmp_path / "bad.h5"
    bad.write_text("x")
    assert main(["qc", str(bad)]) == 2
    assert "bad.h5" in capsys.readouterr().err
    assert main(["identify", str(contaminated), "--out", str(tmp_path / "id"),
                 "--no-figures"]) == 0
    with open(tmp_path / "id" / "qc.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert {"trial", "sE", "repeat", "decision", "reasons", "spans"} <= set(rows[0])
    assert sum(r["decision"] == "excluded" for r in rows) == 2


def test_settings_refuse_nonsense():
    with pytest.raises(ValueError, match="deviation_k"):
        QCSettings(deviation_k=0)
    with pytest.raises(ValueError, match="deviation_min_frac"):
        QCSettings(deviation_min_frac=2.0)


def make_varied_level(wn_sd, zeta_sd, *, n=3, Kp=6.0, wn=25.0, zeta=0.6, noise=0.02,
                      seed=0):
    """Repeats whose dynamics differ from trial to trial (wn, zeta drawn per trial with
    relative SDs ``wn_sd``, ``zeta_sd``; Kp by 10 %): physiology, not artefact."""
    rng = np.random.default_rng(seed)
    t = np.arange(int((STEADY + CHIRP) * FS)) / FS
    r = chirp(t, False)
    trials = []
    for k in range(n):
        kp = Kp * (1 + 0.1 * rng.standard_normal())
        w = wn * (1 + wn_sd * rng.standard_normal())
        z = zeta * (1 + zeta_sd * rng.standard_normal())
        _, y, _ = lsim(([kp * w * w], [1, 2 * z * w, w * w]), r - 0.5, t)
        f = y + rng.normal(0, noise, t.size) + rng.uniform(-1, 1)
        trials.append(Trial(sE=0.6, repeat=k + 1, fs_Hz=FS, rE=r, I_ext_mA=3 + 0 * r,
                            I_flex_mA=3 + 0 * r, force_N=f, name=f"t{k + 1:03d}"))
    return trials, t


@pytest.mark.parametrize("wn_sd,zeta_sd,wn,zeta,n,seed", [
    (0.05, 0.0, 25.0, 0.6, 3, 0), (0.0, 0.08, 25.0, 0.6, 3, 1), (0.08, 0.08, 12.0, 0.9, 3, 2),
    (0.08, 0.08, 45.0, 0.4, 5, 3), (0.1, 0.1, 30.0, 0.5, 2, 4), (0.06, 0.06, 20.0, 0.7, 4, 5)])
def test_dynamics_varying_between_repeats_is_not_an_artefact(wn_sd, zeta_sd, wn, zeta, n,
                                                              seed):
    trials, _ = make_varied_level(wn_sd, zeta_sd, wn=wn, zeta=zeta, n=n, seed=seed)
    lv = assess_level(trials)
    assert [v.decision for v in lv.verdicts] == ["used"] * n, \
        [v.reasons for v in lv.verdicts]


def test_gain_and_shift_alone_would_call_dynamics_scatter_an_artefact():
    """The comparison without the shared filter (the first release's) excludes clean
    trials whose wn differs by ~10 %: the filter is what keeps them."""
    narrow = QCSettings(shared_filter_s=0)
    excluded = 0
    for seed in range(4):
        trials, _ = make_varied_level(0.1, 0.1, wn=30.0, zeta=0.5, seed=seed)
        excluded += sum(v.decision == "excluded"
                        for v in assess_level(trials, narrow).verdicts)
        assert all(v.decision == "used" for v in assess_level(trials).verdicts)
    assert excluded >= 1


@pytest.mark.parametrize("amp,t0,seed", [(2.0, 9.0, 0), (-2.0, 12.0, 1), (3.0, 6.5, 2)])
def test_contraction_found_among_repeats_with_varying_dynamics(amp, t0, seed):
    trials, t = make_varied_level(0.08, 0.08, seed=seed)
    trials[2].force_N = trials[2].force_N + bump(t, t0, 1.5, amp)
    v = verdicts(assess_level(trials))
    assert v["t003"].decision == "excluded", v["t003"].reasons
    (a, b), = v["t003"].spans
    assert a <= t0 + 0.3 and b >= t0 + 1.2
    assert v["t001"].decision == v["t002"].decision == "used"


def test_jump_found_among_repeats_with_varying_dynamics():
    trials, t = make_varied_level(0.08, 0.08, seed=7)
    trials[0].force_N = trials[0].force_N + np.where(t > 11.0, -1.2, 0.0)
    v = verdicts(assess_level(trials))
    assert v["t001"].decision == "repaired", v["t001"].reasons
    assert v["t002"].decision == v["t003"].decision == "used"


def test_counts_and_excluded_are_result_objects_with_the_json_form():
    from nmsid.analysis.qc.decide import DecisionCounts, LevelQC, SessionQC, TrialQC
    vs = [TrialQC("t001", 0.5, 1, "used"), TrialQC("t002", 0.5, 2, "excluded", ["spike"]),
          TrialQC("t003", 0.5, 3, "repaired", ["bridged"]),
          TrialQC("t004", 0.5, 4, "excluded", ["a", "b"])]
    qc = SessionQC("P01", "s.h5", [LevelQC(0.5, vs)])
    c = qc.counts()
    assert c == DecisionCounts(used=1, repaired=1, excluded=2) and c.total == 4
    assert c.to_dict() == {"used": 1, "repaired": 1, "excluded": 2}
    ex = qc.excluded()
    assert dict(ex) == {"t002": "spike", "t004": "a; b"}
    with pytest.raises(TypeError):
        ex["t001"] = "x"  # type: ignore[index]
    assert vs[3].to_dict()["reasons"] == "a; b"


def test_filtering_all_trials_together_changes_no_verdict(monkeypatch):
    """assess_session filters every trial's force in one batch (spike low-pass and the
    repeats' smoothing); a spike, a gap, a contraction and a shorter trial decide the same
    as when each trial is filtered on its own, and the repaired forces agree."""
    from nmsid.analysis.qc import decide
    from nmsid.protocols.session_model import Session
    levels = []
    for i, sE in enumerate((0.4, 0.5, 0.6)):
        trials, t = make_level(sE=sE, n=3, Kp=3 + 4 * sE, seed=40 + i)
        levels.append(trials)
    levels[0][1].force_N[14000:14003] += 4.0                      # a spike: bridged
    levels[1][0].force_N[16000] = np.nan                          # a gap: not batched
    levels[1][2].force_N = levels[1][2].force_N + bump(t, 9.0, 1.5, 3.0)   # excluded
    levels[2][2].force_N = levels[2][2].force_N[:26000]           # alone at its length
    levels[2][2].rE = levels[2][2].rE[:26000]
    session = Session(path="batch.h5", participant="QC02", created_utc="", software="",
                      calibration=Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0),
                      trials=[tr for lv in levels for tr in lv])
    batch = decide._filter_together(session.trials, QCSettings())
    assert len(batch) == 7 and id(levels[1][0]) not in batch and id(levels[2][2]) not in batch
    together = assess_session(session)
    monkeypatch.setattr(decide, "_filter_together", lambda trials, s: {})
    alone = assess_session(session)
    assert [(v.trial, v.decision, v.reasons, v.spans) for v in together.trials] == \
        [(v.trial, v.decision, v.reasons, v.spans) for v in alone.trials]
    assert {v.decision for v in together.trials} == {"used", "repaired", "excluded"}
    for a, b in zip(together.levels, alone.levels, strict=True):
        for ta, tb in zip(a.kept, b.kept, strict=True):
            assert np.allclose(ta.force_N, tb.force_N, rtol=0, atol=1e-12)
