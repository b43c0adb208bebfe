"""The GUI takes its labels, units and limits from the session's joint (issue 41), chosen
on the set-up panel as ``nmsid run --joint`` does; a simulated knee session on the template
leg participant (the session service, as the CLI) shows torque in N m and the knee's
muscle groups; trials are named as in the file (issue 39 item 6)."""

from __future__ import annotations

import dataclasses

import pytest

from nmsid.protocols.joints import JOINTS
from nmsid.protocols.session_file import read_session
from nmsid.rig.gui.setup_panel import SetupPanel


def test_setup_panel_joint_selector_feeds_the_request(qtbot, tmp_path):
    got = []
    panel = SetupPanel(on_start=got.append)
    qtbot.addWidget(panel)
    names = [panel.joint.itemData(i) for i in range(panel.joint.count())]
    assert names == [None, *JOINTS]          # the configuration's, then every joint
    panel.set_values(participant="J01", output=tmp_path / "J01.h5")
    assert panel.request().joint is None     # the configuration decides (elbow default)
    panel.set_values(joint="ankle")
    assert panel.request().joint == "ankle"
    assert "triceps surae" in panel.joint.currentText()
    assert "torque (N m)" in panel.joint.currentText()


def test_joint_reaches_the_configuration_as_the_cli_flag_does(tmp_path):
    from nmsid.rig.gui.session_controller import load_session_config
    from nmsid.rig.gui.setup_panel import Backend, SessionRequest
    req = SessionRequest("J02", Backend.SIM, tmp_path / "J02.h5", joint="knee")
    cfg = load_session_config(req)
    assert cfg.joint == "knee"
    # the knee's default limits, not the elbow's 25 N (protocols/joints.py)
    assert cfg.calibration.Fmax_N == JOINTS["knee"].Fmax
    plain = load_session_config(dataclasses.replace(req, joint=None))
    assert plain.joint == "elbow" and plain.calibration.Fmax_N == JOINTS["elbow"].Fmax


class _LevelResult:
    """Stands in for the per-level identification (tested on its own)."""

    def __init__(self, trials):
        self.Kp, self.wn_rad_s, self.zeta, self.fit_pct = 20.0, 10.0, 0.5, 90.0


def _knee_short(cfg):
    p = dataclasses.replace(cfg.protocol, sE_levels=(0.5,), repeats=1, steady_s=0.2,
                            chirp_s=1.0, rest_s=0.0)
    return cfg.replace(protocol=p)


def test_knee_session_shows_torque_in_newton_metres_and_the_knees_muscles(qtbot, tmp_path):
    from nmsid.rig.gui.main_window import MainWindow
    from nmsid.rig.gui.results_panel import SelectionView
    w = MainWindow(config_transform=_knee_short, identify=_LevelResult,
                   select_models=lambda path: SelectionView([], note="skipped"))
    qtbot.addWidget(w)
    w.show()
    try:
        out = tmp_path / "K01.h5"
        w.start_session(participant="K01", output=out, backend="sim", seed=3,
                        realtime=False, joint="knee")
        assert w.controller.engine is not None, w.setup_panel.message.text()
        assert w.joint.name == "knee"
        knee = JOINTS["knee"]
        # the live plot's axis, the large readouts, the calibration plot and form
        assert w.live.force_plot.getAxis("left").labelText == "torque (N m)"
        assert w.live.readouts.names["force"].text() == "torque (N m)"
        assert w.live.readouts.names["I_ext"].text() == "quadriceps (mA)"
        assert w.live.readouts.names["I_flex"].text() == "hamstrings (mA)"
        assert "N m" in w.calibration_panel.plot.getAxis("left").labelText
        assert "quadriceps" in w.calibration_panel.field_labels["Iemin_mA"].text()
        assert "hamstrings" in w.calibration_panel.field_labels["Ifmax_mA"].text()
        assert w.identification.plots["Kp"].getAxis("left").labelText == "Kp (N m)"
        # the knee's thresholds on the calibration plot (5 / 50 N m), not the elbow's
        assert w.calibration_panel.force_lines["ext_Fmax"].value() == knee.Fmax
        assert w.calibration_panel.force_lines["flex_Fmin"].value() == -knee.Fmin
        qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled()
                        or w.run_error is not None, timeout=60_000)
        assert w.run_error is None
        w.confirm_calibration()
        qtbot.waitUntil(lambda: w.run_result is not None or w.run_error is not None,
                        timeout=120_000)
        assert w.run_error is None
        s = read_session(out, load_data=False)
        assert s.attrs.get("joint") == "knee"
        qtbot.waitUntil(lambda: w.identification.pending == 0, timeout=30_000)
        assert "Kp = 20 N m," in w.identification.status.text()
        # one trial numbering: the file's name in the schedule, the title and the badge
        name = s.trials[0].name
        assert w.schedule_panel.table.item(0, 0).text() == name
        assert w.live.title.text().startswith(f"{name}:")
        assert w.safety.trial_name == name
    finally:
        w.controller.shutdown(timeout_s=5.0)
        w.close()


