"""The STG4002 driver against the vendor's documented behaviour (issue 16, "STG4002").

One test per defect found in review; each failed on the driver before the fix (checked by
running this file against the previous ``drivers/stg4002.py``). The fake models McsUsbNet
as documented (see ``testing/fakes/fake_mcs_usb.py``), not the driver.
"""

from __future__ import annotations

import logging
import threading

import numpy as np
import pytest

from nmsid.drivers.errors import DeviceError, StimulatorSettingError
from nmsid.drivers.interfaces import CheckedWaveform, StimulatorState
from nmsid.drivers.stg4002 import Stg4002Stimulator

FS = 2000.0


def waveform(seconds=0.2, amp=4.0):
    env = np.full(int(seconds * FS), amp)
    return CheckedWaveform(env, env * 0.5, FS, 1000.0, 12.0, 12.0)


def make(fake_mcs, **hw):
    reg = fake_mcs(hardware=[fake_mcs.module.FakeStgHardware(**hw)])
    stim = Stg4002Stimulator(ceiling_ext_mA=12.0, ceiling_flex_mA=12.0,
                             clock=fake_mcs.bench.now)
    return reg, reg.hardware[0], stim


def start(stim, wf=None):
    stim.load(wf or waveform())
    stim.arm()
    stim.start()


def test_finished_is_an_end_not_running_and_an_early_end_is_a_fault(fake_mcs):
    # Stg200xTriggerStatusEnumNet: Finished = 2 must not read as running (bool(2)); a pulse
    # on the trigger input stops the pattern (SetupRetriggerMode default): the trial ended
    # early and must not be recorded as complete
    reg, hw, stim = make(fake_mcs, start_status=3)  # Armed during the start delay
    stim.connect()
    reg.devices[-1].DisableAutoReset()   # status stays Finished (XML: DisableAutoReset)
    start(stim, waveform(seconds=1.0))
    fake_mcs.bench.sleep(0.1)
    assert stim.status().state is StimulatorState.RUNNING
    hw.trigger_pulse(0)
    assert hw.status_at(hw.now())[0] == 2
    st = stim.status()
    assert st.state is StimulatorState.ERROR and not st.output_active
    assert "ended the pattern after" in st.error and "FINISHED" in st.error


def test_running_that_arrives_late_is_still_running(fake_mcs):
    # SendStart: "The startup delay is in the range of a few ms"; here 0.3 s. The output
    # is on until the device says it ended, not when the host's clock says so
    reg, hw, stim = make(fake_mcs, start_delay_s=0.3)
    stim.connect()
    start(stim, waveform(seconds=0.2))
    fake_mcs.bench.sleep(0.25)       # past the nominal end, the device is still starting
    st = stim.status()
    assert st.state is StimulatorState.RUNNING and st.output_active
    fake_mcs.bench.sleep(0.15)       # device running now (0.3 .. 0.5 s)
    assert np.any(hw.current_at(0, hw.now() + np.arange(50) * 2e-5) != 0)
    assert stim.status().state is StimulatorState.RUNNING
    fake_mcs.bench.sleep(0.2)        # ended at 0.5 s
    assert stim.status().state is StimulatorState.STOPPED
    assert stim.status().error == ""


def test_armed_reads_as_starting_not_as_an_end(fake_mcs):
    # a start delay of 1 s, checked at 0.05 s: a host stall up to 0.95 s (a loaded machine,
    # Wine) cannot carry the check past it
    reg, hw, stim = make(fake_mcs, start_delay_s=1.0, start_status=3)
    stim.connect()
    start(stim, waveform(seconds=0.1))
    fake_mcs.bench.sleep(0.05)
    assert hw.status_at(hw.now())[0] == 3
    assert stim.status().state is StimulatorState.RUNNING
    fake_mcs.bench.sleep(1.25)
    assert stim.status().state is StimulatorState.STOPPED


def test_overcurrent_shutdown_is_a_fault_with_output_stopped_and_logged(fake_mcs, caplog):
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    start(stim, waveform(seconds=1.0))
    fake_mcs.bench.sleep(0.05)
    hw.lose_contact()
    with caplog.at_level(logging.ERROR, logger="nmsid.drivers.stg4002"):
        st = stim.status()
    assert st.state is StimulatorState.ERROR
    assert "overcurrent shutdown" in st.error and "electrode" in st.error
    assert hw.triggers[0].stop_t is not None            # SendStop was sent
    assert any("overcurrent" in r.getMessage() for r in caplog.records)
    # the next trial starts clean: load resets the latched shutdown
    stim.load(waveform())
    assert stim.status().error == "" and hw.overcurrent_status() == 0


