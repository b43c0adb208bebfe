"""The FES physics of the musculoskeletal participant, against closed forms (no MuJoCo)."""

import math

import numpy as np
import pytest

from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.msk_physics import (
    MUSCLES,
    FixtureMount,
    MuscleDrive,
    MuscleFatigue,
    Recruitment,
    default_drives,
)


@pytest.mark.parametrize("th, i50, w, a", [(2.0, 8.0, 1.5, 0.1), (0.5, 3.0, 0.4, 1.0),
                                           (4.0, 12.0, 3.0, 0.02)])
def test_recruitment_threshold_sigmoid_saturation(th, i50, w, a):
    r = Recruitment(th, i50, w, a)
    I = np.linspace(0, 40, 4001)
    f = r(I)
    assert np.all(f[I <= th] == 0)                       # nothing below threshold
    assert np.all(np.diff(f) >= 0)                        # monotonic
    assert f[-1] == pytest.approx(a, rel=1e-4)            # saturates at the reach
    s = lambda x: 1 / (1 + math.exp(-(x - i50) / w))  # noqa: E731 (closed form at the midpoint)
    want = a * (0.5 - s(th)) / (1 - s(th))
    assert float(r(i50)) == pytest.approx(want, rel=1e-12)
    # steepest rise at the midpoint (sigmoid), not at the threshold
    slope = np.gradient(f, I)
    assert abs(I[np.argmax(slope)] - i50) < 0.02


def test_spill_over_drives_the_neighbour_with_more_current():
    own = Recruitment(2.0, 8.0, 1.5, 0.12)
    spill = Recruitment(7.0, 14.0, 2.0, 0.006)
    bic = MuscleDrive("BIClong", own, spill)
    tri = MuscleDrive("TRIlat", own, spill)
    I_e = np.array([0.0, 5.0, 10.0, 16.0])
    I_f = np.zeros(4)
    assert np.all(bic.command(I_f, I_f) == 0)
    # the extensor electrode reaches the flexor only above the spill threshold, weakly
    c = bic.command(I_e, I_f)
    assert c[0] == c[1] == 0 and 0 < c[2] < c[3] <= 0.006
    np.testing.assert_allclose(tri.command(I_e, I_f), own(I_e))
    np.testing.assert_allclose(bic.command(I_f, I_e), own(I_e))


def test_mount_gives_its_natural_frequency_and_damping():
    for I in (0.05, 0.08, 0.12):
        m = FixtureMount(wn_rad_s=20.0, zeta=0.6)
        K, B = m.stiffness_damping(I)
        assert math.sqrt(K / I) == pytest.approx(20.0)
        assert B / (2 * math.sqrt(K * I)) == pytest.approx(0.6)


def test_fatigue_step_is_the_exact_solution():
    fat = MuscleFatigue(tau_fatigue_s=60.0, tau_recovery_s=120.0, min_fraction=0.4)
    f0 = np.array([1.0, 0.7, 0.5])
    a = np.array([1.0, 0.0, 0.3])
    # one long step equals many small ones (a held constant: exact linear ODE)
    f_big = fat.step(f0, a, 30.0)
    f_small = f0.copy()
    for _ in range(3000):
        f_small = fat.step(f_small, a, 0.01)
    np.testing.assert_allclose(f_big, f_small, rtol=1e-10)
    # full recruitment: exponential decay towards min_fraction with tau_fatigue
    assert f_big[0] == pytest.approx(0.4 + 0.6 * math.exp(-0.5))
    # no stimulation: recovery towards 1 with tau_recovery
    assert f_big[1] == pytest.approx(1 - 0.3 * math.exp(-0.25))
    assert np.all(MuscleFatigue().step(f0, a, 100.0)[[0]] == pytest.approx(1.0))  # off


def test_default_drives_cover_the_model_muscles_in_order():
    d = default_drives()
    assert tuple(x.muscle for x in d) == MUSCLES
    assert [x.is_extensor for x in d] == [True] * 3 + [False] * 3


@pytest.mark.parametrize("make, word", [
    (lambda: Recruitment(5.0, 4.0, 1.0, 0.1), "I50_mA"),
    (lambda: Recruitment(1.0, 4.0, 0.0, 0.1), "width_mA"),
    (lambda: Recruitment(1.0, 4.0, 1.0, 1.5), "max_activation"),
    (lambda: FixtureMount(zeta=-1), "zeta"),
    (lambda: FixtureMount(angle_deg=170), "angle_deg"),
    (lambda: MuscleFatigue(tau_fatigue_s=0), "tau_fatigue_s"),
    (lambda: MuscleDrive("DELT1", Recruitment()), "DELT1"),
])
def test_bad_settings_name_the_setting(make, word):
    with pytest.raises(SimConfigError, match=word):
        make()


def test_missing_extra_is_one_clear_error(monkeypatch, tmp_path, capsys):
    import sys

    from nmsid.cli import main
    from nmsid.sim_backends.msk_model import MujocoUnavailable
    from nmsid.sim_backends.msk_participant import default_msk_participant
    from nmsid.sim_backends.msk_simulation import MskSimulator

    monkeypatch.setitem(sys.modules, "mujoco", None)      # as if not installed
    with pytest.raises(MujocoUnavailable, match=r"'mujoco' extra"):
        MskSimulator(default_msk_participant())
    out = tmp_path / "x.h5"
    assert main(["run", "--backend", "sim", "--participant-model", "musculoskeletal",
                 "--out", str(out), "--quiet", "--no-identify"]) == 2
    err = capsys.readouterr().err
    assert "'mujoco' extra" in err and "pip install" in err and "Traceback" not in err
    assert not out.exists()
