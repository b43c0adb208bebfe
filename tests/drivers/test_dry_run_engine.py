"""The dry run is a plan run by the one engine (issue 36), and its streamed trial on the
STG4002 is checked on the dummy load by the lock-in (issue 37 item 8).

On the fake rig (the fake STG's real output across a simulated resistor into the fake
CAIO's monitor input), in real time (``fake_speed = 1``: the streamed trial writes its
updates while it plays, as on the rig). The fakes follow the McsUsbNet manual, section 6.3
"Streaming mode": samples play in order from ``SendStart``; "When DisableContinousMode is
used, the STG stops when it runs out of data".
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from nmsid.cli import main
from nmsid.drivers.dry_run import DryRunSettings
from nmsid.drivers.hardware import build_devices, with_monitor
from nmsid.drivers.hw_config import load_hw_config
from nmsid.drivers.interfaces import StimulatorState
from nmsid.drivers.registry import stimulator_kind
from nmsid.protocols.plan import PlanRefused, dry_run_plan
from nmsid.protocols.session_file import read_session
from nmsid.rig import engine as engine_module
from nmsid.rig.dry_run import report, run_dry_run_plan
from nmsid.testing.fakes import fake_stg_streaming

MONITOR = 7


pytestmark = pytest.mark.usefixtures("deep_fake_fifo")


@pytest.fixture
def rig(tmp_path, write_hw_config):
    """The fake STG + CAIO rig scanning the monitor input, the resistor wired to the
    extensor channel; closed after the test."""
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=1.0, estop="none",
                         monitor=MONITOR)
    cfg = with_monitor(load_hw_config(hw))
    devices = build_devices(cfg)
    devices.clock.bench.dummy_load = (0, 1000.0)
    yield devices, stimulator_kind(cfg.stimulator).dry_run
    devices.close()


@pytest.fixture
def generous_queue(monkeypatch):
    """The streamed trial queues 0.8 s ahead instead of 0.5 s: a host stall up to that long
    on a loaded test machine does not run the STG dry (these tests check the delivered
    amplitude, not the host's speed; the stream running dry has its own test)."""
    monkeypatch.setattr("nmsid.rig.dry_run.STREAM_QUEUE_S", 0.8)


def _run(rig, tmp_path, roles, **kw):
    devices, support = rig
    s = DryRunSettings()
    result = run_dry_run_plan(devices, s, support, roles, fs_Hz=s.monitor_fs_Hz,
                              session_dir=tmp_path / "dry", **kw)
    lines: list[str] = []
    ok = report(result, s, support, fs_Hz=s.monitor_fs_Hz, out=lines.append)
    return ok, "\n".join(lines), result


def _events(path):
    return [(e.kind, e.detail) for e in read_session(path).events]


# -- issue 36: one engine, its preflight, its interlock --------------------------------------
def test_the_dry_run_is_a_plan_held_by_the_engines_preflight(rig, tmp_path, monkeypatch):
    seen = []
    real = engine_module.preflight

    def spy(plan, limits, calibration=None):
        seen.append((plan.kind, [it.max_mA for it in plan], calibration))
        return real(plan, limits, calibration)
    monkeypatch.setattr(engine_module, "preflight", spy)
    ok, text, result = _run(rig, tmp_path, ["download"])
    assert ok, text
    # before anything is connected (no calibration), and with the dummy load's
    # calibration before the first trial
    assert [k for k, _, _ in seen] == ["dry_run"] * len(seen) and len(seen) >= 2
    assert seen[0][1] == [(2.0, 0.0)] and seen[0][2] is None
    cal = seen[-1][2]
    assert cal is not None and (cal.Iemax_mA, cal.Ifmax_mA) == (2.0, 2.0)
    with h5py.File(result.path, "r") as f:
        assert f.attrs["session_kind"] == "dry_run"
    trial = read_session(result.path).trials[0]
    assert trial.completed and trial.extra_attrs["dry_run_role"] == "download"
    assert float(np.max(trial.I_ext_mA)) == pytest.approx(2.0) and not trial.I_flex_mA.any()


def test_an_item_above_the_ceiling_is_refused_before_anything_is_connected(rig, tmp_path):
    devices, _ = rig
    plan = dry_run_plan(["download"], "extensor", 8.0, 1.0, source="test plan")
    with pytest.raises(PlanRefused, match=r"test plan: item 0 .*8\.0 mA is outside \[0, 5\] "
                                          "mA.*nothing was stimulated"):
        _run(rig, tmp_path, ["download"], plan=plan)
    assert devices.stimulator.status().state is StimulatorState.DISCONNECTED
    assert devices.clock.bench.stimulator is None          # no McsUsbNet handle opened
    assert not (tmp_path / "dry").exists() or not any((tmp_path / "dry").iterdir())


def test_an_item_above_the_dummy_loads_calibration_is_refused_before_any_output(rig,
                                                                                tmp_path):
    # within the 5 mA ceiling, above the 2 mA the dummy load was "calibrated" at: the
    # preflight after calibration refuses it, before the first trial
    plan = dry_run_plan(["download"], "extensor", 4.0, 1.0, source="test plan")
    with pytest.raises(PlanRefused, match=r"4 mA is above 2 mA.*no trial was run"):
        _run(rig, tmp_path, ["download"], plan=plan)
    stg = rig[0].clock.bench.stimulator
    assert stg is None or stg.started_at is None            # never started


def test_an_estop_mid_dry_run_ends_with_output_zero_and_an_event(rig, tmp_path):
    ok, text, result = _run(rig, tmp_path, ["estop"])
    assert ok, text
    assert "[PASS] E-stop: trial ended" in text and "[PASS] E-stop: output zero" in text
    assert result.summary.ended_by.startswith("interlock: estop")
    trips = [d for k, d in _events(result.path) if k == "interlock_trip"]
    assert len(trips) == 1 and "E-stop test mid-chirp" in trips[0]
    trial = read_session(result.path).trials[0]
    assert trial.status == "aborted" and 0 < trial.n_samples < 10_000
    assert rig[0].stimulator.status().output_active is False


# -- issue 37 item 8: the STG's streamed trial on the dummy load -----------------------------
def test_probe_streams_a_tracking_style_trial_into_the_dummy_load_on_the_stg(
        tmp_path, write_hw_config, capsys, generous_queue):
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=1.0, estop="none",
                         monitor=MONITOR)
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "dry run, streamed trial: 1 s" in out
    for name in ("stream: ended", "stream: amplitude", "stream: envelope", "amplitude",
                 "E-stop: output zero"):
        assert f"[PASS] {name}:" in out, out
    assert "over 1000 carrier periods of 100 updates" in out
    assert "[FAIL]" not in out and "dry run: OK" in out


