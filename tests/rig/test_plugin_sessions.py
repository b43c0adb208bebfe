"""Plug-in participants the rig never copies (issue 36): a model holding a module, a lock
or an FMPy FMU instance runs a whole session forward only; an E-stop mid-trial ends with
output at zero; a plug-in that raises or exits ends the session in one line, output zero,
exit non-zero; a resume imports no module its command did not name."""

import json
import os
import shutil
import sys
import textwrap

import numpy as np
import pytest

from nmsid.cli import main
from nmsid.protocols.config import load_config
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import Engine, TripPolicy
from nmsid.sim_backends import Fault, FaultKind, make_sim_rig
from nmsid.sim_backends.plugin import plugin_participant

NONCOPY = """
import os
import sys
import threading

import numpy as np

made = []


class Lag:
    def __init__(self, fs_Hz):
        self.a = np.exp(-1.0 / (0.02 * fs_Hz))
        self.y = 0.0
        made.append(self)

    def _run(self, I_e, I_f):
        u = np.maximum(I_e - 2.0, 0) - np.maximum(I_f - 1.5, 0)
        out = np.empty(len(u))
        for k, uk in enumerate(u):
            self.y = self.a * self.y + (1 - self.a) * uk
            out[k] = self.y
        return out


class WithModule(Lag):
    def __init__(self, fs_Hz):
        super().__init__(fs_Hz)
        self.np = np                      # a module handle: cannot be deep-copied

    def force_N(self, I_e, I_f):
        return self._run(I_e, I_f)


class WithLock(Lag):
    def __init__(self, fs_Hz):
        super().__init__(fs_Hz)
        self.lock = threading.Lock()      # cannot be deep-copied

    def force_N(self, I_e, I_f):
        with self.lock:
            return self._run(I_e, I_f)


class FailsInSession(WithModule):
    '''Every model after the first (the check when it is named) fails on stimulation
    while the file 'boom' exists: by raising, or by sys.exit(0) with 'boom' = 'exit'.'''

    def force_N(self, I_e, I_f):
        if len(made) > 1 and os.path.exists("boom") and (I_e > 0).any():
            if open("boom").read() == "exit":
                sys.exit(0)
            raise RuntimeError("the solver diverged")
        return self._run(I_e, I_f)


def with_module(seed, fs_Hz):
    return WithModule(fs_Hz)


def with_lock(seed, fs_Hz):
    return WithLock(fs_Hz)


def fails(seed, fs_Hz):
    return FailsInSession(fs_Hz)
"""
CONFIG = """
participant = "P01"
seed = 3
[protocol]
sE_levels = [0.4, 0.7]
repeats = 1
steady_s = 0.4
chirp_s = 0.6
[calibration.manual]
Iemin_mA = 2.0
Iemax_mA = 9.5
Ifmin_mA = 1.5
Ifmax_mA = 8.0
"""