def test_state_badge_names_the_running_trial_as_the_file_does(qtbot):
    from nmsid.rig.gui.safety_panel import SafetyPanel
    panel = SafetyPanel(on_estop=lambda: None, on_rearm=lambda: None)
    qtbot.addWidget(panel)
    panel.set_state("stimulating")
    panel.set_trial("t004")
    assert panel.state_label.text() == "STIMULATING t004"
    panel.set_state("resting")
    assert panel.state_label.text() == "RESTING t004"
    panel.set_state("paused")
    assert panel.state_label.text() == "PAUSED"


@pytest.mark.parametrize("name", list(JOINTS))
def test_every_joints_labels_reach_the_panels(qtbot, name):
    """Each registered joint's muscle groups, quantity and unit (protocols/joints.py) on
    the live plot, the readouts, the calibration plot and form and Kp's axis."""
    from nmsid.rig.gui.calibration_panel import CalibrationPanel
    from nmsid.rig.gui.identification_panel import IdentificationPanel
    from nmsid.rig.gui.live_buffer import LiveBuffer
    from nmsid.rig.gui.live_plots import LivePlots
    j = JOINTS[name]
    live = LivePlots(LiveBuffer(window_s=1.0, fs_Hz=100.0))
    cal = CalibrationPanel(on_confirm=lambda c: None)
    ident = IdentificationPanel(identify=None)
    for widget in (live, cal, ident):
        qtbot.addWidget(widget)
    live.timer.stop()
    for panel in (live, cal, ident):
        panel.set_joint(j)
    assert live.force_plot.getAxis("left").labelText == j.quantity_label
    assert live.readouts.names["force"].text() == j.quantity_label
    assert live.readouts.names["I_ext"].text() == f"{j.extensor_muscles} (mA)"
    assert live.readouts.names["I_flex"].text() == f"{j.flexor_muscles} (mA)"
    legend = {item.text for _, item in live.i_plot.legend.items}
    assert legend == {j.extensor_muscles, j.flexor_muscles}
    assert cal.plot.getAxis("left").labelText == f"{j.quantity}, muscle alone ({j.unit})"
    assert j.extensor_muscles in cal.field_labels["Iemax_mA"].text()
    assert j.flexor_muscles in cal.field_labels["Ifmin_mA"].text()
    cal_legend = {item.text for _, item in cal.plot.getPlotItem().legend.items}
    assert any(j.flexor_muscles in t for t in cal_legend)
    assert ident.plots["Kp"].getAxis("left").labelText == f"Kp ({j.unit})"
    ident.shutdown()


def test_nmsid_gui_joint_option_fills_the_form(qtbot, tmp_path):
    """``nmsid gui --joint knee`` selects the knee on the set-up panel."""
    from nmsid.cli import build_parser
    from nmsid.rig.gui.app import GuiOptions, build_window
    args = build_parser().parse_args(["gui", "--joint", "knee"])
    assert args.joint == "knee"
    w = build_window(GuiOptions(joint=args.joint, participant="K02",
                                out=tmp_path / "K02.h5"))
    qtbot.addWidget(w)
    assert w.setup_panel.request().joint == "knee"
    w.close()


def test_setup_panel_lists_the_built_in_participants_for_the_simulator(qtbot, tmp_path):
    """The Simulated participant selector: the configuration's, then every built-in model
    of the one registry (no plug-in), sim only; it feeds the request as
    ``--participant-model`` does, and an untyped code follows it (MK01, not P01)."""
    from nmsid.protocols.config import PARTICIPANT_MODELS
    from nmsid.rig.errors import RequestError
    panel = SetupPanel(on_start=lambda r: None)
    qtbot.addWidget(panel)
    box = panel.participant_model
    assert [box.itemData(i) for i in range(box.count())] == [None, *PARTICIPANT_MODELS]
    panel.set_values(output=tmp_path / "x.h5")
    assert panel.request().participant_model is None and panel.request().participant == "P01"
    panel.set_values(joint="knee", participant_model="musculoskeletal")
    req = panel.request()
    assert req.participant_model == "musculoskeletal" and req.joint == "knee"
    assert req.participant == "MK01"            # as nmsid run without --participant
    panel.set_values(joint="ankle")
    assert panel.request().participant == "MA01"
    panel.set_values(backend="hw")              # a real participant: no simulated one
    assert not box.isEnabled() and panel.request().participant_model is None
    assert panel.request().participant == "P01"
    panel.set_values(backend="sim", participant="S07")   # a code the operator gave stays
    assert box.isEnabled() and panel.request().participant == "S07"
    with pytest.raises(RequestError, match="nmsid run --participant-model"):
        panel.set_values(participant_model="mylab.models:make")


