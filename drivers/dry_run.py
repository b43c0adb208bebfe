"""``nmsid probe --dry-run``: short low-current trials into a dummy-load resistor, the
comparisons of what was recorded with what was commanded (the trials themselves are a plan
run by the engine: :mod:`nmsid.rig.dry_run`).

Wiring (``docs/hardware.md``, "Dry run on a dummy load"): the tested STG output drives a
resistor of ``load_ohm`` (1 kOhm, >= 0.25 W) instead of electrodes; the voltage over it
goes to a spare A/D input, the STG sync output to the A/D's trigger input and sync channel
as in a session. The trial: 1 s at 1 kHz carrier on one channel (the other at 0 mA), an
envelope that ramps up to ``amplitude_mA`` (default 2 mA = 2 V over 1 kOhm), holds, steps
to half, ramps down. Force, sync and the resistor's voltage are recorded in ONE triggered
scan of the analog chain (``acquisition.monitor_channel`` added to the session's channels,
:func:`nmsid.drivers.hardware.with_monitor`) at ``monitor_fs_Hz`` (``acquisition.
monitor_fs_Hz``, 10 kHz by default: 10 samples per carrier period), through the same
driver code as a session.

What is compared with what the driver downloaded (``Stg4002Stimulator.last_download``,
the exact samples), each printed with its figure and limit:

* ``onset``: the recorded current lags the command by at most :data:`ONSET_LIMIT_S`
  (cross-correlation to the sample, refined by the carrier's phase; sample 0 of the record
  is the sync edge, as for the force record). A multiplexed A/D converts the monitor
  input a little after the scan's clock edge (``sample_delay_s`` of the driver: channel x
  conversion time on the CAIO, channel / convert clock on NI); that known delay is added
  back and printed;
* ``force record``: the force acquisition, triggered by the same sync, sees the sync high
  at its sample 0 (onset timing against the force record);
* ``amplitude``: per carrier period (lock-in at the carrier), measured vs commanded, at
  most :data:`AMPLITUDE_LIMIT` of ``amplitude_mA``;
* ``carrier``: spectral peak within :data:`CARRIER_LIMIT` of the carrier frequency;
* ``envelope``: correlation of the per-period amplitudes >= :data:`ENVELOPE_LIMIT`;
* ``charge balance``: worst net charge of one carrier period, measured, at most
  :data:`CHARGE_LIMIT_NC` or 1 % of the largest phase charge.

The streamed trial on a carrier stimulator (the STG4002; :func:`check_stream_lockin`):

* ``stream: amplitude``: each carrier period's lock-in amplitude on the resistor against
  the streamed update in force (counted from the sync edge, ``carrier / update rate``
  periods per update; zero after the last), at most :data:`AMPLITUDE_LIMIT` of
  ``amplitude_mA``: a gain error, a wrong resistor or a stream that ran dry fails it;
* ``stream: envelope``: correlation of the measured and commanded per-period amplitudes
  >= :data:`ENVELOPE_LIMIT`.

Before anything is stimulated the dry run needs an analog chain (caio / nidaq) with
``acquisition.monitor_channel`` set; otherwise ``nmsid probe --dry-run`` says so in one line
(:func:`nmsid.drivers.hardware.with_monitor`). A record that comes back short, flagged
(overrun, over-range, sensor fault) or at another rate than asked fails with the reason.
In fake mode (``fake = true``) the fake A/D's monitor input carries the fake STG's real
output across a simulated resistor (``testing.fakes.bench.monitor_wiring``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from nmsid.drivers.errors import StimulatorSettingError

log = logging.getLogger(__name__)

MAX_DRY_RUN_MA = 5.0
A2D_RANGE_V = 10.0
ONSET_LIMIT_S = 1e-4
AMPLITUDE_LIMIT = 0.05
CARRIER_LIMIT = 0.01
ENVELOPE_LIMIT = 0.99
CHARGE_LIMIT_NC = 2.0
ENVELOPE_FS_HZ = 2000.0
CARRIER_HZ = 1000.0


@dataclass(frozen=True)
class DryRunSettings:
    """What the dry run stimulates and how it records (``nmsid probe`` flags)."""

    load_ohm: float = 1000.0
    channel: str = "extensor"
    amplitude_mA: float = 2.0
    duration_s: float = 1.0
    monitor_fs_Hz: float = 10_000.0

    def __post_init__(self):
        if self.channel not in ("extensor", "flexor"):
            raise StimulatorSettingError(f"dry-run channel {self.channel!r}: expected "
                                         "'extensor' or 'flexor'")
        if not 0 < self.amplitude_mA <= MAX_DRY_RUN_MA:
            raise StimulatorSettingError(f"dry-run amplitude {self.amplitude_mA:g} mA: "
                                         f"expected > 0 and <= {MAX_DRY_RUN_MA:g} mA (a "
                                         "low-current check)")
        if not 100 <= self.load_ohm <= 10_000:
            raise StimulatorSettingError(f"dummy load {self.load_ohm:g} Ohm: expected 100 .. "
                                         "10000 Ohm (1000 Ohm recommended)")
        if self.amplitude_mA * 1e-3 * self.load_ohm > A2D_RANGE_V:
            raise StimulatorSettingError(
                f"{self.amplitude_mA:g} mA over {self.load_ohm:g} Ohm is "
                f"{self.amplitude_mA * self.load_ohm / 1000:g} V, above the A/D's "
                f"+-{A2D_RANGE_V:g} V; lower the amplitude or the resistor")
        per = self.monitor_fs_Hz / CARRIER_HZ
        if abs(per - round(per)) > 1e-9 or round(per) < 10:
            raise StimulatorSettingError(f"monitor rate {self.monitor_fs_Hz:g} Hz: expected a "
                                         f"multiple of the {CARRIER_HZ:g} Hz carrier, >= 10x")
        if not 0.2 <= self.duration_s <= 5:
            raise StimulatorSettingError(f"dry-run duration {self.duration_s:g} s: expected "
                                         "0.2 .. 5 s")


@dataclass(frozen=True)
class Check:
    """One comparison of the recorded current with the command."""

    name: str
    passed: bool
    figure: str
    limit: str

    def line(self) -> str:
        return f"  [{'PASS' if self.passed else 'FAIL'}] {self.name}: {self.figure} " \
               f"(limit {self.limit})"


def dry_run_envelope(s: DryRunSettings, fs_Hz: float = ENVELOPE_FS_HZ) -> np.ndarray:
    """Ramp up (20 %), hold at ``amplitude_mA`` (40 %), half (20 %), ramp down (20 %)."""
    n = int(round(s.duration_s * fs_Hz))
    x = np.arange(n) / n
    A = s.amplitude_mA
    env = np.select([x < 0.2, x < 0.6, x < 0.8], [A * x / 0.2, A, A / 2],
                    A / 2 * (1 - (x - 0.8) / 0.2))
    return np.clip(env, 0.0, A)


def dry_run_chirp_envelope(s: DryRunSettings, fs_Hz: float = ENVELOPE_FS_HZ,
                           f0_Hz: float = 0.5, f1_Hz: float = 10.0) -> np.ndarray:
    """The E-stop test's envelope: ``amplitude_mA`` x (1 + sin(exponential chirp)) / 2, the
    chirp sweeping ``f0_Hz`` .. ``f1_Hz`` over ``duration_s`` (the shape of a session's
    trial, at dry-run currents)."""
    n = int(round(s.duration_s * fs_Hz))
    t = np.arange(n) / fs_Hz
    T = s.duration_s
    k = (f1_Hz / f0_Hz) ** (1 / T)
    phase = 2 * np.pi * f0_Hz * (k ** t - 1) / np.log(k)
    return np.clip(s.amplitude_mA * 0.5 * (1 - np.cos(phase)), 0.0, s.amplitude_mA)


def commanded_current_A(values_nA: np.ndarray, output_rate_Hz: float, n: int,
                        fs_Hz: float) -> np.ndarray:
    """The downloaded samples (nA at the output rate) as the monitor would see them (A)."""
    k = np.floor(np.arange(n) * output_rate_Hz / fs_Hz + 1e-9).astype(np.int64)
    x = np.asarray(values_nA, dtype=np.float64)
    return np.where(k < len(x), x[np.minimum(k, len(x) - 1)], 0.0) * 1e-9


def _per_period(i_A: np.ndarray, fs_Hz: float) -> np.ndarray:
    P = int(round(fs_Hz / CARRIER_HZ))
    m = len(i_A) // P
    return i_A[:m * P].reshape(m, P)


def _carrier_ref(n: int, fs_Hz: float) -> np.ndarray:
    """``exp(-j 2 pi f_c t)`` at ``n`` samples from t = 0: the lock-in's reference."""
    return np.exp(-2j * np.pi * CARRIER_HZ * np.arange(n) / fs_Hz)