def test_output_rate_is_never_set_in_download_mode(fake_mcs):
    # issue 25: SetOutputRate is documented for streaming mode; download mode has a fixed
    # 20 us resolution (STG4000 manual p.16); the fake download handle has no SetOutputRate
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    names = [c[0] for c in reg.devices[-1].calls]
    assert "SetOutputRate" not in names and "GetOutputRate" not in names
    assert stim.capabilities().output_rate_Hz == 50_000.0
    stim.load(waveform())
    assert stim.status().state is StimulatorState.LOADED


def test_output_rate_outside_the_vendor_range_is_refused():
    with pytest.raises(StimulatorSettingError, match="1000 .. 50000 Hz"):
        Stg4002Stimulator(ceiling_ext_mA=1, ceiling_flex_mA=1, output_rate_Hz=60_000)


def test_an_output_rate_other_than_20_us_is_refused_for_download_mode():
    with pytest.raises(StimulatorSettingError, match="fixed 20 us resolution"):
        Stg4002Stimulator(ceiling_ext_mA=1, ceiling_flex_mA=1, output_rate_Hz=25_000)


def test_version_info_keeps_the_software_version(fake_mcs):
    reg, hw, stim = make(fake_mcs, software="1.48", hardware="Rev. C")
    stim.connect()
    assert stim.capabilities().firmware == "software 1.48, hardware Rev. C"
    assert stim.describe()["software"] == "1.48"


def test_memory_is_checked_in_the_selected_segment_before_sending(fake_mcs):
    # issue 25: GetCapacity / SetCapacity do not exist in download mode (CStg200xStreamingNet
    # only); the documented members are SegmentSelect, GetAvailableMemory, GetMemoryUsageDAC
    # and GetMemoryUsageSyncout. A layout left by another program: segment 0 holds 100 kB
    reg, hw, stim = make(fake_mcs)
    hw.segment_bytes = [100_000, 64 * 1024 * 1024 - 100_000]
    stim.connect()
    from nmsid.drivers.errors import DeviceMemoryError
    with pytest.raises(DeviceMemoryError, match="segment 0 has 0.10 MB available"):
        stim.load(waveform(seconds=1.0))
    names = [c[0] for c in reg.devices[-1].calls]
    assert "PrepareAndSendData" not in names
    assert names.index("SegmentSelect") < names.index("GetAvailableMemory")
    assert "GetCapacity" not in names and "SetCapacity" not in names
    hw.segment_bytes = [64 * 1024 * 1024]
    stim.load(waveform(seconds=1.0))
    assert stim.status().state is StimulatorState.LOADED
    used = stim.delivery_summary()["memory_used_bytes"]
    assert used["channel 1"] == len(hw.channel_data[0][0]) * 8 and used["sync 1"] > 0


def test_trial_too_large_for_the_memory_sends_nothing(fake_mcs):
    from nmsid.drivers.errors import DeviceMemoryError
    reg, hw, stim = make(fake_mcs, memory_bytes=200_000)
    stim.connect()
    with pytest.raises(DeviceMemoryError, match="nothing was sent"):
        stim.load(waveform(seconds=1.0))
    assert "PrepareAndSendData" not in [c[0] for c in reg.devices[-1].calls]


def test_connect_stops_a_pattern_left_running_on_any_trigger(fake_mcs):
    # MC_Stimulus II (or a crashed run) left trigger 2 playing forever
    reg, hw, stim = make(fake_mcs)
    hw.leave_running(trigger=1, channel=0, current_nA=2_000_000)
    assert np.any(hw.current_at(0, hw.now() + np.arange(3) * 2e-5) != 0)
    stim.connect()
    t = hw.now() + np.arange(10) * 2e-5
    assert np.all(hw.current_at(0, t) == 0)
    assert hw.status_at(hw.now())[1] in (0, 2)
    assert ("SendStop", 0b11) in reg.devices[-1].calls