def test_participant_model_reaches_the_configuration_as_the_cli_flag_does(tmp_path):
    from nmsid.rig.gui.session_controller import load_session_config
    from nmsid.rig.gui.setup_panel import Backend, SessionRequest
    req = SessionRequest("MK01", Backend.SIM, tmp_path / "MK01.h5", joint="knee",
                         participant_model="musculoskeletal")
    cfg = load_session_config(req)
    assert (cfg.participant_model, cfg.joint, cfg.participant) == \
        ("musculoskeletal", "knee", "MK01")
    assert load_session_config(dataclasses.replace(
        req, participant_model=None)).participant_model == "template"


def test_nmsid_gui_participant_model_option_fills_the_form(qtbot, tmp_path):
    """``nmsid gui --participant-model musculoskeletal --joint knee``; a plug-in spec is
    refused by the command line (it runs with ``nmsid run`` only)."""
    from nmsid.cli import build_parser
    from nmsid.rig.gui.app import GuiOptions, build_window
    args = build_parser().parse_args(["gui", "--joint", "knee", "--participant-model",
                                      "musculoskeletal"])
    w = build_window(GuiOptions(joint=args.joint, participant_model=args.participant_model,
                                out=tmp_path / "MK01.h5"))
    qtbot.addWidget(w)
    req = w.setup_panel.request()
    assert (req.participant_model, req.joint, req.participant) == \
        ("musculoskeletal", "knee", "MK01")
    w.close()
    with pytest.raises(SystemExit):
        build_parser().parse_args(["gui", "--participant-model", "mylab.models:make"])


def test_knee_session_on_the_myoleg_participant_through_the_window(qtbot, tmp_path):
    """Issue 41: a simulated knee session on the built-in MyoLeg participant runs end to
    end from the GUI (one short trial, fast clock) and its file records the model."""
    pytest.importorskip("mujoco")
    from nmsid.rig.gui.main_window import MainWindow
    from nmsid.rig.gui.results_panel import SelectionView
    w = MainWindow(config_transform=_knee_short, identify=_LevelResult,
                   select_models=lambda path: SelectionView([], note="skipped"))
    qtbot.addWidget(w)
    w.show()
    try:
        out = tmp_path / "MK01.h5"
        w.start_session(output=out, backend="sim", seed=3, realtime=False, joint="knee",
                        participant_model="musculoskeletal")
        assert w.controller.engine is not None, w.setup_panel.message.text()
        assert w.controller.config.participant_model == "musculoskeletal"
        assert w.live.force_plot.getAxis("left").labelText == "torque (N m)"
        assert w.live.readouts.names["I_ext"].text() == "quadriceps (mA)"
        assert w.live.readouts.names["I_flex"].text() == "hamstrings (mA)"
        assert "N m" in w.calibration_panel.plot.getAxis("left").labelText
        qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled()
                        or w.run_error is not None, timeout=120_000)
        assert w.run_error is None
        w.confirm_calibration()
        qtbot.waitUntil(lambda: w.run_result is not None or w.run_error is not None,
                        timeout=180_000)
        assert w.run_error is None
        s = read_session(out, load_data=False)
        assert s.attrs.get("participant_model") == "musculoskeletal"
        assert s.attrs.get("joint") == "knee"
        assert s.participant == "MK01"
        assert [t.completed for t in s.trials] == [True]
    finally:
        w.controller.shutdown(timeout_s=5.0)
        w.close()


def test_one_function_applies_the_participant_model_for_the_cli_and_the_gui():
    """``with_participant_model``: ``nmsid run`` and the GUI both call it; an unnamed
    participant of the MyoLeg knee is MK01 (issue 39), a named one is kept."""
    from nmsid.protocols.config import load_config
    from nmsid.rig.session_service import with_participant_model
    knee = load_config(None, overrides={"joint": "knee"})
    assert with_participant_model(knee, None, participant_given=False) is knee
    got = with_participant_model(knee, "musculoskeletal", participant_given=False)
    assert (got.participant_model, got.participant) == ("musculoskeletal", "MK01")
    kept = with_participant_model(knee, "musculoskeletal", participant_given=True)
    assert kept.participant == knee.participant == "P01"
    assert with_participant_model(knee, "template", participant_given=False).participant \
        == "P01"
