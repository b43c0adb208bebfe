"""``nmsid probe --dry-run``: one short low-current trial into a dummy load, through the
rig's own safety path.

The trial is stimulated by :func:`nmsid.rig.stimulation.run_block`, exactly as a session's
trials: the interlock (force, stall, acquisition flags, stimulator status, the hardware
E-stop switch and its watcher thread) watches it, and every exit puts output at zero. The
recorded resistor current is then compared with what the device was given
(:mod:`nmsid.drivers.dry_run` holds the comparisons; wiring and limits are described there
and in docs/hardware.md).

The streamed trial (:func:`run_stream_dry_run`, a stimulator that streams: the closed loop's
path): one tracking-style trial, its updates written while it runs by the same
:func:`~nmsid.rig.stimulation.run_block` hook a tracking session uses, at dry-run
currents. It is checked against what the DEVICE reports (every update answered, each
delivered current the command rounded down to the device's step, the output stopped and
confirmed) and, with a monitor input, against the resistor's recorded pulses. With a
Leptrino (no A/D input) the resistor's current is not recorded: the RehaStim2 itself tests
the load's resistance before each pulse and stops with an electrode error on an open or
wrong load (ScienceMode2 1.2, 4.3), and the operator reads the amplitude on an
oscilloscope across the resistor (the line printed says what to expect).

``estop_at_s``: the E-stop test. The trial's envelope is a chirp (0.5 .. 10 Hz, the shape of
a session's trial at dry-run currents) and the interlock's E-stop is pressed that long into
it (mid-chirp); the block must end by the E-stop, and a short
record taken right after shows the resistor current at zero and, for a device with a sync
output, the sync line low.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from nmsid.drivers.dry_run import (
    CARRIER_HZ,
    ENVELOPE_FS_HZ,
    Check,
    DryRunSettings,
    check_after_stop,
    check_loopback,
    check_pulses,
    dry_run_chirp_envelope,
    dry_run_envelope,
    record_problem,
)
from nmsid.drivers.hardware import BenchClock
from nmsid.drivers.interfaces import (
    CheckedWaveform,
    DeliveryReporting,
    HostStreamedStimulator,
    SampleTiming,
    StimulatorState,
)
from nmsid.drivers.registry import stimulator_kind
from nmsid.protocols.interlock_settings import InterlockConfig
from nmsid.rig.safety import Interlock
from nmsid.rig.stimulation import run_block

log = logging.getLogger(__name__)

DRY_RUN_INTERLOCK = InterlockConfig(stall_timeout_s=2.0)
"""A dummy load, not a participant: a late chunk on a loaded PC must not spoil the check."""
AFTER_STOP_S = 0.1
"""Length of the record taken after an E-stop."""


def run_dry_run(devices, s: DryRunSettings, support, *, out=print,
                estop_at_s: float | None = None, monitor_channel: int | None = None,
                interlock_cfg: InterlockConfig = DRY_RUN_INTERLOCK) -> bool:
    """Stimulate the dummy load once through the interlock, record, compare, print.

    Parameters
    ----------
    devices : drivers.interfaces.RigDevices
        Connected stimulator, clock, E-stop switch, and an analog acquisition scanning the
        monitor input (:func:`nmsid.drivers.hardware.with_monitor`).
    s : DryRunSettings
    support : drivers.registry.DryRunSupport
        What the stimulator kind's dry run checks.
    estop_at_s : float, optional
        Press the E-stop this long into the trial (the E-stop test).
    monitor_channel : int, optional
        The A/D input of the resistor's voltage (its known conversion delay is corrected).

    Returns
    -------
    bool
        True if every check passed.
    """
    stim, acq = devices.stimulator, devices.acquisition
    ext = s.channel == "extensor"
    ch = devices.extensor_channel if ext else devices.flexor_channel
    env = dry_run_envelope(s) if estop_at_s is None else dry_run_chirp_envelope(s)
    zeros = np.zeros_like(env)
    wf = CheckedWaveform(env if ext else zeros, zeros if ext else env, ENVELOPE_FS_HZ,
                         CARRIER_HZ, s.amplitude_mA, s.amplitude_mA)
    out(f"dry run: {s.duration_s:g} s at up to {s.amplitude_mA:g} mA on the {s.channel} "
        f"channel ({ch}) into {s.load_ohm:g} Ohm, through the interlock"
        + (f"; chirp envelope, E-stop at {estop_at_s:g} s (mid-chirp)"
           if estop_at_s is not None else ""))
    fs = acq.configure(s.monitor_fs_Hz)
    if abs(fs - s.monitor_fs_Hz) > 1e-6 * s.monitor_fs_Hz:
        out(f"  [FAIL] record: the A/D gives {fs:g} Hz for the {s.monitor_fs_Hz:g} Hz asked; "
            "set acquisition.monitor_fs_Hz to a rate it gives exactly")
        return False
    n = round(s.duration_s * fs)
    monitor: list[np.ndarray | None] = []
    flags: list[str] = []
    interlock = Interlock(interlock_cfg, stim, estop_input=devices.estop)
    press_at = None if estop_at_s is None else round(estop_at_s * fs)

    def on_chunk(chunk):
        if chunk.n:
            monitor.append(chunk.monitor)
        if chunk.flags.any:
            flags.append(chunk.flags.detail or "flagged")

    def on_samples(lo, hi, *_rest):
        if press_at is not None and hi >= press_at and not interlock.latched:
            interlock.estop("dry run: E-stop test mid-chirp")

    interlock.start_watcher()
    try:
        block = run_block(devices, interlock, wf, n, on_samples=on_samples, on_chunk=on_chunk)
    finally:
        interlock.stop_watcher()
    got = block.received
    out(f"  record: {got} of {n} samples at {fs:g} Hz (force, sync and monitor in one scan)"
        + (f"; block ended: {block.abort_reason}" if block.abort_reason else ""))
    if press_at is not None:
        return _estop_checks(devices, s, support, block, press_at, fs, out)
    problem = record_problem(got, n, flags, monitor) or block.abort_reason
    if problem:
        out(f"  [FAIL] record: {problem}")
        out("dry run: FAILED (see above)")
        return False
    monitor_V = np.concatenate([m for m in monitor if m is not None])[:n]
    sync_V = block.sync if block.sync is not None else np.zeros(n)
    if support.method == "lock-in":
        command = support.command_A(stim, ch, n, fs)
        checks = check_loopback(monitor_V, sync_V, command, s, float(sync_V[0]),
                                monitor_delay_s=_monitor_delay_s(acq, monitor_channel))
    else:
        summary = stim.delivery_summary() if isinstance(stim, DeliveryReporting) else None
        if not summary:
            checks = [Check("pulses", False, "the stimulator reported no pulses", ">= 1")]
        else:
            pulses = summary["channels"][s.channel]["pulse_current_mA"]
            shape = summary["waveshape"]
            checks = check_pulses(monitor_V, s, pulses, float(shape["pulse_width_us"]),
                                  float(shape.get("interphase_us", 0.0)),
                                  pulse_index=summary.get("pulse_index"),
                                  repeats=summary.get("repeats_update", True))
    return _report(checks, out)


def _estop_checks(devices, s, support, block, press_at, fs, out) -> bool:
    """The block ended by the E-stop near ``press_at``; then record the load briefly."""
    stopped_by_estop = "estop" in block.abort_reason.lower()
    checks = [Check("E-stop: trial ended", stopped_by_estop and block.received < block.force_N
                    .size, f"after {block.received} of {block.force_N.size} samples "
                    f"({block.abort_reason or 'not stopped'})", f"by the E-stop near sample "
                    f"{press_at}")]
    acq = devices.acquisition
    m = round(AFTER_STOP_S * fs)
    mon, sync = [], []
    acq.start(m, triggered=False)
    try:
        got, t_end = 0, devices.clock.monotonic_s() + AFTER_STOP_S + 2.0
        while got < m and devices.clock.monotonic_s() < t_end:
            chunk = acq.read(0.1)
            if chunk is None or not chunk.n:
                continue
            got += chunk.n
            mon.append(np.zeros(chunk.n) if chunk.monitor is None else chunk.monitor)
            sync.append(np.zeros(chunk.n) if chunk.sync is None else chunk.sync)
    finally:
        acq.stop()
    if not mon:
        checks.append(Check("E-stop: record after the stop", False, "no samples", f"{m}"))
    else:
        checks += check_after_stop(np.concatenate(mon), np.concatenate(sync), s,
                                   has_sync=support.hardware_sync)
    return _report(checks, out)


def _report(checks: list[Check], out) -> bool:
    for c in checks:
        out(c.line())
    ok = all(c.passed for c in checks)
    out("dry run: OK" if ok else "dry run: FAILED (see above)")
    return ok


def _monitor_delay_s(acq, monitor_channel: int | None) -> float:
    """How long after the scan's clock edge the A/D converts the monitor input."""
    if monitor_channel is None or not isinstance(acq, SampleTiming):
        return 0.0
    return float(acq.sample_delay_s(monitor_channel))


