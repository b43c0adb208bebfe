"""STG carrier rendering: charge balance and render+check time, new vs the old renderer.

Both renderers run in this process on the default protocol (15 sE levels, 15 s trials,
1 kHz carrier, 50 kHz output, 500 nA resolution) at the full-range calibration of issue 16
(Iemin 2, Iemax 16, Ifmin 1.5, Ifmax 16 mA):

* worst net charge of one carrier period (nC) and worst net charge of one trial (uC),
  over every level and both channels;
* render + check time of one 15 s trial (both channels, best of 3): the new path is
  ``drivers.stg_download.prepare_download`` (render, ceiling check, charge-balance check);
  the baseline is the previous renderer (envelope held per 2 kHz sample, i.e. half a
  carrier period) with its ceiling check, copied below unchanged.

    python bench/run.py stimulation
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.drivers.interfaces import CheckedWaveform  # noqa: E402
from nmsid.drivers.stg_download import ChannelPlan, prepare_download  # noqa: E402
from nmsid.drivers.stg_waveform import check_rendered, compress  # noqa: E402
from nmsid.protocols.config import load_config  # noqa: E402
from nmsid.protocols.waveforms import trial_waveform  # noqa: E402

RATE, RES = 50_000.0, 500.0
CAL = (2.0, 16.0, 1.5, 16.0)


class Cal:
    Iemin_mA, Iemax_mA, Ifmin_mA, Ifmax_mA = CAL


def old_render_samples(envelope_mA, fs_Hz, carrier_Hz, output_rate_Hz, resolution_nA):
    """The previous ``drivers.stg_waveform.render_samples`` (baseline, unchanged)."""
    env = np.asarray(envelope_mA, dtype=np.float64)
    n_out = int(round(len(env) / fs_Hz * output_rate_Hz))
    j = np.arange(n_out, dtype=np.float64)
    k = np.minimum(np.floor(j * (fs_Hz / output_rate_Hz) + 1e-9).astype(np.int64),
                   len(env) - 1)
    i_nA = env[k] * 1e6 * np.sin(2.0 * np.pi * carrier_Hz * j / output_rate_Hz)
    return (np.trunc(i_nA / resolution_nA) * resolution_nA).astype(np.int64)


def net_figures(samples_nA, period):
    x = np.asarray(samples_nA, dtype=np.int64)
    n = len(x) // period
    per = np.abs(x[:n * period].reshape(n, period).sum(axis=1)).max() / RATE  # nC
    return float(per), float(abs(x.sum()) / RATE / 1000)                    # uC


def main() -> None:
    p = load_config(None).protocol
    period = int(RATE / p.carrier_Hz)
    plans = (ChannelPlan(1, "extensor", 16.0, 16e6, RES), ChannelPlan(2, "flexor", 16.0,
                                                                       16e6, RES))
    old_per = old_trial = new_per = new_trial = 0.0
    for sE in p.sE_levels:
        wf = trial_waveform(p, sE, Cal)
        checked = CheckedWaveform(wf.I_ext_mA, wf.I_flex_mA, p.fs_Hz, p.carrier_Hz, 16, 16)
        dl = prepare_download(checked, *plans, sync_out=1, output_rate_Hz=RATE)
        for env, ch in ((wf.I_ext_mA, 1), (wf.I_flex_mA, 2)):
            a, b = net_figures(old_render_samples(env, p.fs_Hz, p.carrier_Hz, RATE, RES),
                               period)
            old_per, old_trial = max(old_per, a), max(old_trial, b)
            a, b = net_figures(dl.channels[ch].expand(), period)
            new_per, new_trial = max(new_per, a), max(new_trial, b)
    # render + check time of the top level (sE 1.0: the largest currents)
    wf = trial_waveform(p, max(p.sE_levels), Cal)
    checked = CheckedWaveform(wf.I_ext_mA, wf.I_flex_mA, p.fs_Hz, p.carrier_Hz, 16, 16)
    t_new, t_old = [], []
    for _ in range(3):
        t0 = time.perf_counter()
        prepare_download(checked, *plans, sync_out=1, output_rate_Hz=RATE)
        t_new.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for env in (wf.I_ext_mA, wf.I_flex_mA):
            check_rendered(compress(old_render_samples(env, p.fs_Hz, p.carrier_Hz, RATE,
                                                       RES), 20), 16.0, "old")
        t_old.append(time.perf_counter() - t0)
    tn, to = min(t_new), min(t_old)
    rows = [
        ("worst net charge per carrier period", f"{new_per:.3f} nC",
         f"old renderer {old_per:.1f} nC (15 levels x 2 channels, cal 2,16,1.5,16 mA); "
         f"target <= 1 nC: {'met' if new_per <= 1.0 else 'missed'}"),
        ("worst net charge per 15 s trial", f"{new_trial:.4f} uC",
         f"old renderer {old_trial:.3f} uC"),
        ("render + checks, one 15 s trial, 2 channels", f"{tn * 1e3:.0f} ms",
         f"old render + ceiling check {to * 1e3:.0f} ms; ratio {tn / to:.2f}x (best of 3; "
         "new adds the charge-balance check)"),
    ]
    w = max(len(r[0]) for r in rows)
    v = max(len(r[1]) for r in rows)
    print(f"{'figure':<{w}}  {'value':<{v}}  note")
    for name, value, note in rows:
        print(f"{name:<{w}}  {value:<{v}}  {note}")


if __name__ == "__main__":
    main()
