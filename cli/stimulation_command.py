"""The handler of ``nmsid stimulation`` (registered by :mod:`nmsid.cli.stimulation`).

Every sE level of the protocol goes through :func:`nmsid.protocols.waveforms.trial_waveform` (as
in a session) and :func:`nmsid.drivers.stg_download.prepare_download` (as in
:meth:`nmsid.drivers.stg4002.Stg4002Stimulator.load`), with the channels, ceilings and output
rate of the hardware configuration and the STG4002's nominal range and resolution
(:data:`~nmsid.drivers.stg_download.STG4002_RANGE_NA`,
:data:`~nmsid.drivers.stg_download.STG4002_RESOLUTION_NA`; ``nmsid probe`` reports the
device's own). Memory: the per-channel capacity is the STG4002's 64 MiB split evenly over
its 2 channels and 2 sync outputs (the driver can lay out more with ``SetCapacity``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from nmsid.drivers.hw_config import load_hw_config
from nmsid.drivers.interfaces import CheckedWaveform, CurrentLimitError
from nmsid.drivers.registry import stimulator_kind
from nmsid.drivers.stg4002_settings import Stg4002Config
from nmsid.drivers.stg_download import (
    STG4002_OUTPUT_RATE_HZ,
    STG4002_RANGE_NA,
    STG4002_RESOLUTION_NA,
    ChannelPlan,
    prepare_download,
)
from nmsid.drivers.stimulation_report import SUMMARY_FORMAT, download_summary
from nmsid.errors import OutputExistsError
from nmsid.protocols.calibration import make_calibration
from nmsid.protocols.config import load_config
from nmsid.protocols.errors import CalibrationError
from nmsid.protocols.waveforms import trial_waveform

log = logging.getLogger(__name__)

STG4002_MEMORY_BYTES = 64 * 1024 * 1024
"""MC_Stimulus II manual for the STG4002 ("Pulse Types"): 64 MB."""
FILES = ("stimulation.json", "samples.npz")


def parse_calibration(text: str) -> tuple[float, float, float, float]:
    """``"Iemin,Iemax,Ifmin,Ifmax"`` (mA) -> four floats.

    Raises
    ------
    CalibrationError
        Naming the value and what is valid.
    """
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or not all(np.isfinite(values)):
        raise CalibrationError(f"--calibration {text!r}: expected four numbers in mA, "
                               "Iemin,Iemax,Ifmin,Ifmax (e.g. 2,16,1.5,16)")
    return values  # type: ignore[return-value]


def level_key(sE: float, muscle: str) -> str:
    """``samples.npz`` key of one level and channel: ``sE0.30_ext``, ``sE0.30_flex``."""
    return f"sE{sE:.2f}_{muscle}"


def render_protocol(config_path, calibration: tuple[float, float, float, float],
                    stim: Stg4002Config, output_rate_Hz: float = STG4002_OUTPUT_RATE_HZ):
    """Every level's download summary and samples.

    Returns
    -------
    report : dict
        What ``stimulation.json`` holds.
    samples : dict[str, ndarray]
        What ``samples.npz`` holds (int32 nA at the output rate, as downloaded).
    """
    cfg = load_config(config_path)
    p = cfg.protocol
    Iemin, Iemax, Ifmin, Ifmax = calibration
    cal = make_calibration((Iemin, Iemax), (Ifmin, Ifmax), cfg.calibration)
    ceil_e = min(stim.ceiling_ext_mA, cfg.calibration.ceiling_ext_mA, STG4002_RANGE_NA / 1e6)
    ceil_f = min(stim.ceiling_flex_mA, cfg.calibration.ceiling_flex_mA,
                 STG4002_RANGE_NA / 1e6)
    ext = ChannelPlan(stim.extensor_channel, "extensor", stim.ceiling_ext_mA,
                      STG4002_RANGE_NA, STG4002_RESOLUTION_NA)
    flex = ChannelPlan(stim.flexor_channel, "flexor", stim.ceiling_flex_mA,
                       STG4002_RANGE_NA, STG4002_RESOLUTION_NA)
    capacity = STG4002_MEMORY_BYTES // 4
    levels: list[dict] = []
    samples: dict[str, np.generic | np.ndarray] = {
        "output_rate_Hz": np.float64(output_rate_Hz), "carrier_Hz": np.float64(p.carrier_Hz)}
    worst = 0.0
    for sE in p.sE_levels:
        wf = trial_waveform(p, sE, cal)
        try:
            checked = CheckedWaveform(wf.I_ext_mA, wf.I_flex_mA, p.fs_Hz, p.carrier_Hz,
                                      ceil_e, ceil_f)
        except CurrentLimitError as exc:
            raise CurrentLimitError(f"sE {sE:g}: {exc}") from None
        dl = prepare_download(checked, ext, flex, stim.sync_out, output_rate_Hz)
        summary = download_summary(dl, {ext.channel: capacity, flex.channel: capacity})
        summary["sE"] = float(sE)
        levels.append(summary)
        for plan, short in ((ext, "ext"), (flex, "flex")):
            samples[level_key(sE, short)] = dl.channels[plan.channel].expand().astype(np.int32)
            worst = max(worst, summary["channels"][plan.name]["worst_net_charge_per_period_nC"])
    report = {
        "format": SUMMARY_FORMAT, "protocol": cfg.source,
        "calibration_mA": {"Iemin_mA": Iemin, "Iemax_mA": Iemax, "Ifmin_mA": Ifmin,
                           "Ifmax_mA": Ifmax},
        "device": {"model": "STG4002 (nominal)", "range_mA": STG4002_RANGE_NA / 1e6,
                   "resolution_nA": STG4002_RESOLUTION_NA,
                   "memory_bytes": STG4002_MEMORY_BYTES, "capacity_per_channel_bytes": capacity},
        "output_rate_Hz": float(output_rate_Hz), "carrier_Hz": float(p.carrier_Hz),
        "ceilings_mA": {"extensor": ceil_e, "flexor": ceil_f},
        "worst_net_charge_per_period_nC": worst,
        "samples_npz": "samples.npz: per level and channel (keys sE0.30_ext, sE0.30_flex, "
                       "...) the current in nA at output_rate_Hz, as downloaded (ending "
                       "with the final 0 nA step)",
        "levels": levels}
    return report, samples


def run(args) -> int:
    out = Path(args.out)
    if out.exists() and not args.force:
        raise OutputExistsError(f"--out {out} exists; choose a new folder or add --force "
                              "(replaces its stimulation.json and samples.npz only)")
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"--out {out} is a file, not a folder")
    calibration = parse_calibration(args.calibration)
    stim = (load_hw_config(args.hw_config).stimulator if args.hw_config
            else Stg4002Config())
    if not isinstance(stim, Stg4002Config):   # another kind: its registry entry's report
        return _run_registry(args, out, calibration, stim)
    report, samples = render_protocol(args.config, calibration, stim, stim.output_rate_Hz)
    out.mkdir(parents=True, exist_ok=True)
    (out / "stimulation.json").write_text(json.dumps(report, indent=1) + "\n",
                                          encoding="utf-8")
    np.savez_compressed(out / "samples.npz", **samples)
    n = len(report["levels"])
    print(f"stimulation: {n} sE levels rendered at {report['output_rate_Hz']:g} Hz, carrier "
          f"{report['carrier_Hz']:g} Hz; worst net charge per carrier period "
          f"{report['worst_net_charge_per_period_nC']:.3f} nC; wrote {out / FILES[0]} and "
          f"{out / FILES[1]}")
    return 0


def render_levels(config_path, calibration: tuple[float, float, float, float], stim):
    """Every level as the configured stimulator kind would deliver it (its registry entry's
    ``report``), for kinds other than the STG4002.

    Returns
    -------
    report : dict
        What ``stimulation.json`` holds.
    samples : dict[str, ndarray]
        Per level and channel, the current of each pulse in mA (int32).
    """
    entry = stimulator_kind(stim)
    cfg = load_config(config_path)
    p = cfg.protocol
    Iemin, Iemax, Ifmin, Ifmax = calibration
    cal = make_calibration((Iemin, Iemax), (Ifmin, Ifmax), cfg.calibration)
    ceil_e = min(stim.ceiling_ext_mA, cfg.calibration.ceiling_ext_mA)
    ceil_f = min(stim.ceiling_flex_mA, cfg.calibration.ceiling_flex_mA)
    levels, samples = [], {}
    for sE in p.sE_levels:
        wf = trial_waveform(p, sE, cal)
        try:
            checked = CheckedWaveform(wf.I_ext_mA, wf.I_flex_mA, p.fs_Hz, p.carrier_Hz,
                                      ceil_e, ceil_f)
        except CurrentLimitError as exc:
            raise CurrentLimitError(f"sE {sE:g}: {exc}") from None
        summary = entry.report(stim, checked)
        summary["sE"] = float(sE)
        for name, short in (("extensor", "ext"), ("flexor", "flex")):
            samples[level_key(sE, short)] = np.asarray(
                summary["channels"][name].pop("pulse_current_mA"), dtype=np.int32)
        levels.append(summary)
    report = {"format": SUMMARY_FORMAT, "protocol": cfg.source, "device": entry.title,
              "calibration_mA": {"Iemin_mA": Iemin, "Iemax_mA": Iemax, "Ifmin_mA": Ifmin,
                                 "Ifmax_mA": Ifmax},
              "carrier_Hz": float(p.carrier_Hz),
              "carrier_Hz_note": "the protocol's setting; a pulse stimulator renders none",
              "ceilings_mA": {"extensor": ceil_e, "flexor": ceil_f},
              "samples_npz": "samples.npz: per level and channel (keys sE0.30_ext, ...) the "
                             "current of each pulse in mA",
              "levels": levels}
    return report, samples


def _run_registry(args, out: Path, calibration, stim) -> int:
    report, samples = render_levels(args.config, calibration, stim)
    out.mkdir(parents=True, exist_ok=True)
    (out / "stimulation.json").write_text(json.dumps(report, indent=1) + "\n",
                                          encoding="utf-8")
    np.savez_compressed(out / "samples.npz", **samples)
    peak = max(ch["peak_current_mA"] for lv in report["levels"]
               for ch in lv["channels"].values())
    print(f"stimulation: {len(report['levels'])} sE levels as {report['device']} delivers "
          f"them ({report['levels'][0]['waveshape']['kind']}); peak pulse current "
          f"{peak:g} mA; wrote {out / FILES[0]} and {out / FILES[1]}")
    return 0