ESTOP_AT = 0.5
"""The E-stop test presses the E-stop at this fraction of the dry run (the hold)."""


def dry_run_probe(devices, cfg, args, *, out=print) -> bool:
    """``nmsid probe --dry-run``: settings from the flags and the hardware file; the checked
    trial, then the E-stop test (a second trial stopped by the E-stop at :data:`ESTOP_AT`
    of its duration).

    ``devices`` are built from :func:`nmsid.drivers.hardware.with_monitor` ``(cfg)``. In fake
    mode the simulated resistor is "wired" as the flags say (the tested channel into the
    fake A/D's monitor input).
    """
    s = DryRunSettings(load_ohm=args.load_ohm, channel=args.dry_run_channel,
                       amplitude_mA=args.dry_run_mA,
                       monitor_fs_Hz=cfg.acquisition.monitor_fs_Hz)
    bench = devices.clock.bench if isinstance(devices.clock, BenchClock) else None
    if bench is not None:  # fake mode: the operator wired the resistor as told
        ch = devices.extensor_channel if s.channel == "extensor" else devices.flexor_channel
        bench.dummy_load = (ch - 1, s.load_ohm)
    support = stimulator_kind(cfg.stimulator).dry_run
    monitor = cfg.calibration is not None and cfg.calibration.monitor_channel is not None
    ok = stopped = True
    if not monitor and (support.method != "pulse-amplitude" or
                        not isinstance(devices.stimulator, HostStreamedStimulator)):
        out("dry run: FAILED: this acquisition has no A/D input for the resistor and this "
            "stimulator does not stream (its own delivery reports are the streamed trial's "
            "checks); use an analog chain with acquisition.monitor_channel, or an "
            "oscilloscope (docs/hardware.md, section 6)")
        return False
    if monitor:
        ok = run_dry_run(devices, s, support, out=out,
                         monitor_channel=cfg.acquisition.monitor_channel)
        stopped = run_dry_run(devices, s, support, out=out,
                              estop_at_s=ESTOP_AT * s.duration_s,
                              monitor_channel=cfg.acquisition.monitor_channel)
    streamed = True
    if support.method == "pulse-amplitude":   # a device that reports each pulse's current
        streamed = run_stream_dry_run(devices, s, out=out, fs_Hz=(
            cfg.acquisition.monitor_fs_Hz if monitor else cfg.acquisition.fs_Hz))
    else:
        out("dry run, streamed trial: not run for this stimulator (it reports no per-pulse "
            "currents; its carrier is checked by the lock-in of the trial above)")
    return ok and stopped and streamed


