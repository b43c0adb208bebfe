"""Shared fixtures for the GUI tests: offscreen Qt, short protocols, window builders."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import pytest  # noqa: E402

HERE = Path(__file__).resolve().parent


def _load_fake_engine():
    spec = importlib.util.spec_from_file_location("gui_fake_engine", HERE / "fake_engine.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["gui_fake_engine"] = module
    spec.loader.exec_module(module)
    return module


fake_engine = _load_fake_engine()

#: A GUI test that hangs (a deadlock between the Qt thread and a worker, an event that never
#: comes) fails after this long instead of stalling the run. ``thread``: pytest-timeout
#: dumps every thread's stack (where it hung) and ends the process; the ``signal`` method
#: cannot interrupt a main thread blocked inside Qt. The slowest GUI test takes ~15 s alone.
GUI_TEST_TIMEOUT_S = 180


def pytest_collection_modifyitems(config, items):
    for item in items:
        if HERE in Path(str(item.path)).resolve().parents and \
                item.get_closest_marker("timeout") is None:
            item.add_marker(pytest.mark.timeout(GUI_TEST_TIMEOUT_S, method="thread"))


class FakeLevelResult:
    def __init__(self, sE):
        self.Kp, self.wn_rad_s, self.zeta, self.fit_pct = 2 * sE, 10 + sE, 0.5, 90.0


def fake_identify(trials):
    return FakeLevelResult(float(trials[0].sE))


def no_model_selection(session_path):
    """Stand-in for the end-of-session model selection (tested on its own)."""
    from nmsid.rig.gui.results_panel import SelectionView
    return SelectionView([], note="model selection skipped in this test")


def short_config(cfg, levels=(0.4, 0.6), repeats=1, steady_s=0.2, chirp_s=1.0, rest_s=0.0):
    """A shortened protocol: few levels, short chirp, no rest."""
    import dataclasses
    p = dataclasses.replace(cfg.protocol, sE_levels=tuple(levels), repeats=repeats,
                            steady_s=steady_s, chirp_s=chirp_s, rest_s=rest_s)
    return cfg.replace(protocol=p)


@pytest.fixture
def fake_window(qtbot):
    """A window over the fake engine (no devices) with fake identification."""
    from nmsid.rig.gui.main_window import MainWindow

    w = MainWindow(devices_factory=lambda req, cfg: _NoDevices(),
                   engine_factory=fake_engine.FakeEngine,
                   config_transform=short_config, identify=fake_identify,
                   select_models=no_model_selection)
    qtbot.addWidget(w)
    w.show()
    yield w
    w.controller.shutdown(timeout_s=2.0)


class _NoDevices:
    class stimulator:  # noqa: N801
        @staticmethod
        def stop_now():
            pass

    def close(self):
        pass


def sim_short_config(cfg):
    """The real protocol, shortened for a real-time simulated session of ~15 s."""
    import dataclasses
    p = dataclasses.replace(cfg.protocol, sE_levels=(0.4, 0.7), repeats=2, steady_s=0.5,
                            chirp_s=1.2, rest_s=0.1)
    c = dataclasses.replace(cfg.calibration, hold_s=0.15, baseline_s=0.2, step_mA=1.0)
    return cfg.replace(protocol=p, calibration=c)


def _sim_window(qtbot, realtime: bool, config_transform, select_models=None, faults=None):
    from nmsid.rig.gui.main_window import MainWindow
    from nmsid.sim_backends.rig import make_sim_rig

    rigs = []

    def devices(request, config):
        rig = make_sim_rig(realtime=realtime, seed=request.seed or 0,
                           fs_Hz=config.protocol.fs_Hz, faults=faults)
        rigs.append(rig)
        return rig

    w = MainWindow(devices_factory=devices, config_transform=config_transform,
                   select_models=select_models)
    w.rigs = rigs
    qtbot.addWidget(w)
    w.show()
    return w


@pytest.fixture
def sim_window(qtbot):
    """A window over the real engine and the real-time simulated rig; ``w.rigs`` holds
    the simulated rigs it built (to look inside the simulator)."""
    w = _sim_window(qtbot, True, sim_short_config, select_models=no_model_selection)
    yield w
    w.controller.shutdown(timeout_s=5.0)
    w.results.shutdown(wait=True)


def sim_levels_config(cfg):
    """Six sE levels, one repeat each (enough points for AICc model selection)."""
    import dataclasses
    p = dataclasses.replace(cfg.protocol, sE_levels=(0.3, 0.45, 0.6, 0.75, 0.9, 1.0),
                            repeats=1, steady_s=1.0, chirp_s=4.0, rest_s=0.0)
    return cfg.replace(protocol=p)


@pytest.fixture
def fast_sim_window(qtbot):
    """A window over the real engine and the simulated rig on its fast clock, with a
    100 N force spike 1 s into the second trial (the force-limit rule must trip)."""
    from nmsid.sim_backends.faults import Fault, FaultKind
    spike = Fault(FaultKind.FORCE_SPIKE, trial=1, at_s=1.0, amplitude_N=100.0)
    w = _sim_window(qtbot, False, sim_levels_config, faults=[spike])
    yield w
    w.controller.shutdown(timeout_s=5.0)
    w.identification.shutdown()
    w.results.shutdown(wait=True)


def sim_manual_config(cfg):
    """:func:`sim_short_config` with the four currents entered by hand (no ramps)."""
    import dataclasses

    from nmsid.protocols.config import ManualCurrents
    cfg = sim_short_config(cfg)
    c = dataclasses.replace(cfg.calibration, manual=ManualCurrents(2.0, 9.0, 1.0, 8.0))
    return cfg.replace(calibration=c)


@pytest.fixture
def sim_window_manual(qtbot):
    """As ``sim_window``, with hand-entered calibration currents."""
    w = _sim_window(qtbot, True, sim_manual_config, select_models=no_model_selection)
    yield w
    w.controller.shutdown(timeout_s=5.0)
    w.results.shutdown(wait=True)


@pytest.fixture
def make_sim_window(qtbot):
    """``make_sim_window(config_transform, realtime=False, faults=None)`` -> a window over
    the real engine and the simulator, closed after the test."""
    made = []

    def make(config_transform=sim_levels_config, realtime=False, faults=None):
        w = _sim_window(qtbot, realtime, config_transform, select_models=no_model_selection,
                        faults=faults)
        made.append(w)
        return w
    yield make
    for w in made:
        w.controller.shutdown(timeout_s=5.0)
        w.results.shutdown(wait=True)
