"""A lab's own participant model on the simulated rig (``--participant-model pkg.mod:f``)."""

import sys
import textwrap

import numpy as np
import pytest

from nmsid.errors import UserError
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.direct_drive import run_waveform, waveform
from nmsid.sim_backends.participant import default_participant
from nmsid.sim_backends.participant_models import participant_for_model
from nmsid.sim_backends.plugin import (
    PluginParticipant,
    plugin_participant,
    template,
)
from nmsid.sim_backends.sensor import SensorModel
from nmsid.sim_backends.simulation import ParticipantSimulator

LAB_MODULE = """
import numpy as np

class FirstOrder:
    '''Extensor minus flexor through a first-order lag, 1 N per mA above 1 mA.'''
    def __init__(self, seed, fs_Hz):
        self.a = np.exp(-1.0 / (0.05 * fs_Hz))
        self.y = 0.0
        self.calls = []
    def force_N(self, I_ext_mA, I_flex_mA):
        self.calls.append(len(I_ext_mA))
        u = np.maximum(I_ext_mA - 1.0, 0) - np.maximum(I_flex_mA - 1.0, 0)
        out = np.empty(len(u))
        for k, uk in enumerate(u):
            self.y = self.a * self.y + (1 - self.a) * uk
            out[k] = self.y
        return out

def make(seed, fs_Hz):
    return FirstOrder(seed, fs_Hz)

class Short(FirstOrder):
    def force_N(self, I_ext_mA, I_flex_mA):
        return np.zeros(max(len(I_ext_mA) - 1, 0))

class Nan(FirstOrder):
    def force_N(self, I_ext_mA, I_flex_mA):
        out = np.zeros(len(I_ext_mA))
        if np.any(I_ext_mA > 0):
            out[-1] = np.nan
        return out

def short(seed, fs_Hz):
    return Short(seed, fs_Hz)

def nan(seed, fs_Hz):
    return Nan(seed, fs_Hz)

def nothing(seed, fs_Hz):
    return object()

class Restorable(FirstOrder):
    restores = 0
    def snapshot(self):
        return self.y
    def restore(self, y):
        self.y = y
        self.restores += 1

def restorable(seed, fs_Hz):
    return Restorable(seed, fs_Hz)

def exits(seed, fs_Hz):
    import sys
    sys.exit(0)

def raises(seed, fs_Hz):
    raise RuntimeError("no licence")

not_callable = 3
"""


