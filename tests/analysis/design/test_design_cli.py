"""``nmsid design`` end to end: outputs, the proposed protocol run, validated, identified,
diagnosed; user mistakes in one line."""

import dataclasses
import json

import numpy as np
import pytest

from nmsid.analysis.design.api import run_design
from nmsid.analysis.design.candidates import Candidate
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.predict import DEFAULT_SCATTER
from nmsid.analysis.design.prior import PARAMETERS, population_prior
from nmsid.analysis.design.search import parse_target
from nmsid.analysis.design.validate import alternative_scatter
from nmsid.cli import main
from nmsid.protocols.config import load_config
from nmsid.protocols.session_file import read_session, trial_input, validate_session

SMALL_MULTISINE = Candidate(sE_levels=(0.3, 0.45, 0.6, 0.8, 1.0), repeats=2, steady_s=1.0,
                            chirp_s=3.0, input_kind="multisine", multisine_tones=10,
                            rest_s=10.0, label="small-multisine")
SMALL_CHIRP = Candidate(sE_levels=(0.3, 0.45, 0.6, 0.8, 1.0), repeats=2, steady_s=1.0,
                        chirp_s=3.0, rest_s=10.0, label="small-chirp")


@pytest.fixture(scope="module")
def designed(tmp_path_factory):
    out = tmp_path_factory.mktemp("design")
    outcome = run_design(population_prior(2, seed=3), "paper", out, validate_n=1,
                         candidates=[SMALL_CHIRP, SMALL_MULTISINE], draws=10)
    _OUTCOME.append(outcome)
    return out, outcome.to_dict()


_OUTCOME: list = []


def test_run_design_returns_an_object_with_a_verdict(designed):
    """Issue 39: run_design returns a result object; design says pass or fail in one line."""
    out, doc = designed
    outcome = _OUTCOME[-1]
    assert outcome.to_dict() is doc and outcome.found is False
    assert outcome.verdict == "FAIL"
    assert outcome.verdict_line().startswith("verdict: FAIL: no candidate met the target")
    assert "FAIL" in repr(outcome) and "\n" not in repr(outcome)
    # the verdict of a found proposal follows the validated ratio and its Monte-Carlo SE
    found = dict(doc, found=True)
    for ratio, se, verdict in ((1.01, 0.05, "PASS"), (1.05, 0.02, "UNDECIDED"),
                               (1.25, 0.05, "FAIL"), (None, None, "NOT VALIDATED")):
        o = dataclasses.replace(outcome, document=dict(found, validated_sd_ratio=ratio,
                                                       validated_sd_ratio_se=se))
        assert o.verdict == verdict
        assert o.verdict_line().startswith(f"verdict: {verdict}:")
    o = dataclasses.replace(outcome, document=dict(found, validated_sd_ratio=1.25,
                                                   validated_sd_ratio_se=0.05))
    assert "1.250 +- 0.050 > 1.02" in o.verdict_line()


def test_outputs_have_the_promised_fields(designed):
    out, doc = designed
    for name in ("protocol.toml", "design.json", "report.txt", "report.html"):
        assert (out / name).is_file()
    d = json.loads((out / "design.json").read_text())
    for key in ("stimulation_s", "paper_stimulation_s", "predicted_sd_ratio",
                "validated_sd_ratio", "selection_accuracy"):
        assert key in d
    assert d["paper_stimulation_s"] == 675.0
    assert d["stimulation_s"] == 5 * 2 * 4.0
    assert set(d["selection_accuracy"]) >= {"proposal", "paper"}
    # 10 trials of 3 s against 45 of 10 s: far less information; the target is missed,
    # and the design says so rather than pretending
    assert d["found"] is False and d["predicted_sd_ratio"] > 1.02
    assert "NO CANDIDATE MET THE TARGET" in (out / "report.txt").read_text()
    # three validation runs: the assumed scatter, sensor noise alone, another scatter model;
    # each ratio is the proposal's realised curve error over the paper's, worst parameter
    v = d["validation"]
    assert v["other_scatter"]["model"] == alternative_scatter(DEFAULT_SCATTER).label
    for run in (v, v["without_scatter"], v["other_scatter"]):
        rms = run["curve_rms_rel"]
        ratios = [rms["proposal"][n] / rms["paper"][n] for n in PARAMETERS]
        assert run["validated_sd_ratio"] == pytest.approx(max(ratios), rel=1e-12)
        assert run["validated_sd_ratio_se"] is None          # one participant: no SE
    assert d["validated_sd_ratio"] == v["validated_sd_ratio"]
    text = (out / "report.txt").read_text()
    assert text.count("n/a (one participant)") == 3
    assert "under a scatter model the design did not assume (correlated (0.6)" in text
    assert "what this does not promise" in (out / "report.txt").read_text()


