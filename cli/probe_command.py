"""The handler of ``nmsid probe`` (registered by :mod:`nmsid.cli.probe`): check every
configured device ON ITS OWN, print what it reports and a few force samples, release it;
nothing is stimulated.

Each device (stimulator, force acquisition, E-stop switch) is built, loaded and asked in
its own ``try``: one that cannot be reached (a missing vendor library, an unplugged cable,
a wrong port or serial) is reported in one line, ``<device>: FAILED: <reason>``, and the
others are still checked. Exit status 0 if every device passed, 1 if any failed (a bad
configuration file is still one line and exit 2, raised before any device is tried).

With real devices each check runs in its OWN PROCESS (:func:`run_isolated`): a vendor
library that aborts in native code (McsUsbNet's does under mono; any C library may) ends
only that process, which is reported as that device's failure, and the other devices still
print. Fake devices share one simulated bench, so they are checked in this process.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from typing import cast

import numpy as np

from nmsid.cli.errors import UsageError
from nmsid.drivers.dry_run import DryRunSettings
from nmsid.drivers.hardware import (
    FakeStack,
    build_devices,
    load_acquisition_library,
    load_stimulator_library,
    make_acquisition,
    make_estop,
    make_stimulator,
    prepare,
    with_monitor,
)
from nmsid.drivers.hw_config import load_hw_config
from nmsid.drivers.interfaces import Describable, ReportsSensorInfo
from nmsid.drivers.registry import acquisition_kind
from nmsid.rig.dry_run import dry_run_probe

CHECK_TIMEOUT_S = 120.0
"""How long one device's isolated check may take (a connect waits seconds at most)."""
MAX_PROBE_SAMPLES = 10_000
"""Most force samples ``--samples`` may ask for: the probe reads for at most 5 s (100
reads of 50 ms), 10000 samples at the paper's 2 kHz."""


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else 'no detail'}"


def probe(args) -> int:
    if not 1 <= args.samples <= MAX_PROBE_SAMPLES:
        raise UsageError(f"--samples {args.samples} is outside [1, {MAX_PROBE_SAMPLES}] (the "
                         "probe reads for at most 5 s: 10000 samples at 2 kHz)")
    dll = getattr(args, "check_assembly", None)   # None: not asked; "": the file's dll_path
    if dll:   # the assembly alone: no hardware file, no device
        return _check_assembly(dll)
    if not args.hw_config:
        raise UsageError("probe needs --hw-config FILE (the rig's hardware configuration), "
                         "or --check-assembly DLL to check McsUsbNet.dll alone")
    cfg = load_hw_config(args.hw_config)
    if dll is not None:
        dll_path = getattr(cfg.stimulator, "dll_path", None)
        if dll_path is None:   # a stimulator kind driven without McsUsbNet
            raise UsageError(f"{cfg.source}: --check-assembly checks the McsUsbNet assembly "
                             "named by stimulator.dll_path; this [stimulator] has none "
                             "(or name it: --check-assembly DLL)")
        return _check_assembly(dll_path)
    dry_cfg = None
    if getattr(args, "dry_run", False):
        # an analog chain records the resistor on its monitor input; a digital one (the
        # Leptrino) has none: the streamed trial is then checked by the device's reports
        dry_cfg = with_monitor(cfg) if acquisition_kind(cfg).analog else cfg
    if dry_cfg is not None:  # the dry run's flags, before any device is probed
        DryRunSettings(load_ohm=args.load_ohm, channel=args.dry_run_channel,
                       amplitude_mA=args.dry_run_mA,
                       monitor_fs_Hz=dry_cfg.acquisition.monitor_fs_Hz)
    cfg, stack, clock = prepare(cfg)
    print(f"hardware configuration {cfg.source}: {cfg.describe()}")
    failed: list[str] = []
    try:
        for name, check in CHECKS.items():
            if stack is None:   # real devices: a native abort ends only this check
                problem = run_isolated(name, [str(args.hw_config), str(args.samples)])
            else:
                problem = _check_here(check, cfg, stack, clock, args)
            if problem:
                failed.append(name)
                print(f"{name}: FAILED: {problem}", flush=True)
    finally:
        if stack is not None:
            stack.close()
    if getattr(args, "dry_run", False):
        # the stimulator-side checks on the dummy load, once every device above passed
        if failed:
            print("dry run: not run (a device failed)")
        elif not _dry_run(dry_cfg, args):
            failed.append("dry run")
    if failed:
        print(f"probe: {len(failed)} device(s) failed: {', '.join(failed)}")
        return 1
    print("probe: OK")
    return 0


def _check_assembly(dll_path) -> int:
    from nmsid.drivers.mcs_surface import assembly_report  # noqa: PLC0415
    status, lines = assembly_report(dll_path)
    print("\n".join(lines))
    return status


def _check_here(check, cfg, stack, clock, args) -> str:
    try:
        return check(cfg, stack, clock, args)
    except Exception as exc:  # this device only: report it, check the others
        return _one_line(exc)