def lockin_amplitude_A(i_A: np.ndarray, fs_Hz: float) -> np.ndarray:
    """Carrier amplitude per period: ``2 |mean(i exp(-j 2 pi f_c t))|`` (independent of the
    carrier's phase, so a known A/D scan delay does not bias it)."""
    per = _per_period(i_A, fs_Hz)
    return 2 * np.abs((per * _carrier_ref(per.shape[1], fs_Hz)).mean(axis=1))


def _lag_samples(measured: np.ndarray, command: np.ndarray, max_lag: int) -> int:
    best, best_c = 0, -np.inf
    for lag in range(-max_lag, max_lag + 1):
        a = measured[max(lag, 0):len(measured) + min(lag, 0)]
        b = command[max(-lag, 0):len(command) - max(lag, 0)]
        c = float(np.dot(a, b))
        if c > best_c:
            best, best_c = lag, c
    return best


def _delay_s(measured: np.ndarray, command: np.ndarray, fs_Hz: float, max_lag: int) -> float:
    """Delay of ``measured`` behind ``command`` (s): to the sample by cross-correlation,
    refined by the phase of the carrier (within half a sample)."""
    lag = _lag_samples(measured, command, max_lag)
    a = measured[max(lag, 0):len(measured) + min(lag, 0)]
    b = command[max(-lag, 0):len(command) - max(lag, 0)]
    ref = _carrier_ref(len(a), fs_Hz)
    za, zb = complex(np.dot(a, ref)), complex(np.dot(b, ref))
    fine = 0.0 if za == 0 or zb == 0 else -np.angle(za / zb) / (2 * np.pi * CARRIER_HZ)
    return lag / fs_Hz + fine


