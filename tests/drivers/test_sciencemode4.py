"""The ScienceMode4 driver (P24, RehaMove3, low level) against the byte-level fake: the
confirmed stop (nmsid's E-stop for devices without one), lost and corrupted packets, the
unconfirmed-stop fallback, electrode errors, the ceilings; and the fake's mid-level
keep-alive expiry (IFU "Mid-Level Update", RM3 5.1)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmsid.drivers import sciencemode4_protocol as sm4
from nmsid.drivers.errors import StimulatorSettingError
from nmsid.drivers.interfaces import CheckedWaveform, CurrentLimitError, StimulatorState
from nmsid.drivers.sciencemode4 import P24, REHAMOVE3, Sm4Stimulator
from nmsid.testing.fakes.fake_sciencemode4 import FakeSm4

RATE_HZ = 40.0


def _rig(model=P24, **kw):
    fake = FakeSm4(model.title.split()[-1])
    stim = Sm4Stimulator("COM9", model, ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                         extensor_channel=1, flexor_channel=model.n_channels,
                         pulse_rate_Hz=RATE_HZ, open_port=fake.open, clock=fake.clock, **kw)
    stim.connect()
    return fake, stim


def _waveform(stim, seconds=2.0, mA=10.0):
    n = int(seconds * 1000)
    return CheckedWaveform(np.full(n, mA), np.full(n, mA / 2), 1000.0, 40.0, 20.0, 20.0)


@pytest.mark.parametrize("model", [P24, REHAMOVE3])
def test_stop_reaches_the_last_pulse_within_one_period_and_is_confirmed(model):
    fake, stim = _rig(model)
    try:
        stim.load(_waveform(stim))
        stim.arm()
        stim.start()
        time.sleep(0.4)
        t_stop = fake.clock()          # the E-stop, on the fake's clock
        stim.stop_now()
        time.sleep(0.1)
        last = max(p[0] for p in fake.pulses)
        # IFU "Ll_channel_config_ack ... after the stimulation has been executed": one
        # pulse command outstanding at most, so the last pulse began < one period later
        assert last - t_stop <= 1.0 / RATE_HZ, (last - t_stop)
        assert fake.level == sm4.STIM_NONE and [w for _, w in stim.stop_log][-1] == "confirmed"
        assert stim.status().state is StimulatorState.STOPPED
        assert {p[1] for p in fake.pulses} == {1, model.n_channels}
        assert max(p[2] for p in fake.pulses) == 10.0
        summary = stim.delivery_summary()
        assert summary["ended_by"] == "stop_now"
        assert summary["channels"]["flexor"]["peak_current_mA"] == 5.0
    finally:
        stim.disconnect()


def test_a_lost_stop_is_resent_and_confirmed():
    fake, stim = _rig()
    try:
        stim.load(_waveform(stim, 1.0))
        stim.arm()
        stim.start()
        time.sleep(0.2)
        fake.lose_next(sm4.LL_STOP)
        stim.stop_now()
        assert sm4.LL_STOP in fake.lost
        assert fake.level == sm4.STIM_NONE
        assert [w for _, w in stim.stop_log][-1] == "confirmed"
        n = len(fake.pulses)
        time.sleep(0.1)
        assert len(fake.pulses) == n
    finally:
        stim.disconnect()


def test_a_corrupted_reply_is_asked_again_at_once_not_after_a_timeout():
    fake, stim = _rig()
    try:
        fake.corrupt_next_reply(sm4.GET_STIM_STATUS)
        t0 = time.monotonic()
        assert stim.stim_level() == sm4.STIM_NONE
        # science_mode_4 0.0.23 drops it and waits 5 s; here the next try answers
        assert time.monotonic() - t0 < 2 * 0.1 + 0.5
    finally:
        stim.disconnect()


def test_a_corrupted_pulse_is_counted_not_delivered_and_the_trial_goes_on():
    fake, stim = _rig()
    try:
        fake.corrupt_next(sm4.LL_CHANNEL_CONFIG, 2)
        stim.load(_waveform(stim, 0.5))
        stim.arm()
        stim.start()
        time.sleep(0.8)
        s = stim.delivery_summary()
        assert s["ended_by"] == "completed" and s["updates_transfer_error"] == 2
        assert fake.transfer_errors == 2 and stim.status().state is StimulatorState.STOPPED
    finally:
        stim.disconnect()


def test_an_unconfirmed_stop_goes_silent_and_tells_the_operator_to_switch_off(caplog):
    fake, stim = _rig()
    try:
        stim.load(_waveform(stim, 2.0))
        stim.arm()
        stim.start()
        time.sleep(0.2)
        fake.line_down(10.0)
        stim.stop_now()
        st_ = stim.status()
        assert st_.state is StimulatorState.ERROR and "SWITCH THE P24 OFF" in st_.error
        assert [w for _, w in stim.stop_log][-1] == "unconfirmed"
        n_written = len(fake.lost)
        stim.stop_now()                        # idempotent, and still nothing written
        time.sleep(0.1)
        assert len(fake.lost) == n_written
        assert sum("SWITCH THE P24 OFF" in r.message for r in caplog.records) == 1
    finally:
        stim.disconnect()


def test_an_electrode_error_ends_the_trial_in_error():
    fake, stim = _rig(REHAMOVE3)
    try:
        fake.electrode_error(1)
        stim.load(_waveform(stim, 1.0))
        stim.arm()
        stim.start()
        time.sleep(0.3)
        assert stim.status().state is StimulatorState.ERROR
        assert "electrode error" in stim.status().error
    finally:
        stim.disconnect()


def test_a_level_left_running_is_stopped_at_connect():
    fake = FakeSm4("P24")
    fake.level = sm4.STIM_LL                   # a previous program left low level on
    stim = Sm4Stimulator("COM9", P24, ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                         open_port=fake.open, clock=fake.clock)
    stim.connect()
    try:
        assert fake.level == sm4.STIM_NONE
    finally:
        stim.disconnect()


@pytest.mark.parametrize("kw,match", [
    ({"flexor_channel": 5}, "flexor_channel"),                  # RehaMove3 has 4
    ({"ceiling_ext_mA": 150.0}, "130"),
    ({"pulse_width_us": 10}, "pulse_width_us"),                 # RehaMove3 >= 20 us
    ({"pulse_rate_Hz": 500.0}, "pulse_rate_Hz")])
def test_settings_outside_the_rehamove3_ranges_are_refused(kw, match):
    base = {"ceiling_ext_mA": 20.0, "ceiling_flex_mA": 20.0}
    with pytest.raises(StimulatorSettingError, match=match):
        Sm4Stimulator("COM9", REHAMOVE3, **{**base, **kw})


def test_currents_never_above_the_ceiling():
    fake, stim = _rig()

    @settings(max_examples=60, deadline=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(st.lists(st.floats(0.0, 20.0), min_size=1, max_size=200),
           st.floats(0.5, 20.0), st.floats(0.0, 40.0))
    def check(env, ceiling, streamed):
        env = np.minimum(np.asarray(env), ceiling)
        w = CheckedWaveform(env, env[::-1], 1000.0, 40.0, ceiling, ceiling)
        stim.load(w)
        trial = np.asarray(stim._trial)
        assert trial.size == 0 or trial.max() <= ceiling
        assert np.all(trial * 2 == np.round(trial * 2))          # 0.5 mA steps
        stim.open_stream(ceiling, ceiling, RATE_HZ)
        if streamed > ceiling:
            with pytest.raises(CurrentLimitError):
                stim.write_stream(np.array([streamed]), np.array([0.0]))
        with pytest.raises(CurrentLimitError):                   # the encoder refuses too
            stim._pulse_data(1, 20.5)
        stim.stop_now()

    try:
        check()
        assert not fake.pulses or max(p[2] for p in fake.pulses) <= 20.0
    finally:
        stim.disconnect()


def test_the_fake_mid_level_stops_two_seconds_after_the_last_keep_alive():
    clock = {"t": 0.0}
    fake = FakeSm4("RehaMove3", clock=lambda: clock["t"], response_latency_s=0.0)
    port = fake.open()
    pts = sm4.biphasic_points(12.0, 200, 100)
    port.write(sm4.encode(0, sm4.ML_INIT, bytes((0,))))
    port.write(sm4.encode(1, sm4.ML_UPDATE, sm4.ml_update_data({0: (25.0, pts)})))
    for k in range(1, 4):                      # a keep-alive every second: still running
        clock["t"] = float(k)
        port.write(sm4.encode(2 + k, sm4.ML_GET_CURRENT_DATA, sm4.ml_get_current_data_data()))
    clock["t"] = 4.9
    assert fake.level == 3 or fake.in_waiting >= 0 and fake.level == 3
    clock["t"] = 5.1                           # 2.1 s after the last one: expired
    _ = fake.in_waiting
    assert fake.keepalive_expiries == 1 and fake.level == sm4.STIM_ML
    assert fake.amplitude_mA_at(1, [4.9])[0] == 12.0
    assert fake.amplitude_mA_at(1, [5.05])[0] == 0.0
    replies = sm4.Decoder().feed(port.read(4096))
    assert [p.command for p in replies] == [31, 33, 37, 37, 37]


def _mid_rig(model=P24):
    from nmsid.drivers.sciencemode4_mid import Sm4MidLevelStimulator
    fake = FakeSm4(model.title.split()[-1])
    stim = Sm4MidLevelStimulator("COM9", model, ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                                 extensor_channel=1, flexor_channel=2, pulse_rate_Hz=RATE_HZ,
                                 open_port=fake.open, clock=fake.clock)
    stim.connect()
    return fake, stim


@pytest.mark.parametrize("model", [P24, REHAMOVE3])
def test_mid_level_trial_runs_and_its_stop_is_confirmed(model):
    fake, stim = _mid_rig(model)
    try:
        stim.load(_waveform(stim, 1.0))
        stim.arm()
        assert fake.level == sm4.STIM_ML
        stim.start()
        time.sleep(0.3)
        t_stop = fake.clock()
        stim.stop_now()
        assert fake.level == sm4.STIM_NONE and [w for _, w in stim.stop_log][-1] == "confirmed"
        start, end, chans = fake.ml_spans[-1]
        assert chans == {1: (25.0, 10.0), 2: (25.0, 5.0)}     # 40 Hz: 25 ms periods
        assert end - t_stop <= 1.0 / RATE_HZ                  # the device's last pulse
        assert stim.delivery_summary()["channels"]["extensor"]["pulses_acknowledged"] > 0
    finally:
        stim.disconnect()


def test_mid_level_stream_is_kept_alive_while_it_waits():
    fake, stim = _mid_rig()
    try:
        stim.open_stream(20.0, 20.0, RATE_HZ)
        stim.write_stream(np.array([8.0]), np.array([4.0]))
        stim.start()
        time.sleep(2.6)          # the queue ran dry 2.5 s ago: only the keep-alive remains
        assert fake.level == 3 and fake.keepalive_expiries == 0
        assert sum(c == sm4.ML_GET_CURRENT_DATA for _, c in fake.received) >= 3
        stim.close_stream()
        assert fake.level == sm4.STIM_NONE
    finally:
        stim.disconnect()


def test_mid_level_unconfirmed_stop_withholds_the_keep_alive_so_the_device_stops():
    fake, stim = _mid_rig()
    try:
        stim.open_stream(20.0, 20.0, RATE_HZ)
        stim.write_stream(np.array([8.0]), np.array([4.0]))
        stim.start()
        time.sleep(0.2)
        fake.line_down(1.5)                   # the stop and its resends are all lost
        stim.stop_now()
        assert "SWITCH THE P24 OFF" in stim.status().error and "no keep-alive" in \
            stim.status().error
        time.sleep(2.3)                       # nothing written since: the device's timeout
        _ = fake.in_waiting
        assert fake.keepalive_expiries == 1 and fake.level == sm4.STIM_ML
        assert fake.amplitude_mA_at(1, [fake.clock()])[0] == 0.0
    finally:
        stim.disconnect()


def test_mid_level_electrode_error_ends_the_trial():
    fake, stim = _mid_rig(REHAMOVE3)
    try:
        stim.load(_waveform(stim, 2.0))
        stim.arm()
        stim.start()
        time.sleep(0.2)
        fake.electrode_error(2)
        time.sleep(0.9)                       # the next Ml_get_current_data tells
        assert stim.status().state is StimulatorState.ERROR
        assert "electrode error" in stim.status().error
        assert fake.level == sm4.STIM_NONE    # stopped, confirmed
    finally:
        stim.disconnect()


def test_mid_level_refuses_a_rate_off_the_half_millisecond_grid():
    from nmsid.drivers.sciencemode4_mid import Sm4MidLevelStimulator
    with pytest.raises(StimulatorSettingError, match="0.5 ms"):
        Sm4MidLevelStimulator("COM9", P24, ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                              pulse_rate_Hz=30.0)


def test_the_dry_runs_pulse_check_sees_half_milliampere_pulses_whole():
    # 0.5 mA pulses (the ScienceMode4 step, IFU Table 15) sent with the driver's codec to
    # the fake P24, sampled at the dry run's 10 kHz with its 1 mV noise over 1 kOhm, start
    # at random phases of the sample grid. Each is +I, pause, -I of equal widths (IFU
    # Table 15, RM3 7.1): the check must find every one and call it balanced. (It found a
    # pulse where the current rose above a fixed 0.5 mA, so noise on a 0.5 mA pulse cut
    # its first sample off: "worst net 49.8 nC per pulse", issue 43.)
    from nmsid.drivers.dry_run import DryRunSettings, check_pulses
    now = [1.0]
    fake = FakeSm4("P24", clock=lambda: now[0])
    port = fake.open()
    port.write(sm4.encode(0, sm4.LL_INIT, sm4.ll_init_data()))
    rng = np.random.default_rng(5)
    amps = [0.5, 0.5, 1.0, 0.5, 2.0, 0.5] * 5
    for k, a in enumerate(amps):
        now[0] = 1.0 + k / RATE_HZ + rng.uniform(0, 1e-4)
        port.write(sm4.encode((k + 1) & 0x3F, sm4.LL_CHANNEL_CONFIG,
                              sm4.ll_channel_config_data(
                                  0, 0, sm4.biphasic_points(a, 300, 100))))
    assert len(fake.pulses) == len(amps)
    s = DryRunSettings()
    t = 0.99 + np.arange(int(s.monitor_fs_Hz)) / s.monitor_fs_Hz
    volts = fake.current_at(0, t) * 1e-9 * s.load_ohm + 1e-3 * rng.standard_normal(len(t))
    checks = {c.name: c for c in check_pulses(volts, s, amps, 300.0, 100.0)}
    assert checks["pulse count"].figure.startswith(f"{len(amps)} pulses found"), \
        checks["pulse count"].line()
    assert all(c.passed for c in checks.values()), [c.line() for c in checks.values()]


def test_answers_later_than_the_next_pulse_count_as_answered_not_lost():
    # The P24 answers in 5-15 ms (issue 43) and a busy host reads an answer late: at 100 Hz
    # every answer here comes after the next pulse is due, so the driver sends that pulse
    # (a lost answer costs its own slot only); the answer that arrives afterwards still
    # counts the pulse acknowledged (IFU "Ll_channel_config_ack": sent after the pulse).
    # They were counted unanswered and dropped: "updates answered" failed the dry run.
    fake = FakeSm4("P24", response_latency_s=(0.012, 0.015), seed=3)
    stim = Sm4Stimulator("COM9", P24, ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                         extensor_channel=1, flexor_channel=5, pulse_rate_Hz=100.0,
                         open_port=fake.open, clock=fake.clock)
    stim.connect()
    try:
        n = 500
        stim.load(CheckedWaveform(np.full(n, 4.0), np.zeros(n), 1000.0, 40.0, 20.0, 20.0))
        stim.arm()
        stim.start()
        deadline = time.monotonic() + 10.0        # generous: a loaded host (not timed)
        while "confirmed" not in [w for _, w in stim.stop_log] and \
                time.monotonic() < deadline:      # the last answer comes before the stop's
            time.sleep(0.02)
        s = stim.delivery_summary()
    finally:
        stim.disconnect()
    assert s["ended_by"] == "completed" and s["updates_sent"] > 0
    assert s["updates_unanswered"] == 0, s
    assert s["updates_acknowledged"] == s["updates_sent"] == len(fake.pulses)
    assert s["updates_answered_late"] > 0


def test_a_slot_the_host_skipped_has_no_low_level_pulse_in_the_dry_runs_count():
    # Low level is one command per pulse (IFU "Low-Level channel configuration"): a slot
    # the host skipped to keep the time base has no pulse, unlike the RehaStim2's and the
    # mid level's repeated update (ScienceMode2 1.3, IFU "Mid-Level Update"). The dry run
    # filled the gap with the previous current and failed "pulse count" on a busy host
    # ("32 pulses found, 37 non-zero pulse periods").
    from nmsid.drivers.dry_run import DryRunSettings, check_pulses
    from nmsid.drivers.sciencemode4_mid import Sm4MidLevelStimulator
    now = [1.0]
    fake = FakeSm4("P24", clock=lambda: now[0])
    port = fake.open()
    port.write(sm4.encode(0, sm4.LL_INIT, sm4.ll_init_data()))
    slots = [0, 1, 2, 8, 9, 10, 11, 12, 18, 19]          # two stalls of 5 slots
    amps = [1.0, 2.0] * 5
    for n, (k, a) in enumerate(zip(slots, amps, strict=True)):
        now[0] = 1.0 + k / RATE_HZ
        port.write(sm4.encode(n + 1, sm4.LL_CHANNEL_CONFIG, sm4.ll_channel_config_data(
            0, 0, sm4.biphasic_points(a, 300, 100))))
    s = DryRunSettings()
    t = 0.99 + np.arange(int(s.monitor_fs_Hz)) / s.monitor_fs_Hz
    volts = fake.current_at(0, t) * 1e-9 * s.load_ohm
    fake2, stim = _rig()
    try:
        stim.load(_waveform(stim, 0.1))
        stim.arm()
        stim.start()
        time.sleep(0.3)
        repeats = stim.delivery_summary()["repeats_update"]
    finally:
        stim.disconnect()
    assert repeats is False
    checks = {c.name: c.passed for c in check_pulses(volts, s, amps, 300.0, 100.0,
                                                     pulse_index=slots, repeats=repeats)}
    assert checks == {"pulse count": True, "pulse amplitude": True, "charge balance": True}
    mid = Sm4MidLevelStimulator("COM9", P24, ceiling_ext_mA=5.0, ceiling_flex_mA=5.0,
                                open_port=fake2.open)
    assert mid.repeats_update is True