def test_stop_now_stops_every_trigger(fake_mcs):
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    hw.leave_running(trigger=1, channel=1, current_nA=1_000_000)  # e.g. front-panel start
    stim.stop_now()
    assert reg.devices[-1].calls[-1] == ("SendStop", 0b11)
    assert np.all(hw.current_at(1, hw.now() + np.arange(10) * 2e-5) == 0)


def test_estop_during_a_download_never_ends_loaded(fake_mcs):
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    hw.call_delay_s["PrepareAndSendData"] = 0.4   # a slow USB download
    in_download = threading.Event()
    hw.on_call["PrepareAndSendData"] = in_download.set
    err: list[BaseException] = []

    def load():
        try:
            stim.load(waveform())
        except BaseException as exc:  # noqa: BLE001 (collected for the assert)
            err.append(exc)
    th = threading.Thread(target=load)
    th.start()
    assert in_download.wait(2.0)
    stim.stop_now()                               # the E-stop, from another thread
    th.join(5.0)
    assert hw.overlaps == []                      # never concurrent with the download
    assert stim.status().state is StimulatorState.ERROR
    assert "during the download" in stim.status().error
    assert err and "during the download" in str(err[0])
    names = [c[0] for c in reg.devices[-1].calls]
    assert names[-1] == "SendStop"                # sent as soon as the download returned
    with pytest.raises(DeviceError):
        stim.arm()
    hw.call_delay_s.clear()
    stim.load(waveform())                         # the next, complete load clears it
    assert stim.status().state is StimulatorState.LOADED


def test_disconnect_and_estop_never_overlap(fake_mcs):
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    start(stim)
    hw.call_delay_s["SendStop"] = 0.2
    in_stop = threading.Event()
    hw.on_call["SendStop"] = in_stop.set
    th = threading.Thread(target=stim.stop_now)
    th.start()
    assert in_stop.wait(2.0)
    stim.disconnect()                             # while the E-stop's SendStop runs
    th.join(5.0)
    assert hw.overlaps == []
    st = stim.status()
    assert st.state is StimulatorState.DISCONNECTED and st.error == ""
    assert not st.output_active
    stim.stop_now()                               # after disconnect: a no-op, no error
    assert stim.status().error == ""


def test_no_status_leaks_into_the_next_trial(fake_mcs):
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    start(stim, waveform(seconds=0.05))
    fake_mcs.bench.sleep(0.15)
    assert stim.status().state is StimulatorState.STOPPED
    stim.stop_now()                               # the engine's finally
    hw.start_delay_s = 0.3                        # next trial's Running arrives late
    start(stim, waveform(seconds=0.5))
    fake_mcs.bench.sleep(0.1)
    st = stim.status()
    assert st.state is StimulatorState.RUNNING and st.output_active


def test_connect_again_after_a_usb_error(fake_mcs):
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    start(stim, waveform(seconds=1.0))
    hw.unplug()
    st = stim.status()
    assert st.state is StimulatorState.ERROR and "device not connected" in st.error
    hw.replug()
    stim.disconnect()
    stim.connect()                                # how the engine reconnects
    st = stim.status()
    assert st.state is StimulatorState.IDLE and st.error == "" and not st.output_active
    start(stim)
    assert stim.status().state is StimulatorState.RUNNING


def test_connect_twice_releases_the_first_connection(fake_mcs):
    reg, hw, stim = make(fake_mcs)
    stim.connect()
    first = reg.devices[-1]
    stim.connect()
    assert first.disposed and hw.opened_by is reg.devices[-1]
    assert stim.status().state is StimulatorState.IDLE


def test_output_rate_setting_of_the_hardware_config(tmp_path):
    from nmsid.drivers.errors import HardwareConfigError
    from nmsid.drivers.hw_config import parse_hw_config
    base = {"acquisition": {"kind": "leptrino", "fs_Hz": 1200.0,
                            "leptrino": {"port": "COM5"}}}
    cfg = parse_hw_config({**base, "stimulator": {"output_rate_Hz": 25000.0}}, "hw.toml")
    assert cfg.stimulator.output_rate_Hz == 25000.0
    with pytest.raises(HardwareConfigError, match=r"hw.toml: stimulator.output_rate_Hz = "
                                                  r"30000.0 is invalid; a whole number of "
                                                  r"microseconds per sample"):
        parse_hw_config({**base, "stimulator": {"output_rate_Hz": 30000.0}}, "hw.toml")
    with pytest.raises(HardwareConfigError, match=r"stimulator.output_rate_Hz = 60000.0 .*"
                                                  r"1000 \.\. 50000 Hz"):
        parse_hw_config({**base, "stimulator": {"output_rate_Hz": 60000.0}}, "hw.toml")


