"""The GUI shows each completed trial's QC verdict and offers to repeat an excluded one."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lsim

from nmsid.protocols.schedule import PlannedTrial, TrialStatus
from nmsid.protocols.session_file import Trial
from nmsid.rig.gui import analysis_hooks
from nmsid.rig.gui.schedule_panel import COLUMNS, SchedulePanel

FS = 2000.0


def level_trials(contaminated: int | None = None, n: int = 3) -> dict[int, Trial]:
    rng = np.random.default_rng(5)
    t = np.arange(int(8 * FS)) / FS
    tc = np.clip(t - 2, 0, None)
    r = np.where(t < 2, 0.5, 0.5 + 0.5 * np.sin(2 * np.pi * 6 / math.log(10)
                                                 * (10 ** (tc / 6) - 1)))
    _, y, _ = lsim(([5 * 400.0], [1, 2 * 0.5 * 20, 400.0]), r - 0.5, t)
    out = {}
    for k in range(n):
        f = y + rng.normal(0, 0.02, t.size) + rng.uniform(-1, 1)
        if k == contaminated:
            f = f + 3.0 * np.where((t > 4) & (t < 5.5), np.sin(np.pi * (t - 4) / 1.5) ** 2, 0)
        out[k * 2] = Trial(sE=0.5, repeat=k + 1, fs_Hz=FS, rE=r, I_ext_mA=0 * r + 3,
                           I_flex_mA=0 * r + 3, force_N=f, steady_s=2.0, chirp_s=6.0,
                           name=f"t{k:03d}")
    return out


def test_trial_verdicts_name_the_contaminated_repeat():
    verdicts = analysis_hooks.trial_verdicts(level_trials(contaminated=1))
    assert verdicts[2][0] == "excluded" and "not explained by rE" in verdicts[2][1]
    assert "[3.9-5.6 s]" in verdicts[2][1]  # where, in s
    assert verdicts[0][0] == verdicts[4][0] == "used"


def test_schedule_panel_qc_column_and_repeat_button(qtbot):
    asked = []
    panel = SchedulePanel(lambda: None, lambda: None, lambda: None, lambda i: None,
                          on_repeat=asked.append)
    qtbot.addWidget(panel)
    planned = [PlannedTrial(i, 0.5, i + 1, status=TrialStatus.DONE) for i in range(3)]
    panel.set_schedule(planned)
    panel.set_state("resting")
    assert not panel.repeat_button.isEnabled()
    panel.set_qc(1, "excluded", "response not explained by rE at 4.0-5.5 s")
    panel.set_qc(0, "used", "")
    panel.set_schedule(planned)
    col = COLUMNS.index("QC")
    assert panel.table.item(1, col).text() == "excluded"
    assert "4.0-5.5" in panel.table.item(1, col).toolTip()
    assert panel.table.item(0, col).text() == "used"
    assert panel.repeat_button.isEnabled()
    panel.repeat_button.click()
    assert asked == [1]
    panel.set_state("finished")
    assert not panel.repeat_button.isEnabled()


def test_window_judges_each_finished_trial_and_repeats_on_request(fake_window, monkeypatch,
                                                                  qtbot):
    w = fake_window
    calls = []
    monkeypatch.setattr(w.controller, "repeat_trial", lambda i, why: calls.append((i, why)))
    trials = level_trials(contaminated=2)
    for index, tr in trials.items():
        w._on_trial_finished(index, tr)
    # judged in the QC worker, not in the GUI thread (it held the display back, issue 39)
    qtbot.waitUntil(lambda: w.qc.pending == 0 and 4 in w.schedule_panel.qc, timeout=60_000)
    assert w.schedule_panel.qc[4][0] == "excluded"
    assert w.schedule_panel.qc[0][0] == "used"
    # the trial by its name in the file, not by a count of its own
    assert any(line.startswith("QC: t002 ") for line in w.event_log.lines), w.event_log.lines
    w.schedule_panel.statuses = ["done"] * 5
    w.repeat_excluded()
    assert calls and calls[0][0] == 4 and calls[0][1].startswith("QC excluded it")