@pytest.fixture
def lab(tmp_path, monkeypatch):
    (tmp_path / "noncopy_lab.py").write_text(textwrap.dedent(NONCOPY), encoding="utf-8")
    (tmp_path / "p.toml").write_text(CONFIG, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    yield tmp_path
    sys.modules.pop("noncopy_lab", None)


def _engine_session(tmp_path, participant, faults=()):
    rig = make_sim_rig(participant, faults=list(faults))
    cfg = load_config(tmp_path / "p.toml").with_protocol(rest_s=0.0)
    eng = Engine(cfg, rig, tmp_path / f"s{len(list(tmp_path.glob('s*.h5')))}.h5",
                 trip_policy=TripPolicy.END_SESSION)
    return rig, eng.path, eng.run()


def _estop_ends_at_zero(rig, summary):
    assert summary.trip is not None and summary.trip.rule == "estop"
    assert any(z.reason == "stop_now" for z in rig.output_zero_events)
    stop = [z for z in rig.output_zero_events if z.reason == "stop_now"][0].sample_index
    I_e, I_f, _ = rig.world.output(stop, stop + 2000)
    assert not I_e.any() and not I_f.any()


@pytest.mark.parametrize("spec", ["noncopy_lab:with_module", "noncopy_lab:with_lock"])
def test_a_non_copyable_plugin_runs_a_session_and_an_estop_ends_at_zero(lab, spec):
    p = plugin_participant(spec, seed=1)
    rig, path, summary = _engine_session(lab, p)
    assert rig.world.sim.forward_only
    assert summary.n_completed == 2 and validate_session(path) == []
    assert np.abs(read_session(path).trials[0].force_N).max() > 0.1
    rig, path, summary = _engine_session(lab, plugin_participant(spec, seed=1),
                                         [Fault(FaultKind.ESTOP, trial=1, at_s=0.5)])
    _estop_ends_at_zero(rig, summary)
    assert validate_session(path) == [] and read_session(path).trials[-1].status == "aborted"


@pytest.mark.skipif(shutil.which("cc") is None, reason="exporting an FMU needs a C compiler")
def test_the_twin_fmu_participant_runs_a_session_and_an_estop_ends_at_zero(lab,
                                                                            monkeypatch):
    pytest.importorskip("fmpy")
    from nmsid.export.fmu import export_fmu
    from nmsid.sim_backends.participant import default_participant
    data = default_participant().to_twin()
    data.update(participant="DEMO", source=[{"file": "DEMO.h5", "sha256": "ab" * 32}])
    (lab / "twin.json").write_text(json.dumps(data), encoding="utf-8")
    export_fmu(lab / "twin.json", lab / "DEMO.fmu")
    monkeypatch.setenv("NMSID_TWIN_FMU", str(lab / "DEMO.fmu"))
    spec = "nmsid.sim_backends.fmu_participant:make"
    rig, path, summary = _engine_session(lab, plugin_participant(spec))
    assert rig.world.sim.forward_only
    assert summary.n_completed == 2 and validate_session(path) == []
    assert np.abs(read_session(path).trials[1].force_N).max() > 0.1
    rig, path, summary = _engine_session(lab, plugin_participant(spec),
                                         [Fault(FaultKind.ESTOP, trial=0, at_s=0.5)])
    _estop_ends_at_zero(rig, summary)


@pytest.mark.parametrize("how, words", [("raise", "RuntimeError: the solver diverged"),
                                        ("exit", "called sys.exit(0)")])
def test_a_plugin_failing_mid_session_is_one_line_output_zero_exit_non_zero(lab, capsys,
                                                                            how, words):
    (lab / "boom").write_text(how)
    code = main(["run", "--backend", "sim", "--config", "p.toml", "--participant-model",
                 "noncopy_lab:fails", "--out", "f.h5", "--no-identify"])
    out, err = capsys.readouterr()
    assert code == 4, out + err
    trip = [ln for ln in out.splitlines() if ln.startswith("[interlock_trip]")]
    assert len(trip) == 1 and words in trip[0] and "noncopy_lab:fails" in trip[0]
    assert "Traceback" not in out + err
    assert validate_session("f.h5") == []


def test_a_resume_imports_only_the_plugin_its_command_names(lab, capsys):
    (lab / "boom").write_text("raise")
    assert main(["run", "--backend", "sim", "--config", "p.toml", "--participant-model",
                 "noncopy_lab:fails", "--out", "r.h5", "--no-identify", "--quiet"]) == 4
    os.remove(lab / "boom")
    sys.modules.pop("noncopy_lab", None)
    # the module now leaves a mark when imported
    src = (lab / "noncopy_lab.py").read_text()
    (lab / "noncopy_lab.py").write_text("open('imported', 'w').close()\n" + src)
    capsys.readouterr()
    assert main(["run", "--backend", "sim", "--resume", "r.h5", "--no-identify"]) == 2
    err = capsys.readouterr().err
    assert "--participant-model noncopy_lab:fails" in err and len(err.splitlines()) == 1
    assert not (lab / "imported").exists() and "noncopy_lab" not in sys.modules
    assert main(["run", "--backend", "sim", "--resume", "r.h5", "--participant-model",
                 "noncopy_lab:with_lock", "--no-identify"]) == 2
    assert "not --participant-model 'noncopy_lab:with_lock'" in capsys.readouterr().err
    assert not (lab / "imported").exists()
    assert main(["run", "--backend", "sim", "--resume", "r.h5", "--participant-model",
                 "noncopy_lab:fails", "--no-identify", "--quiet"]) == 0
    assert (lab / "imported").exists()
    s = read_session("r.h5")
    assert sum(t.completed for t in s.trials) == 2 and validate_session("r.h5") == []


def test_a_settings_file_naming_a_plugin_imports_nothing_the_command_did_not_name(lab,
                                                                                 capsys):
    src = (lab / "noncopy_lab.py").read_text()
    (lab / "noncopy_lab.py").write_text("open('imported', 'w').close()\n" + src)
    (lab / "q.toml").write_text(CONFIG.replace('participant = "P01"\n', "")
                                + '[participant]\ncode = "P01"\n'
                                  'model = "noncopy_lab:with_lock"\n', encoding="utf-8")
    assert main(["run", "--backend", "sim", "--config", "q.toml", "--out", "q.h5",
                 "--no-identify"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "q.toml" in err
    assert "--participant-model noncopy_lab:with_lock" in err
    assert not (lab / "imported").exists() and "noncopy_lab" not in sys.modules
    assert not (lab / "q.h5").exists()
    # named in the command too: imported and run
    assert main(["run", "--backend", "sim", "--config", "q.toml", "--participant-model",
                 "noncopy_lab:with_lock", "--out", "q.h5", "--no-identify", "--quiet"]) == 0
    assert (lab / "imported").exists() and validate_session("q.h5") == []


@pytest.mark.parametrize("factory", ["make_with_module", "make_with_lock"])
def test_non_copyable_plugins_run_calibration_identify_design_and_tracking(
        tmp_path, monkeypatch, factory):
    """The whole chain of tests/rig/test_tracking_e2e.py with a plug-in that holds a module
    handle or a lock (neither can be deep-copied): ramps, an identification session,
    identify, control design, a tracking session (streamed updates, forward only)."""
    from tests.rig.test_tracking_e2e import CONFIG as E2E_CONFIG
    from tests.rig.test_tracking_e2e import LAB_PARTICIPANT
    extra = '''

import threading


class ElbowWithModule(Elbow):
    def __init__(self, seed, fs_Hz):
        super().__init__(seed, fs_Hz)
        self.np = np


class ElbowWithLock(Elbow):
    def __init__(self, seed, fs_Hz):
        super().__init__(seed, fs_Hz)
        self.lock = threading.Lock()

    def force_N(self, I_ext_mA, I_flex_mA):
        with self.lock:
            return super().force_N(I_ext_mA, I_flex_mA)


def make_with_module(seed, fs_Hz):
    return ElbowWithModule(seed, fs_Hz)


def make_with_lock(seed, fs_Hz):
    return ElbowWithLock(seed, fs_Hz)
'''
    (tmp_path / "lab_noncopy.py").write_text(textwrap.dedent(LAB_PARTICIPANT) + extra,
                                             encoding="utf-8")
    (tmp_path / "short.toml").write_text(E2E_CONFIG, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    try:
        sim = ["--backend", "sim", "--participant-model", f"lab_noncopy:{factory}",
               "--config", "short.toml", "--quiet"]
        assert main(["run", *sim, "--out", "id.h5", "--no-identify"]) == 0
        s = read_session("id.h5", load_data=False)
        assert s.calibration.Iemin_mA > 0 and len(s.trials) == 5
        assert main(["identify", "id.h5", "--out", "ana", "--no-figures"]) == 0
        assert main(["control", "design", "ana/twin.json", "--out", "ctl"]) == 0
        assert main(["run", *sim, "--track", "ctl/controller.json", "--out", "track.h5"]) == 0
        assert validate_session("track.h5") == []
        trials = read_session("track.h5").trials
        assert trials[0].extra_attrs["controller"] == "relay" and all(t.completed
                                                                      for t in trials)
    finally:
        sys.modules.pop("lab_noncopy", None)


@pytest.mark.skipif(shutil.which("cc") is None, reason="exporting an FMU needs a C compiler")
def test_the_twin_fmu_plugin_runs_identify_design_and_tracking(tmp_path, monkeypatch):
    """The same chain with the shipped FMPy participant (a twin's exported FMU, which
    cannot be copied): an identification session (manual calibration: the FMU maps rE and
    sE to force, it has no recruitment threshold for the ramps to find), identify, control
    design and a tracking session, forward only."""
    pytest.importorskip("fmpy")
    from nmsid.export.fmu import export_fmu
    from nmsid.sim_backends.participant import default_participant
    from tests.rig.test_tracking_e2e import CONFIG as E2E_CONFIG
    data = default_participant().to_twin()
    data.update(participant="DEMO", source=[{"file": "DEMO.h5", "sha256": "ab" * 32}])
    (tmp_path / "twin.json").write_text(json.dumps(data), encoding="utf-8")
    export_fmu(tmp_path / "twin.json", tmp_path / "DEMO.fmu")
    monkeypatch.setenv("NMSID_TWIN_FMU", str(tmp_path / "DEMO.fmu"))
    manual = "\n[calibration.manual]\nIemin_mA = 2.0\nIemax_mA = 9.5\nIfmin_mA = 1.5\n" \
             "Ifmax_mA = 8.0\n"
    config = E2E_CONFIG.split("[calibration]")[0] + manual
    (tmp_path / "short.toml").write_text(config, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    sim = ["--backend", "sim", "--participant-model", "nmsid.sim_backends.fmu_participant:make",
           "--config", "short.toml", "--quiet"]
    assert main(["run", *sim, "--out", "id.h5", "--no-identify"]) == 0
    assert validate_session("id.h5") == [] and len(read_session("id.h5").trials) == 5
    assert main(["identify", "id.h5", "--out", "ana", "--no-figures"]) == 0
    assert main(["control", "design", "ana/twin.json", "--out", "ctl"]) == 0
    assert main(["run", *sim, "--track", "ctl/controller.json", "--out", "track.h5"]) == 0
    assert validate_session("track.h5") == []
    trials = read_session("track.h5").trials
    assert trials[0].extra_attrs["controller"] == "relay" and all(t.completed for t in trials)