def test_a_stream_delivered_off_fails_in_one_line(rig, tmp_path, monkeypatch, generous_queue):
    real = fake_stg_streaming.CStg200xStreamingNet.current_at
    monkeypatch.setattr(fake_stg_streaming.CStg200xStreamingNet, "current_at",
                        lambda self, ch, t: 0.9 * real(self, ch, t))   # a 10 % gain error
    ok, text, _ = _run(rig, tmp_path, ["streamed"])
    assert not ok
    fails = [ln for ln in text.splitlines() if "[FAIL]" in ln]
    assert len(fails) == 1 and fails[0].startswith("  [FAIL] stream: amplitude: max error")
    assert "[PASS] stream: ended" in text


def test_a_stream_that_runs_dry_fails_ends_at_zero_and_is_logged(rig, tmp_path, monkeypatch):
    # frames after 0.3 s never reach the STG's memory: it stops (continuous mode disabled)
    cut = 15_000                                            # frames at 50 kHz
    real = fake_stg_streaming.CStg200xStreamingNet._arrival

    def starved(self, ch, limit=None):
        arr = real(self, ch, limit)
        return np.where(self._head + np.arange(len(arr)) >= cut, np.inf, arr)
    monkeypatch.setattr(fake_stg_streaming.CStg200xStreamingNet, "_arrival", starved)
    ok, text, result = _run(rig, tmp_path, ["streamed"])
    assert not ok
    ended = next(ln for ln in text.splitlines() if "stream: ended" in ln)
    assert ended.startswith("  [FAIL]") and "ran out of streamed data" in ended
    assert "[FAIL] stream: amplitude" in text
    trips = [d for k, d in _events(result.path) if k == "interlock_trip"]
    assert trips and "ran out of streamed data" in trips[0]
    handle = fake_stg_streaming._registry[-1]
    assert handle.stop_t is not None and len(handle.played[0]) <= cut


def _streamed_monitor_V(commands_mA, *, gain=1.0, stop_period=None, fs=10_000.0,
                        ohm=1000.0, K=10):
    """The resistor's volts for streamed updates of K carrier periods each (sine carrier
    from sample 0, as the STG renders each period: manual 6.3)."""
    per = np.repeat(np.asarray(commands_mA, float), K) * 1e-3 * gain
    if stop_period is not None:
        per[stop_period:] = 0.0
    P = int(fs / 1000.0)
    t = np.arange(len(per) * P) / fs
    return np.repeat(per, P) * np.sin(2 * np.pi * 1000.0 * t) * ohm


@pytest.mark.parametrize("gain, stop, passed", [(1.0, None, True), (0.9, None, False),
                                                (1.04, None, True), (1.0, 700, False)])
def test_the_streamed_lockin_check_on_known_records(gain, stop, passed):
    from nmsid.drivers.dry_run import check_stream_lockin
    s = DryRunSettings()
    cmd = [2.0 * (0.5 + 0.4 * np.sin(2 * np.pi * 2.0 * j / 100)) for j in range(100)]
    checks = check_stream_lockin(_streamed_monitor_V(cmd, gain=gain, stop_period=stop), cmd,
                                 100.0, s, s.monitor_fs_Hz)
    amp = checks[0]
    assert amp.name == "stream: amplitude" and amp.passed is passed, amp.line()
    assert "over 1000 carrier periods of 100 updates" in amp.line()


def test_the_streamed_lockin_check_counts_periods_after_the_last_update_as_zero():
    # a record longer than the stream: delivered current after the last update is a fault
    from nmsid.drivers.dry_run import check_stream_lockin
    s = DryRunSettings()
    cmd = [1.0] * 50
    v = _streamed_monitor_V([1.0] * 100)                 # the device went on for 50 more
    assert not check_stream_lockin(v, cmd, 100.0, s, s.monitor_fs_Hz)[0].passed
    assert check_stream_lockin(v[:5000], cmd, 100.0, s, s.monitor_fs_Hz)[0].passed


def test_a_dry_run_current_above_the_rigs_ceiling_is_one_line(tmp_path, write_hw_config,
                                                              capsys):
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=1.0, estop="none",
                         monitor=MONITOR)
    hw.write_text(hw.read_text().replace("ceiling_ext_mA = 16.0", "ceiling_ext_mA = 1.5"))
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and "--dry-run-mA 2 is above stimulator.ceiling_ext_mA = 1.5 mA" \
        in err[0], err
    assert "record:" not in cap.out
