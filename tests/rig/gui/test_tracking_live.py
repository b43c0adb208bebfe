"""The live plots show a tracking trial's target beside the achieved force (issue 28, 4)."""

from __future__ import annotations

import numpy as np

from nmsid.rig.gui.live_buffer import LiveBuffer
from nmsid.rig.gui.observer import QtEngineObserver


def test_the_buffer_keeps_the_target_of_each_chunk_and_forgets_it_at_a_new_trial():
    buf = LiveBuffer(window_s=1.0, fs_Hz=10.0)
    buf.start_trial(3)
    z = np.zeros(6)
    buf.append(3, 0, np.arange(6.0), z, z, z)
    buf.set_target(3, 0, np.full(6, 2.5))
    buf.append(3, 6, np.arange(6.0, 12.0), z, z, z)     # wraps the 10-sample window
    buf.set_target(3, 6, np.linspace(3.0, 4.0, 6))
    snap = buf.snapshot()
    assert snap.n == 10 and snap.target_N is not None
    assert np.allclose(snap.target_N, np.r_[np.full(4, 2.5), np.linspace(3.0, 4.0, 6)])
    assert np.allclose(snap.force_N, np.arange(2.0, 12.0))
    buf.set_target(2, 6, np.ones(6))        # another trial's target: ignored
    assert np.allclose(buf.snapshot().target_N[-1], 4.0)
    buf.start_trial(4)                      # an identification trial: no target
    buf.append(4, 0, z, z, z, z)
    assert buf.snapshot().target_N is None


def test_the_force_plot_draws_the_target_only_during_tracking(qtbot):
    from nmsid.rig.gui.live_plots import LivePlots  # noqa: PLC0415 (Qt)
    buf = LiveBuffer(window_s=1.0, fs_Hz=100.0)
    plots = LivePlots(buf)
    qtbot.addWidget(plots)
    z = np.zeros(50)
    buf.start_trial(0)
    buf.append(0, 0, np.linspace(0, 5, 50), z, z, z)
    buf.set_target(0, 0, np.full(50, 4.0))
    plots.draw(buf.snapshot())
    _, y = plots.target_curve.getData()
    assert y is not None and len(y) == 50 and np.allclose(y, 4.0)
    buf.start_trial(1)
    buf.append(1, 0, z, z, z, z)
    plots.draw(buf.snapshot())
    _, y = plots.target_curve.getData()
    assert y is None or len(y) == 0


def test_the_gui_observer_passes_the_target_to_its_buffer():
    obs = QtEngineObserver.__new__(QtEngineObserver)   # the buffer path needs no Qt
    obs.buffer = LiveBuffer(window_s=5.0, fs_Hz=2000.0)
    obs.buffer.start_trial(0)
    obs.on_chunk(0, 0, np.ones(8), np.zeros(8), np.zeros(8), np.zeros(8))
    obs.on_target(0, 0, np.full(8, 1.5))
    assert np.allclose(obs.buffer.snapshot().target_N, 1.5)