@pytest.fixture
def lab_dir(tmp_path, monkeypatch):
    (tmp_path / "labmodel_x.py").write_text(textwrap.dedent(LAB_MODULE), encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    yield tmp_path
    sys.modules.pop("labmodel_x", None)


def test_module_in_the_current_directory_is_loaded(lab_dir):
    p = participant_for_model("labmodel_x:make", seed=4)
    assert isinstance(p, PluginParticipant) and p.seed == 4
    assert str(lab_dir) not in sys.path   # the search path is left as it was


@pytest.mark.parametrize("spec, words", [
    ("labmodel_x", "one colon"),
    ("labmodel_x:make:again", "one colon"),
    ("no_such_module_qq:make", "not found"),
    ("labmodel_x:absent", "has no 'absent'"),
    ("labmodel_x:not_callable", "not a callable"),
    ("labmodel_x:nothing", "without a force_N"),
    ("labmodel_x:short", "shape (63,)"),
    ("labmodel_x:nan", "nan"),
    ("1bad:make", "dotted module name"),
])
def test_a_bad_spec_is_one_line_user_error(lab_dir, spec, words):
    with pytest.raises(UserError) as e:
        plugin_participant(spec)
    msg = str(e.value)
    assert "\n" not in msg and spec in msg and words in msg


def test_plugin_force_reaches_the_acquisition_through_the_sensor(lab_dir):
    p = plugin_participant("labmodel_x:make", seed=1)
    p = PluginParticipant(p.spec, p.factory, seed=1, sensor=SensorModel.ideal())
    rig = make_sim_rig(p)
    rig.stimulator.connect()
    n = 4000
    I_e = np.full(n, 3.0)
    I_f = np.full(n, 1.5)
    force, _ = run_waveform(rig, waveform(I_e, I_f))
    # first-order lag to 2 - 0.5 = 1.5 N: closed form y_k = 1.5 (1 - a^(k+1))
    a = np.exp(-1.0 / (0.05 * 2000.0))
    expect = 1.5 * (1 - a ** (np.arange(n) + 1))
    assert np.allclose(force, expect, atol=1e-9)
    # consecutive blocks: the model saw every sample once, in order
    model = rig.world.sim.model
    assert sum(model.calls) == rig.world.sim.cursor


def test_rollback_uses_the_models_own_snapshot_and_never_copies_it(lab_dir):
    """An E-stop mid-block makes the rig roll the model back and replay: same samples,
    through the model's own snapshot()/restore() (the rig never deep-copies a plug-in)."""
    p = plugin_participant("labmodel_x:restorable")
    p = PluginParticipant(p.spec, p.factory, sensor=SensorModel.ideal())
    rig = make_sim_rig(p)
    rig.stimulator.connect()
    sim = rig.world.sim
    assert not sim.forward_only
    snap = sim.snapshot()
    a = sim.simulate(np.full(50, 4.0), np.zeros(50)).true_force_N
    sim.restore(snap)
    b = sim.simulate(np.full(50, 4.0), np.zeros(50)).true_force_N
    sim.restore(snap)
    c = sim.simulate(np.full(50, 4.0), np.zeros(50)).true_force_N
    assert np.array_equal(a, b) and np.array_equal(b, c) and a[-1] > 0
    assert sim.model.restores == 2


def test_a_plugin_without_snapshot_runs_forward_only_and_is_never_copied(lab_dir,
                                                                         monkeypatch):
    import copy
    monkeypatch.setattr(copy, "deepcopy", lambda *a, **k: pytest.fail("deep-copied"))
    p = plugin_participant("labmodel_x:make")
    p = PluginParticipant(p.spec, p.factory, sensor=SensorModel.ideal())
    rig = make_sim_rig(p)
    rig.stimulator.connect()
    assert rig.world.sim.forward_only
    force, _ = run_waveform(rig, waveform(np.full(4000, 3.0), np.full(4000, 1.5)))
    a = np.exp(-1.0 / (0.05 * 2000.0))
    assert np.allclose(force, 1.5 * (1 - a ** (np.arange(4000) + 1)), atol=1e-9)
    # never ahead: the model saw exactly the samples handed out, once each
    assert sum(rig.world.sim.model.calls) == rig.world.sim.cursor == rig.world.committed


@pytest.mark.parametrize("spec, words", [
    ("labmodel_x:exits", "called sys.exit(0)"),
    ("labmodel_x:raises", "RuntimeError: no licence"),
])
def test_a_factory_that_exits_or_raises_is_one_line(lab_dir, spec, words):
    with pytest.raises(UserError) as e:
        plugin_participant(spec)
    assert words in str(e.value) and spec in str(e.value) and "\n" not in str(e.value)


def test_template_through_the_plugin_interface_equals_the_builtin():
    fs = 2000.0
    model = template(seed=0, fs_Hz=fs)
    sim = ParticipantSimulator(default_participant(seed=0), fs)
    rng = np.random.default_rng(0)
    for _ in range(3):   # consecutive blocks, state carried over
        I_e = 5.0 + rng.random(300)
        I_f = 4.0 + rng.random(300)
        assert np.array_equal(model.force_N(I_e, I_f), sim.simulate(I_e, I_f).true_force_N)


def test_config_accepts_a_plugin_and_refuses_a_bad_name():
    from nmsid.protocols.config import load_config
    cfg = load_config(None).replace(participant_model="lab.models:make")
    assert cfg.participant_model == "lab.models:make"
    with pytest.raises(UserError, match="package.module:factory"):
        load_config(None).replace(participant_model="lab models")


def test_the_check_when_named_runs_the_plugin_as_the_session_will(lab_dir, monkeypatch):
    """At the session's rate, and through its own snapshot/restore when it has them."""
    monkeypatch.syspath_prepend(str(lab_dir))
    import labmodel_x
    seen = []
    real = labmodel_x.Restorable.restore

    def spy(self, y):
        seen.append(self.a)
        return real(self, y)
    labmodel_x.Restorable.restore = spy
    try:
        plugin_participant("labmodel_x:restorable", fs_Hz=500.0)
    finally:
        labmodel_x.Restorable.restore = real
    assert seen == [pytest.approx(np.exp(-1.0 / (0.05 * 500.0)))]