def check_loopback(monitor_V: np.ndarray, sync_V: np.ndarray, command_A: np.ndarray,
                   s: DryRunSettings, force_sync_first_V: float | None, *,
                   monitor_delay_s: float = 0.0) -> list[Check]:
    """Compare the recorded resistor current with the command (see module docstring).

    ``monitor_delay_s``: how long after the scan's clock edge the A/D converts the monitor
    input (added back to the measured onset).
    """
    fs = s.monitor_fs_Hz
    i_A = np.asarray(monitor_V, dtype=float) / s.load_ohm
    out = []
    high = np.flatnonzero(np.asarray(sync_V) > 1.5)
    edge = int(high[0]) if high.size else -1
    lag_s = _delay_s(i_A, command_A, fs, int(2 * fs / CARRIER_HZ)) + monitor_delay_s
    scan = f", scan delay {monitor_delay_s * 1e3:.3f} ms corrected" if monitor_delay_s else ""
    out.append(Check("onset", edge in (0, 1) and abs(lag_s) <= ONSET_LIMIT_S,
                     f"current {lag_s * 1e3:+.3f} ms against the command{scan}, sync edge "
                     f"at sample {edge}", f"+-{ONSET_LIMIT_S * 1e3:g} ms, edge at sample 0"))
    if force_sync_first_V is None:
        out.append(Check("force record", False, "no sync channel in the record",
                         "sync high at sample 0"))
    else:
        out.append(Check("force record", force_sync_first_V > 1.5,
                         f"sync {force_sync_first_V:.2f} V at sample 0 of the force record "
                         "(the same triggered scan)",
                         "> 1.5 V (triggered on the sync edge)"))
    meas = lockin_amplitude_A(i_A, fs)
    cmd = lockin_amplitude_A(command_A, fs)
    on = cmd > 0.1 * s.amplitude_mA * 1e-3
    err_A = float(np.abs(meas[on] - cmd[on]).max()) if on.any() else np.inf
    rel = err_A / (s.amplitude_mA * 1e-3)
    out.append(Check("amplitude", rel <= AMPLITUDE_LIMIT,
                     f"max error {err_A * 1e3:.3f} mA ({rel * 100:.1f} % of "
                     f"{s.amplitude_mA:g} mA) over {int(on.sum())} carrier periods",
                     f"{AMPLITUDE_LIMIT * 100:g} %"))
    n_fft = 8 * len(i_A)
    spec = np.abs(np.fft.rfft(i_A * np.hanning(len(i_A)), n_fft))
    k = int(np.argmax(spec[1:])) + 1
    if 1 <= k < len(spec) - 1:  # parabolic interpolation of the peak
        a, b, c = np.log(spec[k - 1:k + 2] + 1e-300)
        k = k + 0.5 * (a - c) / (a - 2 * b + c)
    f_Hz = k * fs / n_fft
    out.append(Check("carrier", abs(f_Hz - CARRIER_HZ) <= CARRIER_LIMIT * CARRIER_HZ,
                     f"{f_Hz:.2f} Hz", f"{CARRIER_HZ:g} Hz +-{CARRIER_LIMIT * 100:g} %"))
    r = float(np.corrcoef(meas, cmd)[0, 1]) if len(cmd) > 2 and cmd.std() > 0 else 0.0
    out.append(Check("envelope", r >= ENVELOPE_LIMIT, f"r = {r:.4f} over {len(cmd)} "
                     "carrier periods", f">= {ENVELOPE_LIMIT:g}"))
    per = _per_period(i_A, fs)
    net_nC = np.abs(per.sum(axis=1)) / fs * 1e9
    phase_nC = float(np.where(per > 0, per, 0).sum(axis=1).max(initial=0) / fs * 1e9)
    limit = max(CHARGE_LIMIT_NC, 0.01 * phase_nC)
    worst = float(net_nC.max(initial=0))
    total_nC = float(i_A.sum() / fs * 1e9)
    out.append(Check("charge balance", worst <= limit,
                     f"worst net {worst:.3f} nC per carrier period (phase {phase_nC:.0f} nC), "
                     f"{total_nC:+.2f} nC over the trial", f"{limit:.2f} nC per period"))
    return out