STREAM_QUEUE_S = 0.5
"""Updates queued ahead in the streamed trial (a tracking session's queue is similar)."""
STREAM_LEVELS = (1.0, 0.5, 1.0, 0.25, 1.0, 0.75)
"""The streamed trial's staircase target, fractions of ``--dry-run-mA`` (each held 1/6 of
the trial)."""
STREAM_UPDATE_HZ = 100.0
"""The update rate asked of a stimulator that takes one (the RehaStim2 answers its pulse
rate; the STG needs a divisor of its carrier)."""


class DryRunStream:
    """:func:`~nmsid.rig.stimulation.run_block`'s stream hook (as
    :class:`~nmsid.rig.tracking.TrackingStream`): a tracking-style envelope, a staircase
    target held at :data:`STREAM_LEVELS` of ``amplitude_mA`` in turn (whole device steps at
    the default 2 mA, so a 2 mA-step device delivers non-zero pulses), written update by
    update as the trial's samples arrive."""

    def __init__(self, s: DryRunSettings, fs_Hz: float):
        self.s, self.fs_Hz = s, float(fs_Hz)
        self.rate_Hz = STREAM_UPDATE_HZ
        self.commands: list[float] = []
        self.n_updates = 0
        self.stim: HostStreamedStimulator | None = None

    def envelope(self, i: int) -> float:
        k = int(i / self.rate_Hz / self.s.duration_s * len(STREAM_LEVELS))
        return float(STREAM_LEVELS[min(k, len(STREAM_LEVELS) - 1)] * self.s.amplitude_mA)

    def _write(self, upto: int) -> None:
        ext, stim = self.s.channel == "extensor", self.stim
        assert stim is not None    # open() set it
        while len(self.commands) < min(upto, self.n_updates):
            a = self.envelope(len(self.commands))
            stim.write_stream(np.array([a if ext else 0.0]),
                                   np.array([0.0 if ext else a]))
            self.commands.append(a)

    def open(self, stim) -> None:
        a = self.s.amplitude_mA
        self.rate_Hz = float(stim.open_stream(a, a, STREAM_UPDATE_HZ))
        self.n_updates = math.floor(self.s.duration_s * self.rate_Hz)
        self.stim = stim
        self._write(max(1, round(STREAM_QUEUE_S * self.rate_Hz)))

    def update(self, received: int, force_N) -> None:
        self._write(math.floor(received / self.fs_Hz * self.rate_Hz)
                    + round(STREAM_QUEUE_S * self.rate_Hz))

    def close(self, stim) -> None:
        stim.close_stream()


