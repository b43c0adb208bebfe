"""``nmsid probe --dry-run``: one short low-current trial into a dummy load, through the
rig's own safety path.

The trial is stimulated by :func:`nmsid.rig.stimulation.run_block`, exactly as a session's
trials: the interlock (force, stall, acquisition flags, stimulator status, the hardware
E-stop switch and its watcher thread) watches it, and every exit puts output at zero. The
recorded resistor current is then compared with what the device was given
(:mod:`nmsid.drivers.dry_run` holds the comparisons; wiring and limits are described there
and in docs/hardware.md).

``estop_at_s``: the E-stop test. The trial's envelope is a chirp (0.5 .. 10 Hz, the shape of
a session's trial at dry-run currents) and the interlock's E-stop is pressed that long into
it (mid-chirp); the block must end by the E-stop, and a short
record taken right after shows the resistor current at zero and, for a device with a sync
output, the sync line low.
"""

from __future__ import annotations

import logging

import numpy as np

from nmsid.drivers.dry_run import (CARRIER_HZ, ENVELOPE_FS_HZ, Check, DryRunSettings,
                                   check_after_stop, check_loopback, check_pulses,
                                   dry_run_chirp_envelope, dry_run_envelope, record_problem)
from nmsid.drivers.hardware import BenchClock
from nmsid.drivers.interfaces import CheckedWaveform, DeliveryReporting, SampleTiming
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
                                  pulse_index=summary.get("pulse_index"))
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
    ok = run_dry_run(devices, s, support, out=out,
                     monitor_channel=cfg.acquisition.monitor_channel)
    stopped = run_dry_run(devices, s, support, out=out, estop_at_s=ESTOP_AT * s.duration_s,
                          monitor_channel=cfg.acquisition.monitor_channel)
    return ok and stopped