def run_isolated(device: str, argv: list[str], *, target: str = "",
                 timeout_s: float = CHECK_TIMEOUT_S) -> str:
    """Run one device's check in a child Python process; "" if it passed, else the one-line
    problem. Its output is printed here as it was printed there.

    ``target`` (``module:function``, called with ``argv``; tests) replaces the device check.
    """
    cmd = [sys.executable, "-m", "nmsid.cli.probe_command", target or device, *argv]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s,
                              env={**os.environ, "PYTHONFAULTHANDLER": "1"}, check=False)
    except subprocess.TimeoutExpired:
        return f"its check did not end within {timeout_s:g} s (a device or library hung)"
    lines = proc.stdout.splitlines()
    result = lines.pop() if lines and lines[-1].startswith(_RESULT) else None
    if lines:
        print("\n".join(lines), flush=True)
    if result is not None and proc.returncode == 0:
        return str(json.loads(result[len(_RESULT):]))
    rc = proc.returncode
    how = (f"signal {signal.Signals(-rc).name}" if rc < 0 and -rc in
           {s.value for s in signal.Signals} else f"exit status {rc}")
    last = next((ln for ln in reversed(proc.stderr.splitlines()) if ln.strip()), "")
    return (f"its check ended abnormally ({how}): a vendor library aborted in native "
            f"code?{' Last words: ' + last.strip() if last else ''}")


_RESULT = "nmsid-probe-result: "


def _child(argv: list[str]) -> int:
    """``python -m nmsid.cli.probe_command DEVICE HW_CONFIG SAMPLES`` (or ``module:function
    ARGS...``): one check, its result as the last line."""
    what, rest = argv[0], argv[1:]
    if ":" in what:
        import importlib  # noqa: PLC0415 (tests name their own check)
        mod, func = what.split(":")
        problem = getattr(importlib.import_module(mod), func)(*rest)
    else:
        cfg, stack, clock = prepare(load_hw_config(rest[0]))
        args = type("Args", (), {"samples": int(rest[1])})()
        problem = _check_here(CHECKS[what], cfg, stack, clock, args)
    print(_RESULT + json.dumps(problem or ""), flush=True)
    return 0


def _dry_run(cfg, args) -> bool:
    """The dry run's plan into the dummy load, run by the engine (which connects the
    stimulator; nothing here talks to it); ``cfg`` scans the monitor input too."""
    devices = build_devices(cfg)
    try:
        return dry_run_probe(devices, cfg, args)
    finally:
        devices.close()


def _check_stimulator(cfg, stack, clock, args) -> str:
    stim = make_stimulator(cfg, stack, clock)
    try:
        load_stimulator_library(cfg, stim)
        stim.connect()
        print("stimulator:")
        for key, value in (stim.describe() if isinstance(stim, Describable) else {}).items():
            print(f"  {key}: {value}")
    finally:
        try:
            stim.disconnect()
        except Exception:  # releasing a device that never connected
            pass
    return ""


def _check_acquisition(cfg, stack, clock, args) -> str:
    # a fake stack is closed by probe() itself, not by the acquisition it wraps
    # _Borrowed is the stack in all but close (duck-typed)
    acq = make_acquisition(cfg, None if stack is None else cast(FakeStack, _Borrowed(stack)))
    try:
        load_acquisition_library(cfg, acq)
        rate = acq.configure(cfg.acquisition.fs_Hz)
        print(f"acquisition: {rate:g} Hz")
        if isinstance(acq, Describable):
            for key, value in acq.describe().items():
                print(f"  {key}: {value}")
        info = acq.info if isinstance(acq, ReportsSensorInfo) else None
        if info is not None:
            print(f"  sensor: {info.model}, serial {info.serial}, firmware {info.firmware}"
                  + ("" if info.rate_stated else " (no rate stated: the rate is measured)"))
        return _read_samples(acq, args.samples)
    finally:
        acq.close()


def _read_samples(acq, n: int) -> str:
    acq.start(n, triggered=False)
    got, force, flags = 0, [], []
    for _ in range(100):
        chunk = acq.read(0.05)
        if chunk is None:
            if got >= n:
                break
            continue
        got += chunk.n
        force.append(chunk.force_N)
        if chunk.flags.any:
            flags.append(chunk.flags.detail)
        if got >= n:
            break
    acq.stop()
    f = np.concatenate(force) if force else np.zeros(0)
    if len(f):
        print(f"  {len(f)} samples: force mean {f.mean():+.3f} N, sd {f.std():.3f} N, "
              f"first {', '.join(f'{x:+.3f}' for x in f[:5])} N")
    for detail in flags:
        print(f"  flag: {detail}")
    if not len(f):
        return "no samples arrived"
    if flags:
        return f"{len(flags)} flagged chunk(s): {flags[0]}"
    return ""


def _check_estop(cfg, stack, clock, args) -> str:
    estop = make_estop(cfg, stack)
    if estop is None:
        print("E-stop switch: none configured")
        return ""
    try:
        pressed = estop.is_pressed()
        print(f"E-stop switch: {'PRESSED (or unreadable)' if pressed else 'released'}")
        return "switch reads as pressed (or unreadable)" if pressed else ""
    finally:
        estop.close()


class _Borrowed:
    """A fake stack lent to one device: its ``close`` leaves the stack running."""

    def __init__(self, stack):
        self._stack = stack

    def __getattr__(self, name):
        return getattr(self._stack, name)

    def close(self) -> None:
        pass


CHECKS = {"stimulator": _check_stimulator, "acquisition": _check_acquisition,
          "E-stop switch": _check_estop}


if __name__ == "__main__":   # a device's isolated check (run_isolated)
    raise SystemExit(_child(sys.argv[1:]))