def run_stream_dry_run(devices, s: DryRunSettings, *, fs_Hz: float, out=print) -> bool:
    """The streamed (tracking-style) trial into the dummy load; see the module docstring."""
    stim, acq = devices.stimulator, devices.acquisition
    if not isinstance(stim, HostStreamedStimulator):
        out("dry run, streamed trial: not run (this stimulator does not stream)")
        return True
    ch = devices.extensor_channel if s.channel == "extensor" else devices.flexor_channel
    out(f"dry run, streamed trial: {s.duration_s:g} s, tracking-style updates up to "
        f"{s.amplitude_mA:g} mA on the {s.channel} channel ({ch}) into {s.load_ohm:g} Ohm, "
        "through the interlock")
    fs = acq.configure(fs_Hz)
    n = round(s.duration_s * fs)
    stream = DryRunStream(s, fs)
    monitor: list = []
    interlock = Interlock(DRY_RUN_INTERLOCK, stim, estop_input=devices.estop)
    interlock.start_watcher()
    try:
        block = run_block(devices, interlock, None, n, stream=stream,
                          on_chunk=lambda c: monitor.append(c.monitor) if c.n else None)
    finally:
        interlock.stop_watcher()
    out(f"  record: {block.received} of {n} samples at {fs:g} Hz"
        + (f"; block ended: {block.abort_reason}" if block.abort_reason else ""))
    summary = stim.delivery_summary() if isinstance(stim, DeliveryReporting) else None
    st = devices.stimulator.status()   # the Stimulator's (isinstance narrowed stim)
    checks = [Check("stream: ended", not block.abort_reason and st.state is not
                    StimulatorState.ERROR and not st.output_active,
                    f"state {st.state.value}{', ' + st.error if st.error else ''}",
                    "the whole trial, output stopped, no device error")]
    if summary is None:
        out("  [INFO] the stimulator reports no delivered updates: only the end is checked")
        return _report(checks, out)
    sent, acked = summary.get("updates_sent", 0), summary.get("updates_acknowledged", 0)
    lost = sum(summary.get(k, 0) for k in ("updates_busy", "updates_transfer_error",
                                           "updates_unanswered"))
    due = math.floor(block.received / fs * stream.rate_Hz)
    checks.append(Check("stream: updates answered", 0 < sent <= len(stream.commands) and
                        acked + lost == sent and acked >= 0.9 * sent,
                        f"{acked} of {sent} sent acknowledged ({due} due in the record), "
                        f"{lost} skipped (busy, transfer error, unanswered)",
                        ">= 90 % acknowledged, every one answered"))
    step = float(devices.stimulator.capabilities().resolution_mA)
    got = summary["channels"][s.channel]["pulse_current_mA"]
    cmd = [stream.commands[k] for k in summary.get("pulse_index", [])]
    err = [c - g for c, g in zip(cmd, got, strict=False)]   # unequal: the check fails below
    checks.append(Check("stream: delivered = command rounded down",
                        len(cmd) == len(got) and all(-1e-9 <= e < step + 1e-9 for e in err),
                        f"{len(got)} pulses, command - delivered in "
                        f"[{min(err, default=0):.3g}, {max(err, default=0):.3g}] mA",
                        f"0 .. {step:g} mA (the device's step)"))
    mon = [m for m in monitor if m is not None]
    if mon:
        shape = summary["waveshape"]
        checks += check_pulses(np.concatenate(mon)[:n], s, got,
                               float(shape.get("pulse_width_us", 0.0)),
                               float(shape.get("interphase_us", 0.0)),
                               pulse_index=summary.get("pulse_index"),
                               repeats=summary.get("repeats_update", True))
    else:
        width = summary.get("waveshape", {}).get("pulse_width_us")
        out(f"  [INFO] the resistor's current is not recorded (no monitor input): "
            f"look at it on an oscilloscope across the {s.load_ohm:g} Ohm resistor, up to "
            f"+-{max(got, default=0) * 1e-3 * s.load_ohm:g} V"
            + (f" pulses of {width:g} us per phase" if width else "")
            + "; the RehaStim2 checks the load's resistance before each pulse (ScienceMode2 "
            "1.2: an open or wrong load stops it with an electrode error)")
    return _report(checks, out)