def check_stream_lockin(monitor_V: np.ndarray, commands_mA, rate_Hz: float,
                        s: DryRunSettings, fs_Hz: float) -> list[Check]:
    """The streamed carrier on the resistor against the commands.

    Each carrier period's amplitude (:func:`lockin_amplitude_A`)
    against the update in force: one update lasts ``CARRIER_HZ / rate_Hz`` whole carrier
    periods from the sync edge (sample 0). Sources, McsUsbNet manual 5.3.15, 6.3
    "Streaming mode": the queued data (``EnqueueData``) is sent to the analog output "on
    the fly" through the PC's and the STG's ring buffers, in order, once the trigger is
    started ("Start Trigger by pushing the front button or by Software ``SendStart(1)``",
    6.3.1), the trigger's sync output with it (``SetupTrigger`` syncoutmap); the driver
    renders each update as whole charge-balanced periods. Every period counts: a stream
    that ran dry ("When DisableContinousMode is used, the STG stops when it runs out of
    data", 6.3) or whose ring buffer underflowed ("data jumps of the output signals", 6.3.1)
    fails the amplitude check, and so does current after the last update (commanded zero)
    or an amplitude off by more than
    :data:`AMPLITUDE_LIMIT` of ``amplitude_mA``.
    """
    i_A = np.asarray(monitor_V, dtype=float) / s.load_ohm
    meas = lockin_amplitude_A(i_A, fs_Hz)
    K = max(1, round(CARRIER_HZ / rate_Hz))
    j = np.arange(len(meas)) // K
    cmd_mA = np.asarray(list(commands_mA), dtype=float)
    cmd = np.where(j < len(cmd_mA), cmd_mA[np.minimum(j, max(len(cmd_mA) - 1, 0))]
                   if len(cmd_mA) else 0.0, 0.0) * 1e-3
    on = cmd > 0.1 * s.amplitude_mA * 1e-3
    out = []
    if not on.any():
        return [Check("stream: amplitude", False, "no update above 10 % of "
                      f"{s.amplitude_mA:g} mA was commanded", ">= 1 carrier period")]
    err = np.abs(meas - cmd)      # every period: current where none was commanded too
    k = int(np.argmax(err))
    rel = float(err[k]) / (s.amplitude_mA * 1e-3)
    out.append(Check("stream: amplitude", rel <= AMPLITUDE_LIMIT,
                     f"max error {err[k] * 1e3:.3f} mA ({rel * 100:.1f} % of "
                     f"{s.amplitude_mA:g} mA; {meas[k] * 1e3:.3f} mA delivered, "
                     f"{cmd[k] * 1e3:.3f} mA commanded, carrier period {k}) over {len(meas)} "
                     f"carrier periods of {len(cmd_mA)} updates",
                     f"{AMPLITUDE_LIMIT * 100:g} %"))
    r = float(np.corrcoef(meas, cmd)[0, 1]) if len(cmd) > 2 and cmd.std() > 0 and \
        meas.std() > 0 else 0.0
    out.append(Check("stream: envelope", r >= ENVELOPE_LIMIT,
                     f"r = {r:.4f} over {len(cmd)} carrier periods", f">= {ENVELOPE_LIMIT:g}"))
    return out