def test_designed_protocol_runs_validates_identifies_and_gap_works(designed, tmp_path,
                                                                   capsys):
    out, doc = designed
    cfg = load_config(out / "protocol.toml")
    assert cfg.protocol.sE_levels == tuple(doc["protocol"]["sE_levels"])
    session = tmp_path / "D01.h5"
    code = main(["run", "--backend", "sim", "--config", str(out / "protocol.toml"),
                 "--participant", "D01", "--out", str(session), "--seed", "1",
                 "--no-identify", "--quiet"])
    assert code == 0 and validate_session(session) == []
    s = read_session(session)
    assert len(s.trials) == cfg.protocol.repeats * len(cfg.protocol.sE_levels)
    kind = trial_input(s.trials[0])["kind"]
    assert kind == cfg.protocol.input_kind.value
    assert main(["identify", str(session), "--out", str(tmp_path / "id")]) == 0
    assert (tmp_path / "id" / "twin.json").is_file()
    assert main(["gap", str(session), "--out", str(tmp_path / "gap"), "--no-figures",
                 "--no-pairs"]) == 0
    assert (tmp_path / "gap" / "gap_report.json").is_file()


def test_multisine_session_identifies_close_to_the_truth(tmp_path):
    from nmsid.analysis.design.validate import simulate_session
    from nmsid.analysis.identify import identify_session
    from nmsid.sim_backends.population import make_population
    vp = make_population(1, seed=11)[0]
    res = identify_session(simulate_session(vp, SMALL_MULTISINE, seed=2))
    for lv in res.levels:
        truth = vp.true_parameters(lv.sE)
        est = np.array([lv.fit.Kp, lv.fit.wn_rad_s, lv.fit.zeta])
        assert np.all(np.abs(est / np.array(truth) - 1) < 0.03)


def test_cli_design_writes_outputs_and_prints_the_ratio(tmp_path, capsys, monkeypatch):
    import nmsid.analysis.design.api as api
    real = api.search_space
    monkeypatch.setattr(api, "search_space", lambda **kw: [SMALL_CHIRP])
    code = main(["design", "--population", "--n-prior", "2", "--validate", "0",
                 "--out", str(tmp_path / "d")])
    text = capsys.readouterr().out
    assert code == 0 and "predicted_sd_ratio" in text and "validated_sd_ratio not run" in text
    d = json.loads((tmp_path / "d" / "design.json").read_text())
    assert d["validated_sd_ratio"] is None
    assert (tmp_path / "d" / "design.png").stat().st_size > 1000
    assert (tmp_path / "d" / "design.pdf").read_bytes()[:5] == b"%PDF-"
    monkeypatch.setattr(api, "search_space", real)


@pytest.mark.parametrize("args, words", [
    (["--population", "--target", "Kp=abc"], "not a number"),
    (["--population", "--target", "speed=0.1"], "unknown parameter"),
    (["--population", "--validate", "-1"], "--validate"),
    (["--twin", "missing-twin.json"], "missing-twin.json"),
])
def test_user_mistakes_end_in_one_line(tmp_path, capsys, args, words):
    code = main(["design", *args, "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_sd_target_parses_and_refuses_nonsense():
    t = parse_target("Kp=0.05,wn=0.03,zeta=0.04")
    assert t.kind == "sd" and t.sd == {"Kp": 0.05, "wn_rad_s": 0.03, "zeta": 0.04}
    with pytest.raises(DesignError, match="paper"):
        parse_target("fast")
    with pytest.raises(DesignError, match="relative SD"):
        parse_target("Kp=0")


def test_a_multisine_protocol_runs_and_identify_and_gap_work_on_it(tmp_path):
    from nmsid.analysis.design.report import protocol_toml
    toml = tmp_path / "ms.toml"
    toml.write_text(protocol_toml(SMALL_MULTISINE, "a multisine protocol"))
    session = tmp_path / "M01.h5"
    assert main(["run", "--backend", "sim", "--config", str(toml), "--participant", "M01",
                 "--out", str(session), "--seed", "2", "--no-identify", "--quiet"]) == 0
    assert validate_session(session) == []
    s = read_session(session)
    inp = trial_input(s.trials[0])
    assert inp["kind"] == "multisine" and len(inp["tones_Hz"]) == 10
    assert s.trials[0].chirp_s == 3.0 and s.trials[0].chirp_f1_Hz == 10.0
    assert main(["identify", str(session), "--out", str(tmp_path / "id")]) == 0
    params = (tmp_path / "id" / "parameters.csv").read_text().splitlines()
    fits = [float(line.split(",")[5]) for line in params[1:]]
    assert len(fits) == 5 and min(fits) > 90.0
    assert main(["gap", str(session), "--out", str(tmp_path / "gap"), "--no-figures",
                 "--no-pairs"]) == 0
