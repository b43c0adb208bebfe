"""The device-neutral description of what is delivered, checked against the device's
declared capabilities before any output; capabilities reached with isinstance."""

from __future__ import annotations

import pytest

from nmsid.drivers.interfaces import (
    BIPHASIC_PULSES,
    DeliveryCheckError,
    DeliveryReporting,
    Describable,
    RecoverableAcquisition,
    StimulatorCapabilities,
    Waveshape,
    check_deliverable,
)

STG = StimulatorCapabilities(2, 16.0, 0.001, 50_000.0, model="STG")
RS2 = StimulatorCapabilities(8, 130.0, 1.0, 40.0, model="RehaStim2",
                             waveshape=Waveshape(kind=BIPHASIC_PULSES, pulse_rate_Hz=40.0,
                                                 pulse_width_us=300.0),
                             hardware_trigger=False)


def test_a_ceiling_above_the_device_is_refused():
    with pytest.raises(DeliveryCheckError, match="ceiling_flex_mA = 17 mA exceeds"):
        check_deliverable(STG, ceiling_ext_mA=16.0, ceiling_flex_mA=17.0, carrier_Hz=1000.0,
                          envelope_fs_Hz=2000.0)


def test_a_sine_carrier_above_half_the_output_rate_is_refused():
    with pytest.raises(DeliveryCheckError, match="carrier_Hz = 30000 Hz"):
        check_deliverable(STG, ceiling_ext_mA=10.0, ceiling_flex_mA=10.0,
                          carrier_Hz=30_000.0, envelope_fs_Hz=2000.0)


def test_a_pulse_device_is_not_refused_for_a_carrier_it_does_not_render():
    warnings = check_deliverable(RS2, ceiling_ext_mA=16.0, ceiling_flex_mA=16.0,
                                 carrier_Hz=1000.0, envelope_fs_Hz=2000.0,
                                 highest_envelope_Hz=10.0)
    assert len(warnings) == 1 and "steps of 1 mA" in warnings[0]     # coarse resolution
    warnings = check_deliverable(RS2, ceiling_ext_mA=16.0, ceiling_flex_mA=16.0,
                                 carrier_Hz=1000.0, envelope_fs_Hz=2000.0,
                                 highest_envelope_Hz=30.0)
    assert len(warnings) == 2 and "updates its pulses at 40 Hz" in warnings[0]
    assert check_deliverable(STG, ceiling_ext_mA=16.0, ceiling_flex_mA=16.0,
                             carrier_Hz=1000.0, envelope_fs_Hz=2000.0) == []


def test_capabilities_are_structural():
    class Bare:
        pass

    class Acq:
        def device_fault(self):
            return ""

        def reconnect(self, fs_Hz):
            return fs_Hz

    assert not isinstance(Bare(), (Describable, DeliveryReporting, RecoverableAcquisition))
    assert isinstance(Acq(), RecoverableAcquisition)


def test_waveshape_json_drops_unused_fields():
    assert Waveshape(kind=BIPHASIC_PULSES, pulse_rate_Hz=40.0).to_json() == {
        "kind": BIPHASIC_PULSES, "pulse_rate_Hz": 40.0, "modulation": "amplitude"}