def record_problem(got: int, n: int, flags: list[str], monitor: list) -> str:
    if flags:
        return f"the A/D flagged the record: {flags[0]}"
    if got < n:
        return f"only {got} of {n} samples arrived (was the A/D triggered by the sync?)"
    if any(m is None for m in monitor):
        return "the record has no monitor channel (acquisition.monitor_channel)"
    return ""


ESTOP_ZERO_LIMIT_MA = 0.05
"""After an E-stop the resistor current stays below this (A/D noise: 1 mV / 1 kOhm = 1 uA)."""
PULSE_AMPLITUDE_LIMIT_MA = 0.25
"""A pulse's measured peak within this of the acknowledged current (RehaStim2: whole mA)."""


def check_after_stop(monitor_V: np.ndarray, sync_V: np.ndarray | None, s: DryRunSettings,
                     *, has_sync: bool) -> list[Check]:
    """After an E-stop: the resistor current is zero and (if the device has one) the sync
    output is low, over the whole record taken after the stop."""
    i_mA = np.abs(np.asarray(monitor_V, float)) / s.load_ohm * 1e3
    worst = float(i_mA.max()) if i_mA.size else np.inf
    out = [Check("E-stop: output zero", worst <= ESTOP_ZERO_LIMIT_MA,
                 f"max {worst:.4f} mA over {len(i_mA)} samples after the stop",
                 f"<= {ESTOP_ZERO_LIMIT_MA:g} mA")]
    if has_sync:
        high = float(np.max(sync_V)) if sync_V is not None and len(sync_V) else np.inf
        out.append(Check("E-stop: sync low", high < 1.5, f"max {high:.2f} V after the stop",
                         "< 1.5 V"))
    return out


