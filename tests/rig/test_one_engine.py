"""One engine, one trial path (issue 36), and one trial numbering: the file's (issue 39).

The engine is one class whose state is declared once; operator commands are one small
object (``engine.commands``); calibration and device recovery are functions it calls; no
kind of session subclasses it. Every event names a trial as the file does.
"""

import ast
import re
import threading
from pathlib import Path

import nmsid
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig import device_recovery, engine_calibration, engine_commands
from nmsid.rig.engine import Engine
from nmsid.rig.engine_commands import OperatorCommands
from nmsid.rig.states import State
from tests.rig.test_engine import Recorder

PKG = Path(nmsid.__file__).resolve().parent.parent   # the repository (nmsid's packages)


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def test_the_engine_is_one_class_without_mixins_and_no_kind_subclasses_it():
    import nmsid.rig.cocontraction  # noqa: F401  (every kind of session loaded)
    import nmsid.rig.tracking as tracking
    assert Engine.__bases__ == (object,)
    assert Engine.__subclasses__() == []
    # a tracking session is the same engine running another plan, not a subclass
    assert not isinstance(tracking.TrackingEngine, type)


def test_the_engines_helpers_redeclare_no_engine_state():
    """A mixin re-declares the engine's attributes (``_sm: StateMachine`` ...) at class
    level; the folded modules hold functions, exceptions, an enum and the command object,
    which keeps only its queue."""
    for mod in (engine_commands, engine_calibration, device_recovery):
        for node in ast.walk(_tree(Path(mod.__file__))):
            if isinstance(node, ast.ClassDef):
                declared = [n.target.id for n in node.body if isinstance(n, ast.AnnAssign)
                            and isinstance(n.target, ast.Name)]
                assert declared == [], f"{mod.__name__}.{node.name} declares {declared}"


def test_trials_are_started_and_written_only_by_the_engines_trial_path():
    calls: dict[str, list[str]] = {}
    for py in sorted((PKG / "rig").rglob("*.py")) + sorted((PKG / "cli").rglob("*.py")):
        for node in ast.walk(_tree(py)):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
                    node.func.attr in ("begin_trial", "end_trial"):
                calls.setdefault(node.func.attr, []).append(py.relative_to(PKG).as_posix())
            if isinstance(node, ast.FunctionDef) and node.name == "_run_trial":
                calls.setdefault("def _run_trial", []).append(py.relative_to(PKG).as_posix())
    assert calls == {"begin_trial": ["rig/engine.py"], "end_trial": ["rig/engine.py"],
                     "def _run_trial": ["rig/engine.py"]}


def test_operator_commands_are_one_thread_safe_object():
    stopped = []
    cmds = OperatorCommands(stopped.append)
    threading.Thread(target=cmds.estop, args=("button",)).start()
    cmds.wait(5.0)          # woken by the E-stop (generous bound: a thread start)
    cmds.pause()
    cmds.rerun(3)
    assert stopped == ["button"]
    assert [(c.value, a) for c, a in cmds.take()] == [("pause", None), ("rerun", 3)]
    assert list(cmds.take()) == []


TRIAL = re.compile(r"^trial (t\d{3}) \(sE (\S+) repeat (\d+), attempt (\d+)\)")


def test_every_event_names_the_trial_as_the_file_does(tmp_path, fake_rig, small_config):
    """An E-stop aborts the second trial, which is re-run (a second attempt, a new group),
    and the next pending trial is skipped without running: each trial event's name is the
    group under /trials holding that very trial (sE, repeat, attempt)."""
    rig = fake_rig()
    obs = Recorder()
    path = tmp_path / "s.h5"
    eng = Engine(small_config(), rig, path, observer=obs)
    fired = []

    def chunk(index, start):
        if index == 1 and start >= 1000 and not fired:
            fired.append(1)
            eng.commands.estop("button")

    def state(old, new, reason):
        if new is State.TRIPPED:
            eng.commands.rerun(1)
            eng.commands.rearm()
        if new is State.RESTING and len(fired) == 1 and eng.schedule[1].attempts == 2:
            fired.append(2)
            eng.commands.skip_trial()   # between trials: the next pending one is not run
        if new is State.PAUSED:         # waiting for a re-run of the skipped trial
            eng.commands.abort()

    obs.hooks = {"chunk": chunk, "state": state}
    eng.run()
    assert validate_session(path) == []
    s = read_session(path)
    groups = {t.name: t for t in s.trials}
    assert [t.extra_attrs["schedule_index"] for t in s.trials] == [0, 1, 1, 3]
    named = 0
    for e in s.events:
        if e.kind in ("trial_start", "trial_completed", "trial_aborted"):
            m = TRIAL.match(e.detail)
            assert m, e.detail
            t = groups[m.group(1)]
            assert (f"{t.sE:g}", t.repeat, t.extra_attrs["attempt"]) == (
                m.group(2), int(m.group(3)), int(m.group(4))), (e.detail, t.name)
            if e.kind != "trial_start":
                assert t.completed == (e.kind == "trial_completed")
            named += 1
    assert named == 2 * len(s.trials)
    details = {e.kind: e.detail for e in s.events}
    # the re-run names the aborted trial's group; the skipped one was never in the file
    assert details["rerun_queued"].startswith("trial t002 (sE ") and \
        groups["t002"].abort_reason == "estop: button"
    skipped = eng.schedule[2]
    assert details["trial_skipped"] == (f"the trial sE {skipped.sE:g} repeat "
                                        f"{skipped.repeat} (not in the file): not run, "
                                        "skipped by operator")
    assert "schedule index" not in " ".join(e.detail for e in s.events)
