"""The GUI lists the LSL streams it sees and records the ones the operator ticks (issue 43
item 4), into the session file as ``--lsl-record`` does; off by default, and off with the
reason shown when pylsl is absent.

LSL stays on this machine: tests/conftest.py's session fixture points ``LSLAPICFG`` at a
configuration with ``ResolveScope = machine`` and IPv6 off before pylsl is imported.
"""

from __future__ import annotations

import dataclasses
import os
import threading

import h5py
import pytest

from nmsid.rig.gui.lsl_panel import NO_PYLSL, OFF_TEXT, LslPanel, StreamRow

STREAM = f"test-EMG-{os.getpid()}"


def test_lsl_is_kept_on_this_machine_here():
    text = open(os.environ["LSLAPICFG"], encoding="utf-8").read()
    assert "ResolveScope = machine" in text and "IPv6 = disable" in text


def test_panel_is_off_with_the_reason_when_pylsl_is_absent(qtbot):
    panel = LslPanel(resolve=lambda: [StreamRow("EMG", "EMG", 8, 2000.0, "amp-1")],
                     available=False)
    qtbot.addWidget(panel)
    panel.set_on(True)
    panel.set_wanted(["EMG"])
    assert panel.status.text() == NO_PYLSL
    assert not panel.enabled.isEnabled() and not panel.enabled.isChecked()
    assert panel.wanted() == []           # nothing recorded without pylsl
    panel.shutdown()


def test_panel_is_off_by_default_and_lists_nothing(qtbot):
    calls = []
    panel = LslPanel(resolve=lambda: calls.append(1) or [], available=True)
    qtbot.addWidget(panel)
    assert not panel.enabled.isChecked()
    assert panel.status.text() == OFF_TEXT
    panel.refresh()
    qtbot.wait(100)
    assert calls == [] and panel.table.rowCount() == 0 and panel.wanted() == []
    panel.shutdown()


def test_a_failing_look_is_shown_not_raised(qtbot):
    def resolve():
        raise OSError("no network")
    panel = LslPanel(resolve=resolve, available=True)
    qtbot.addWidget(panel)
    panel.set_on(True)
    qtbot.waitUntil(lambda: panel.n_looks == 1, timeout=10_000)
    assert "could not be listed" in panel.status.text() and "no network" in \
        panel.status.text()
    panel.shutdown()


@pytest.fixture
def emg_outlet():
    """A local EMG outlet (this machine only) pushing samples until the test ends."""
    pylsl = pytest.importorskip("pylsl")
    info = pylsl.StreamInfo(STREAM, "EMG", 2, 500.0, pylsl.cf_float32, f"{STREAM}-src")
    outlet = pylsl.StreamOutlet(info)
    stop = threading.Event()

    def push():
        while not stop.is_set():
            outlet.push_chunk([[0.1, -0.1]] * 10)
            stop.wait(0.02)
    th = threading.Thread(target=push, daemon=True)
    th.start()
    yield outlet
    stop.set()
    th.join(2.0)


def test_panel_lists_a_local_outlet_and_the_tick_feeds_lsl_record(qtbot, tmp_path,
                                                                  emg_outlet):
    from PySide6.QtCore import Qt

    from nmsid.rig.gui.setup_panel import SetupPanel
    panel = SetupPanel(on_start=lambda req: None)
    qtbot.addWidget(panel)
    lsl = panel.lsl
    assert lsl.available
    lsl.set_on(True)

    def seen():
        if not any(r.name == STREAM for r in lsl.rows):
            lsl.refresh()         # a look may have come before the outlet was visible
            return False
        return True
    qtbot.waitUntil(seen, timeout=30_000)
    row = next(i for i, r in enumerate(lsl.rows) if r.name == STREAM)
    cells = [lsl.table.item(row, c).text() for c in range(lsl.table.columnCount())]
    assert cells == ["record", STREAM, "EMG", "2", "500", f"{STREAM}-src"]
    assert lsl.table.item(row, 0).flags() & Qt.ItemFlag.ItemIsUserCheckable
    panel.set_values(participant="L01", output=tmp_path / "L01.h5")
    assert panel.request().lsl_record == ()       # listed, not ticked: not recorded
    lsl.table.item(row, 0).setCheckState(Qt.CheckState.Checked)   # the operator's tick
    assert panel.request().lsl_record == (STREAM,)
    lsl.enabled.setChecked(False)                 # LSL off: nothing recorded
    assert panel.request().lsl_record == ()
    lsl.shutdown()


def test_gui_session_records_the_ticked_stream_into_the_file(qtbot, tmp_path, emg_outlet):
    """The ticked stream goes into the session file under /lsl (the recorder of
    ``nmsid run --lsl-record``), with its clock offsets."""
    from nmsid.rig.gui.main_window import MainWindow
    from nmsid.rig.gui.results_panel import SelectionView

    def short(cfg):
        p = dataclasses.replace(cfg.protocol, sE_levels=(0.5,), repeats=1, steady_s=0.2,
                                chirp_s=1.0, rest_s=0.0)
        return cfg.replace(protocol=p)
    class _LevelResult:  # stands in for the per-level identification
        def __init__(self, trials):
            self.Kp, self.wn_rad_s, self.zeta, self.fit_pct = 2.0, 10.0, 0.5, 90.0
    w = MainWindow(config_transform=short, identify=_LevelResult,
                   select_models=lambda path: SelectionView([], note="skipped"))
    qtbot.addWidget(w)
    w.show()
    try:
        out = tmp_path / "L02.h5"
        w.start_session(participant="L02", output=out, backend="sim", seed=2,
                        realtime=False, lsl_record=[STREAM])
        assert w.controller.request.lsl_record == (STREAM,)
        qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled()
                        or w.run_error is not None, timeout=60_000)
        w.confirm_calibration()
        qtbot.waitUntil(lambda: w.run_result is not None or w.run_error is not None,
                        timeout=120_000)
        assert w.run_error is None
        with h5py.File(out, "r") as f:
            runs = list(f["lsl"])
            assert len(runs) == 1
            g = f["lsl"][runs[0]][STREAM]
            assert g.attrs["type"] == "EMG" and g["time_series"].shape[1] == 2
            assert g["time_series"].shape[0] > 0
            assert g["clock_offsets_s"].shape[0] >= 1
    finally:
        w.controller.shutdown(timeout_s=5.0)
        w.setup_panel.lsl.shutdown()
        w.close()


def test_nmsids_own_outlets_are_listed_but_cannot_be_ticked(qtbot):
    from PySide6.QtCore import Qt
    rows = [StreamRow("nmsid Force", "Force", 1, 2000.0, "nmsid-P01-force"),
            StreamRow("EMG", "EMG", 8, 2000.0, "amp-1")]
    panel = LslPanel(resolve=lambda: rows, available=True)
    qtbot.addWidget(panel)
    panel.set_on(True)
    qtbot.waitUntil(lambda: panel.table.rowCount() == 2, timeout=10_000)
    assert not panel.table.item(0, 0).flags() & Qt.ItemFlag.ItemIsUserCheckable
    assert panel.table.item(1, 0).flags() & Qt.ItemFlag.ItemIsUserCheckable
    assert "1 can be recorded" in panel.status.text()
    panel.shutdown()
