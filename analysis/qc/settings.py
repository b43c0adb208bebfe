"""Thresholds of the trial quality control, each with the reason for its default."""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any, cast

from pydantic import Field, StrictFloat, StrictInt

from nmsid.analysis.errors import setting_error
from nmsid.protocols.settings_base import settings_dataclass

Seconds = Annotated[StrictFloat, Field(gt=0.0, le=600.0, description=(
    "a time within a trial, at most 10 min"))]
Hz = Annotated[StrictFloat, Field(gt=0.0, le=100_000.0, description="a frequency below 100 kHz")]
Factor = Annotated[StrictFloat, Field(gt=0.0, le=1e6, description="a positive factor")]


@settings_dataclass(setting_error, prefix="qc_settings")
class QCSettings:
    """Settings of :func:`nmsid.analysis.qc.assess_session` (``docs/identification.md``).

    Every threshold is relative to the recording's own noise or response, so the same
    defaults hold for quiet and noisy sensors and for small and large forces.
    """

    spike_highpass_Hz: Hz = 150.0
    """Spikes are sought above this frequency: the muscle's response (the chirp tops out
    at 10 Hz; its harmonics and any tremor stay below ~50 Hz) and 50/60 Hz mains with
    its second harmonic are below it, a glitch of a few samples is broadband."""
    spike_k: Factor = 8.0
    """A sample is a spike when it is this many robust SDs (1.4826 MAD) from the running
    median: Gaussian noise passes 8 SD about once in 10^15 samples."""
    spike_max_s: Seconds = 0.005
    """Longest run of outlying samples still called a spike (bridged). Longer events are
    not isolated spikes; the comparison across repeats judges them."""
    nonfinite_max_s: Seconds = 0.005
    """Longest run of NaN/Inf samples bridged by linear interpolation (a dropped USB
    packet of the A/D is 1-2 ms); longer gaps exclude the trial."""
    repair_max_total_s: Seconds = 0.05
    """Most data bridged in one trial (0.3 % of a 15 s trial). A trial that needs more is
    not a response with a few glitches: it is excluded instead."""
    stall_min_s: Seconds = 0.1
    """A run of identical samples this long is a stalled stream or a clipped channel. A
    live sensor with noise above half its A/D step never repeats a value 200 times."""
    clip_min_s: Seconds = 0.02
    """A flat run at the trial's own maximum or minimum this long is clipping (the range
    of the sensor or A/D is inferred from the data's plateaus, not assumed)."""
    lowpass_Hz: Hz = 20.0
    """Bandwidth of the comparison across repeats: twice the chirp's top frequency, below
    50/60 Hz mains and the 1 kHz carrier, so pick-up does not count as a difference."""
    window_s: Seconds = 0.25
    """Length of the sliding window in which the unshared component is measured: short
    enough to localise a 1 s voluntary contraction, long enough (~10 independent
    samples at 20 Hz) that its RMS is a stable estimate."""
    onset_ignore_s: Seconds = 0.5
    """Differences between repeats in the first this-many seconds after stimulation onset
    are not reported: how the muscles take up the stimulation depends on how long they
    rested before it (post-activation potentiation, residual force), which the protocol
    does not hold equal, and the fit never sees this part of the lead-in."""
    shared_filter_s: StrictFloat = Field(0.3, ge=0.0, le=600.0, description=(
        "0 s (gain and shift only) up to 10 min"))
    """Repeats may differ by a short linear filter, not only by gain and a time shift: each
    repeat is compared with every other one passed through the best two-sided FIR filter
    of this half-length (taps every 20 ms). Muscle dynamics vary from
    one trial to the next (a few % in wn or zeta: potentiation, temperature, strap
    tension), which changes gain and phase near the resonance; that is a response to rE,
    not an artefact. 0.3 s resolves changes about 1.7 Hz wide, the width of the elbow's
    resonance peak (2 zeta wn at wn 13-46 rad/s, zeta 0.5-0.95). A filtered repeat
    holds only the frequencies rE drives, so a contraction, a jump or a knock (slow or
    broadband force the other repeats lack) stays unexplained. 0: gain and a time shift only
    (the first release's comparison)."""
    deviation_k: Factor = 4.0
    """A window is flagged when its unshared RMS exceeds this multiple of the level's
    typical (median) unshared RMS, which already contains the sensor noise and the
    repeat-to-repeat scatter of the physiology."""
    deviation_min_frac: StrictFloat = Field(0.05, gt=0.0, lt=1.0, description="a fraction")
    """... and exceeds this fraction of the level's response RMS, so that a session with a
    near-perfect sensor does not flag differences nobody could see in the parameters."""
    attribute_ratio: Factor = 2.0
    """With only two repeats the difference is attributed to the one whose deviation from
    the neighbouring levels' response is at least this many times the other's; otherwise
    both are kept and the level is flagged."""
    noise_ratio_max: Factor = 4.0
    """Lead-in noise (robust SD of the second difference) above this multiple of the
    session's median excludes the trial: a loose electrode or cable, or muscle activity
    the stimulation did not cause."""
    min_repeats: StrictInt = Field(2, ge=1, le=100, description="repeats a level needs")
    """Fewer usable repeats than this at a level keeps the level but flags it."""
    rE_match_tol: Factor = 1e-6
    """Repeats are compared only when their commanded rE agree to this tolerance."""

    def replace(self, **changes) -> QCSettings:
        # settings_dataclass hides the dataclass from the type checker
        return cast("QCSettings", dataclasses.replace(cast(Any, self), **changes))