def pulses_in_force(pulses_mA: list[int], pulse_index: list[int] | None,
                    repeats: bool = True) -> list[int]:
    """The current of every pulse period from the first update to the last: an update
    stays in force until the next (ScienceMode2 1.3, continuous channel list mode), so a
    skipped slot repeats the previous current. ``repeats`` False (the delivery summary's
    ``repeats_update``; ScienceMode4 low level, one command per pulse): a skipped slot
    has no pulse."""
    if not pulse_index or not repeats:
        return list(pulses_mA)
    out, j = [], 0
    for k in range(pulse_index[0], pulse_index[-1] + 1):
        while j + 1 < len(pulse_index) and pulse_index[j + 1] <= k:
            j += 1
        out.append(pulses_mA[j])
    return out


def check_pulses(monitor_V: np.ndarray, s: DryRunSettings, pulses_mA: list[int],
                 pulse_width_us: float, interphase_us: float = 100.0,
                 pulse_index: list[int] | None = None, repeats: bool = True) -> list[Check]:
    """A pulse stimulator on the dummy load: the pulses found in the record (a rising edge
    above half the smallest commanded pulse starts one) against the acknowledged updates.

    In the continuous channel list mode (ScienceMode2 1.3) the device repeats the last
    parameters every main interval until the next update or the stop, so the pulses found
    are matched to the updates in order (each pulse's peak within
    :data:`PULSE_AMPLITUDE_LIMIT_MA` of the update in force, the updates advancing
    monotonically), their number is within two of the non-zero updates, and each pulse's
    two phases cancel (charge balance).
    """
    fs = s.monitor_fs_Hz
    i_mA = np.asarray(monitor_V, float) / s.load_ohm * 1e3
    cmd = [float(p) for p in pulses_in_force(pulses_mA, pulse_index, repeats) if p > 0]
    # a pulse starts where the current rises above half the smallest pulse commanded: a
    # fixed 0.5 mA equalled the ScienceMode4 step (0.5 mA pulses), so A/D noise decided
    # on which of a pulse's samples its window began (cutting its first sample off: a
    # charge-balanced pulse measured 50 nC unbalanced)
    above = i_mA > (0.5 * min(cmd) if cmd else 0.5)
    starts = np.flatnonzero(above[1:] & ~above[:-1]) + 1
    span = int(np.ceil((2 * pulse_width_us + interphase_us) * 1e-6 * fs)) + 2
    starts = starts[starts + span <= len(i_mA)]
    count = Check("pulse count", len(cmd) > 0 and abs(len(starts) - len(cmd)) <= 2,
                  f"{len(starts)} pulses found, {len(cmd)} non-zero pulse periods from the "
                  "acknowledged updates", "within 2, > 0")
    if not len(starts) or not cmd:
        return [count]
    win = np.stack([i_mA[k - 1:k - 1 + span] for k in starts])
    peaks = win.max(axis=1)
    j, worst = 0, 0.0
    for pk in peaks:
        while j < len(cmd) - 1 and abs(pk - cmd[j]) > PULSE_AMPLITUDE_LIMIT_MA:
            j += 1
        worst = max(worst, abs(pk - cmd[j]))
    net_nC = np.abs(win.sum(axis=1)) / fs * 1e6
    phase_nC = float(np.where(win > 0, win, 0).sum(axis=1).max() / fs * 1e6)
    limit = max(CHARGE_LIMIT_NC, 0.05 * phase_nC)
    return [count,
            Check("pulse amplitude", worst <= PULSE_AMPLITUDE_LIMIT_MA,
                  f"max error {worst:.3f} mA over {len(peaks)} pulses, matched in order",
                  f"{PULSE_AMPLITUDE_LIMIT_MA:g} mA"),
            Check("charge balance", float(net_nC.max()) <= limit,
                  f"worst net {float(net_nC.max()):.3f} nC per pulse (phase {phase_nC:.0f} nC)",
                  f"{limit:.2f} nC per pulse")]
