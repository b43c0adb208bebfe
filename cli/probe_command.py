"""The handler of ``nmsid probe`` (registered by :mod:`nmsid.cli.probe`): connect to each
configured device, print what it reports and a few force samples, release it; nothing is
stimulated."""

from __future__ import annotations

import numpy as np

from nmsid.drivers.hardware import build_devices
from nmsid.drivers.hw_config import load_hw_config


def probe(args) -> int:
    cfg = load_hw_config(args.hw_config)
    if args.samples < 1:
        raise ValueError(f"--samples must be >= 1, got {args.samples}")
    devices = build_devices(cfg)
    ok = True
    try:
        print(f"hardware configuration {cfg.source}: {cfg.describe()}")
        stim = devices.stimulator
        stim.connect()
        print("stimulator:")
        for key, value in stim.describe().items():
            print(f"  {key}: {value}")
        acq = devices.acquisition
        rate = acq.configure(cfg.acquisition.fs_Hz)
        print(f"acquisition: {rate:g} Hz")
        describe = getattr(acq, "describe", None)
        if describe is not None:
            for key, value in describe().items():
                print(f"  {key}: {value}")
        info = getattr(acq, "info", None)
        if info is not None:
            print(f"  sensor: {info.model}, serial {info.serial}, firmware {info.firmware}")
        acq.start(args.samples, triggered=False)
        got, force, flags = 0, [], []
        for _ in range(100):
            chunk = acq.read(0.05)
            if chunk is None:
                if got >= args.samples:
                    break
                continue
            got += chunk.n
            force.append(chunk.force_N)
            if chunk.flags.any:
                flags.append(chunk.flags.detail)
            if got >= args.samples:
                break
        acq.stop()
        f = np.concatenate(force) if force else np.zeros(0)
        if len(f):
            print(f"  {len(f)} samples: force mean {f.mean():+.3f} N, sd {f.std():.3f} N, "
                  f"first {', '.join(f'{x:+.3f}' for x in f[:5])} N")
        else:
            ok = False
            print("  NO samples arrived")
        for detail in flags:
            ok = False
            print(f"  flag: {detail}")
        if devices.estop is not None:
            pressed = devices.estop.is_pressed()
            print(f"E-stop switch: {'PRESSED (or unreadable)' if pressed else 'released'}")
        else:
            print("E-stop switch: none configured")
    finally:
        devices.close()
    print("probe: OK" if ok else "probe: problems found (see above)")
    return 0 if ok else 1
