"""``nmsid stimulation``: the done-when figure from the files it writes, and its refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.cli import main


def test_default_protocol_full_range_is_balanced_per_period_in_the_npz(tmp_path, capsys):
    out = tmp_path / "stim"
    assert main(["stimulation", "--calibration", "2,16,1.5,16", "--out", str(out)]) == 0
    report = json.loads((out / "stimulation.json").read_text())
    assert report["worst_net_charge_per_period_nC"] <= 1.0
    npz = np.load(out / "samples.npz")
    rate, carrier = float(npz["output_rate_Hz"]), float(npz["carrier_Hz"])
    assert (rate, carrier) == (50_000.0, 1000.0)
    P, tick_s = int(rate / carrier), 1.0 / rate
    levels = [lv["sE"] for lv in report["levels"]]
    assert len(levels) == 15 and f"sE{levels[0]:.2f}_ext" == "sE0.30_ext"
    worst_nC = 0.0
    for lv in report["levels"]:
        for short, name in (("ext", "extensor"), ("flex", "flexor")):
            x = npz[f"sE{lv['sE']:.2f}_{short}"].astype(np.int64)
            assert len(x) == 15 * rate + 1 and x[-1] == 0      # one trial, as downloaded
            n = len(x) // P
            net_nC = np.abs(x[:n * P].reshape(n, P).sum(axis=1)).max() * tick_s
            worst_nC = max(worst_nC, net_nC)
            ch = lv["channels"][name]
            assert ch["peak_current_mA"] == pytest.approx(np.abs(x).max() / 1e6)
            assert ch["net_charge_per_trial_uC"] == pytest.approx(x.sum() * tick_s / 1e3)
            assert ch["fits_channel_memory"] is True
    assert worst_nC <= 1.0
    top = report["levels"][-1]["channels"]["extensor"]
    assert 15.0 < top["peak_current_mA"] <= 16.0       # sE 1.0 reaches Iemax (16 mA)
    assert "worst net charge per carrier period 0.000 nC" in capsys.readouterr().out


def test_existing_out_is_refused_unless_force(tmp_path, capsys):
    cfg = tmp_path / "p.toml"
    cfg.write_text("[protocol]\nsE_levels = [0.5]\nsteady_s = 0.1\nchirp_s = 0.2\n")
    out = tmp_path / "stim"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    args = ["stimulation", "--config", str(cfg), "--calibration", "2,8,2,8", "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "exists" in err and "--force" in err and err.count("\n") == 1
    assert not (out / "stimulation.json").exists()
    assert main(args + ["--force"]) == 0
    assert (out / "notes.txt").read_text() == "mine"        # nothing else touched
    assert set(np.load(out / "samples.npz").files) == {"output_rate_Hz", "carrier_Hz",
                                                       "sE0.50_ext", "sE0.50_flex"}


@pytest.mark.parametrize("cal, msg", [("2,16,1.5", "expected four numbers"),
                                      ("2,x,1,3", "expected four numbers"),
                                      ("5,4,1,3", "Iemax_mA > Iemin_mA")])
def test_bad_calibration_is_one_line(tmp_path, capsys, cal, msg):
    assert main(["stimulation", "--calibration", cal, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert msg in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()