def test_a_busy_host_never_turns_a_normal_end_into_a_fault(fake_mcs):
    # the device starts at once, but SendStart returns to the (loaded) host 80 ms later
    reg, hw, stim = make(fake_mcs, start_delay_s=0.0)
    stim.connect()
    stim.load(waveform(seconds=0.15))
    stim.arm()
    hw.call_delay_after_s["SendStart"] = 0.08
    stim.start()
    fake_mcs.bench.sleep(0.12)   # device ended 0.15 s after its start; host saw ~0.12 s
    st = stim.status()
    assert st.state is StimulatorState.STOPPED and st.error == ""


def test_judge_trial_uses_the_bracketing_times():
    from nmsid.drivers.stg_status import TrialProgress, TriggerStatus, judge_trial
    F, I, R = TriggerStatus.FINISHED, TriggerStatus.IDLE, TriggerStatus.RUNNING
    assert judge_trial(F, True, 1.0, 1.0, elapsed_sent_s=0.9) is TrialProgress.ENDED
    assert judge_trial(F, True, 0.5, 1.0) is TrialProgress.EARLY_END
    assert judge_trial(I, True, 1.0, 1.0) is TrialProgress.ENDED
    assert judge_trial(I, False, 0.5, 1.0) is TrialProgress.RUNNING   # late Running
    assert judge_trial(R, True, 2.5, 1.0, elapsed_sent_s=1.9) is TrialProgress.RUNNING
    assert judge_trial(R, True, 2.5, 1.0, elapsed_sent_s=2.1) is TrialProgress.OVERDUE
    assert judge_trial(I, False, 2.5, 1.0, elapsed_sent_s=2.1) is TrialProgress.ENDED_UNSEEN


def test_status_decoding_accepts_enum_objects_and_refuses_unknown_values():
    from types import SimpleNamespace

    from nmsid.drivers.stg_status import UnknownStatus, decode_status

    class NetEnum:  # an enum object that int() does not convert
        def __init__(self, name):
            self.name = name

        def __str__(self):
            return f"Stg200xTriggerStatusEnumNet.{self.name}"
    ds = decode_status(SimpleNamespace(TiggerStatus=[NetEnum("Finished"), 3],
                                       OvercurrentStatus=1))
    assert [int(t) for t in ds.triggers] == [2, 3] and int(ds.overcurrent) == 1
    with pytest.raises(UnknownStatus, match="trigger 1 reported status 7"):
        decode_status(SimpleNamespace(TiggerStatus=[7], OvercurrentStatus=0))


def test_an_end_reported_after_a_host_stall_before_the_query_is_not_early():
    """The host reads its clock, stalls (a busy PC), then asks the STG, which has by then
    ended the trial on time: the end is judged against the time of the reply, not the
    time read before the query (a false 'ended the pattern early' fault, seen at load 4-8
    on the 10x fake bench)."""
    from nmsid.drivers.interfaces import StimulatorState
    from nmsid.drivers.stg_status import DeviceStatus, OvercurrentStatus, TriggerStatus
    from nmsid.drivers.stg_tracking import StgStatusTracking

    clock = {"t": 0.95}                      # just before the 1.0 s trial's end
    faults: list[str] = []
    tracker = StgStatusTracking()
    tracker._t_start, tracker._t_sent, tracker._duration_s = 0.0, 0.001, 1.0
    tracker._state, tracker._seen_running, tracker._poll = StimulatorState.RUNNING, True, None
    tracker._now = lambda: clock["t"]
    tracker._fault = faults.append

    def query_after_a_stall():
        clock["t"] = 1.2                     # the host was descheduled for 250 ms
        return DeviceStatus((TriggerStatus.FINISHED,), OvercurrentStatus.NORMAL)

    tracker._dev = object()
    tracker._query_locked = query_after_a_stall
    tracker._update_running()
    assert faults == [] and tracker._state is StimulatorState.STOPPED
