"""The engine on the musculoskeletal participant: calibration with the hardware ramp, and
every fault injection of the simulated rig (skipped only without the 'mujoco' extra)."""

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("myo_sim")

from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.protocols.session_file import read_session, validate_session  # noqa: E402
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy  # noqa: E402
from nmsid.rig.states import State  # noqa: E402
from nmsid.sim_backends import Fault, FaultKind, make_sim_rig  # noqa: E402
from nmsid.sim_backends.msk_population import make_msk_population  # noqa: E402


@pytest.fixture(scope="module")
def participant():
    return make_msk_population(2, seed=3)[1]


def _cfg(participant, *, manual=True, **protocol):
    prot = {"sE_levels": [0.5, 0.7, 0.9], "repeats": 1, "steady_s": 0.5, "chirp_s": 1.0,
            "rest_s": 0.0}
    prot.update(protocol)
    d = {"participant": "M02", "seed": 2, "protocol": prot}
    if manual:
        c = participant.ramp_calibration()
        d["calibration"] = {"manual": {n: getattr(c, n) for n in
                                       ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA")}}
    return config_from_dict(d)


def test_calibration_ramp_finds_the_participants_currents(tmp_path, participant):
    rig = make_sim_rig(participant)
    path = tmp_path / "cal.h5"
    s = Engine(_cfg(participant, manual=False, sE_levels=[0.6]), rig, path,
               trip_policy=TripPolicy.END_SESSION).run()
    assert s.complete and validate_session(path) == []
    got = read_session(path).calibration
    want = participant.ramp_calibration()
    for n in ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA"):
        # the same 0.5 mA ramp, with sensor noise: the same step, or the next one when a
        # threshold falls within the noise of a step's force
        assert abs(getattr(got, n) - getattr(want, n)) <= 0.5 + 1e-9, n
    # the ramp data are the participant's recruitment: monotonic, extension positive
    ext = np.asarray(got.ramps["ext_force_N"])
    flex = np.asarray(got.ramps["flex_force_N"])
    assert ext[-1] >= 5.0 and flex[-1] <= -5.0
    assert np.all(np.diff(ext[ext > 0.3]) > 0) and np.all(np.diff(flex[flex < -0.3]) < 0)


class _AutoOperator(EngineObserver):
    """Re-arms after a trip (releasing the switch first) and re-runs the aborted trial."""

    def __init__(self, rig):
        self.rig, self.engine, self.trips, self.output_at_trip = rig, None, [], []

    def on_state(self, old, new, reason):
        if new is State.TRIPPED:
            self.trips.append(reason)
            self.output_at_trip.append(self.rig.world.output_active_at(
                self.rig.clock.monotonic_s()))
            self.rig.estop.release()
            idx = [p.index for p in self.engine.schedule if p.status.value == "aborted"]
            self.engine.commands.rearm()
            for i in idx:
                self.engine.commands.rerun(i)


FAULTS = [
    (Fault(FaultKind.SENSOR_STALL, trial=1, at_s=0.7, duration_s=0.5), "sensor_stream: "),
    (Fault(FaultKind.SENSOR_FAULT, trial=1, at_s=0.7), "acquisition: "),
    (Fault(FaultKind.OVER_RANGE, trial=1, at_s=0.7), "acquisition: "),
    (Fault(FaultKind.OVERRUN, trial=1, at_s=0.7, lost_s=0.05), "acquisition: "),
    (Fault(FaultKind.FORCE_SPIKE, trial=1, at_s=0.7, amplitude_N=100.0), "force_limit: "),
    (Fault(FaultKind.STIM_ERROR, trial=1, at_s=0.7), "stimulator: "),
    (Fault(FaultKind.STIM_DISCONNECT, trial=1, at_s=0.7), "stimulator: "),
    (Fault(FaultKind.ESTOP, trial=1, at_s=0.7), "estop: "),
]


@pytest.mark.parametrize("fault, reason", FAULTS, ids=[f.kind.value for f, _ in FAULTS])
def test_fault_injection_works_on_it(tmp_path, participant, fault, reason):
    rig = make_sim_rig(participant, faults=[fault])
    op = _AutoOperator(rig)
    path = tmp_path / "f.h5"
    eng = Engine(_cfg(participant), rig, path, observer=op)
    op.engine = eng
    s = eng.run()
    assert s.complete, s
    assert len(op.trips) == 1 and op.trips[0].startswith(reason), op.trips
    assert op.output_at_trip == [False]
    assert not rig.world.output_active_at(rig.clock.monotonic_s())
    sess = read_session(path)
    assert validate_session(path) == []
    assert [t.status for t in sess.trials] == ["completed", "aborted", "completed",
                                               "completed"]
    assert 1000 <= sess.trials[1].n_samples <= 1800
    cal = participant.ramp_calibration()
    assert rig.max_sent_mA[0] <= cal.Iemax_mA + 1e-9
    assert rig.max_sent_mA[1] <= cal.Ifmax_mA + 1e-9


def test_after_an_estop_the_force_relaxes(tmp_path, participant):
    rig = make_sim_rig(participant, faults=[Fault(FaultKind.ESTOP, trial=0, at_s=0.6)])
    path = tmp_path / "e.h5"
    Engine(_cfg(participant, sE_levels=[0.9]), rig, path,
           trip_policy=TripPolicy.END_SESSION).run()
    assert rig.output_zero_events and not rig.world.output_active_at(
        rig.clock.monotonic_s())
    # simulate on after the stop: the participant returns to rest (no current, no force)
    sim = rig.world.sim
    sim.advance_quiet(8000)
    z = np.zeros(400)
    assert np.max(np.abs(sim.simulate(z, z).true_force_N)) < 0.05
