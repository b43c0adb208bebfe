"""A first session that is not second order keeps the paper's excitation: the best
second-order twin of such a participant depends on the input, so only the lead-in, levels
and repeats may change."""

import csv
import json

import pytest

from nmsid.analysis.design.candidates import (
    Candidate,
    paper_candidate,
    search_space,
    with_paper_excitation,
)
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.prior import SECOND_ORDER_FIT_PCT, adequacy_from_parameters
from nmsid.cli import main

FIRST = Candidate(sE_levels=(0.30, 0.45, 0.60, 0.80, 1.00), repeats=2, label="first")
SHORT_INPUT = Candidate(sE_levels=(0.3, 0.45, 0.6, 0.8, 1.0), repeats=3, steady_s=2.0,
                        chirp_s=4.0, rest_s=24.0, label="short-input")
PAPER_INPUT = Candidate(sE_levels=(0.3, 0.45, 0.6, 0.8, 1.0), repeats=3, steady_s=2.0,
                        chirp_s=10.0, rest_s=48.0, label="paper-input")


def _params(path, fits):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["participant", "sE", "fit_pct"])
        for k, f in enumerate(fits):
            w.writerow(["P1", 0.3 + 0.1 * k, f])
    return path


@pytest.mark.parametrize("fits,second_order", [
    ([99.6, 99.7, 99.8, 99.8, 99.9], True), ([98.2, 97.5, 97.1, 99.0, 96.0], True),
    ([89.9, 89.7, 89.6, 89.4, 89.2], False), ([80.3, 99.5, 80.3, 80.3, 99.5], False),
    ([float("nan"), 88.0, 87.0], False)])
def test_adequacy_is_the_median_fit_against_the_threshold(tmp_path, fits, second_order):
    a = adequacy_from_parameters(_params(tmp_path / "p.csv", fits))
    assert a.second_order is second_order and a.threshold_pct == SECOND_ORDER_FIT_PCT
    assert ("NOT second order" in a.sentence()) is (not second_order)


def test_adequacy_from_a_bad_file_names_it(tmp_path):
    with pytest.raises(DesignError, match="nope.csv"):
        adequacy_from_parameters(tmp_path / "nope.csv")
    (tmp_path / "nofit.csv").write_text("participant,sE,Kp\nP1,0.3,1\n")
    with pytest.raises(DesignError, match="fit_pct"):
        adequacy_from_parameters(tmp_path / "nofit.csv")


def test_paper_excitation_candidates_vary_only_what_leaves_the_twin_alone():
    everything = search_space()
    kept = with_paper_excitation(everything)
    p = paper_candidate()
    assert 0 < len(kept) < len(everything)
    assert {(c.input_kind, c.chirp_s, c.chirp_f0_Hz, c.chirp_f1_Hz, c.rE_amplitude)
            for c in kept} == {(p.input_kind, p.chirp_s, p.chirp_f0_Hz, p.chirp_f1_Hz,
                                p.rE_amplitude)}
    assert len({(c.sE_levels, c.repeats) for c in kept}) > 5   # levels and repeats free


@pytest.fixture(scope="module")
def first_session(tmp_path_factory):
    """twin.json + parameters.csv of a first session on a second-order participant whose
    physiology scatters between trials (so a shorter input is enough for it)."""
    from nmsid.analysis.design.validate import simulate_session
    from nmsid.analysis.run import run_identification
    from nmsid.sim_backends.population import make_population
    out = tmp_path_factory.mktemp("first")
    vp = make_population(1, seed=12)[0]
    scatter = {"Kp": 0.1, "wn_rad_s": 0.05, "zeta": 0.05}
    run_identification([simulate_session(vp, FIRST, scatter=scatter, seed=1)], out,
                       figures=False)
    return out


def _design(out_dir, first, monkeypatch, params, *extra):
    import nmsid.analysis.design.api as api
    monkeypatch.setattr(api, "search_space", lambda **kw: [SHORT_INPUT, PAPER_INPUT])
    code = main(["design", "--twin", str(first / "twin.json"), "--scatter-from",
                 str(params), "--validate", "0", "--out", str(out_dir), *extra])
    assert code == 0
    return json.loads((out_dir / "design.json").read_text())


def test_second_order_first_session_lets_the_input_shrink(first_session, tmp_path,
                                                          monkeypatch, capsys):
    doc = _design(tmp_path / "d", first_session, monkeypatch, first_session / "parameters.csv")
    assert "second order within the noise" in capsys.readouterr().out
    assert doc["excitation"]["kept_paper_excitation"] is False
    # the shorter input was tried first (it is cheaper), whatever the prior then needs
    assert doc["search"]["candidates_evaluated"] == 2 or doc["protocol"]["chirp_s"] == 4.0


def test_first_session_that_is_not_second_order_keeps_the_papers_input(
        first_session, tmp_path, monkeypatch, capsys):
    rows = list(csv.DictReader(open(first_session / "parameters.csv", newline="")))
    for r in rows:                               # the same session, fits of a Hill model
        r["fit_pct"] = "86.5"
    bad = tmp_path / "parameters.csv"
    with open(bad, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    doc = _design(tmp_path / "d", first_session, monkeypatch, bad)
    out = capsys.readouterr().out
    assert "NOT second order" in out
    assert doc["excitation"]["kept_paper_excitation"] is True
    assert doc["protocol"]["chirp_s"] == 10.0 and doc["protocol"]["chirp_f0_Hz"] == 1.0
    assert doc["search"]["candidates_evaluated"] == 1      # the short input never tried
    assert "the paper's, kept" in (tmp_path / "d" / "report.txt").read_text()
    # asked to search freely anyway: the report says so
    doc = _design(tmp_path / "f", first_session, monkeypatch, bad, "--excitation", "free")
    assert doc["excitation"]["kept_paper_excitation"] is False
    assert "--excitation free" in doc["excitation"]["why"]
