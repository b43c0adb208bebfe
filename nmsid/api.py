"""The entry points of ``import nmsid`` (re-exported lazily by :mod:`nmsid`).

Each wraps what a command does (``nmsid identify``, ``nmsid gap``, ``nmsid twin
simulate``, ``nmsid run --backend sim``, ``nmsid control design``) and returns a result
object with a short repr instead of printing. Like the command line, this module sits on
the top layer (it reaches the rig and the analyses; tests/test_layers.py); each function
imports only what it needs, so ``import nmsid`` stays light.
"""

from __future__ import annotations

import os
import tempfile
import threading
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from nmsid.errors import UserError

if TYPE_CHECKING:  # annotations only
    import numpy as np

    from nmsid.analysis.control.design import ControllerDesign  # lazy, as above
    from nmsid.analysis.gap.api import GapRun  # lazy, as above
    from nmsid.analysis.gap.diagnose import GapSettings  # lazy, as above
    from nmsid.analysis.run import Identification  # lazy, as above
    from nmsid.analysis.settings import IdentificationSettings  # lazy, as above
    from nmsid.analysis.twin import Twin  # lazy, as above
    from nmsid.protocols.config import Config  # lazy, as above
    from nmsid.rig.observer import RunSummary  # lazy, as above

PathLike = str | os.PathLike


def _session_list(sessions) -> list:
    """One session (a path or a Session) or several, as a list."""
    # function-local: protocols.session_file loads h5py, which `import nmsid` must not
    from nmsid.protocols.session_file import Session
    if isinstance(sessions, (str, os.PathLike, Session)):
        return [sessions]
    items = list(sessions)
    if not items:
        raise UserError("no session given; give a session file (.h5), a Session, or a "
                        "list of them")
    return items


def _moved(path: Path, tmp: Path, out: Path) -> Path:
    """Where a file written into the temporary folder ``tmp`` is once it became ``out``."""
    try:
        return out / Path(path).relative_to(tmp)
    except ValueError:
        return Path(path)


def identify(sessions, out_dir: PathLike | None = None,
             settings: IdentificationSettings | None = None, *, figures: bool = False,
             force: bool = False) -> Identification:
    """Identify one session, or a group of sessions, as ``nmsid identify`` does.

    Parameters
    ----------
    sessions : path-like or Session, or a sequence of them
        One session: that participant's second-order model per sE level, the model of
        each parameter across sE and the twin. Several: also the group average.
    out_dir : path-like, optional
        Write ``parameters.csv``, ``model_selection.json``, ``twin.json``, ... there, as
        the command does (a folder that exists is refused unless ``force``). None keeps
        nothing on disk: the result object holds everything.
    settings : IdentificationSettings, optional
        Pre-processing and fit settings (default: the paper's).
    figures : bool
        Also draw the figures into ``out_dir`` (needs matplotlib).
    force : bool
        Replace an existing ``out_dir``.

    Returns
    -------
    Identification
        ``.sessions`` (parameters per sE level), ``.selection`` (models across sE),
        ``.twin``, ``.problems``; ``.rows()`` / ``.to_dataframe()`` give the parameter
        table.

    Raises
    ------
    IdentificationError
        If no session could be read at all (each unreadable one is otherwise listed in
        ``.problems``).
    """
    # function-local: the identification loads scipy and the fit code
    from nmsid.analysis.run import run_identification
    from nmsid.protocols.output_paths import output_dir  # lazy, as above
    items = _session_list(sessions)
    if figures and out_dir is None:
        raise UserError("figures=True needs out_dir (the folder the figures are drawn into)")
    if out_dir is None:
        with tempfile.TemporaryDirectory(prefix="nmsid-identify-") as tmp:
            result = run_identification(items, tmp, settings, figures=False)
        return replace(result, files=[])
    out = Path(out_dir)
    with output_dir(out, force=force, option="out_dir") as tmp:
        result = run_identification(items, tmp, settings, figures=figures)
    return replace(result, files=[_moved(p, tmp, out) for p in result.files])


def diagnose_gap(sessions, out_dir: PathLike | None = None, *,
                 settings: GapSettings | None = None, twin: PathLike | None = None,
                 sim_session: PathLike | None = None, figures: bool = False,
                 force: bool = False) -> GapRun:
    """Diagnose the sim-to-real gap of each session, as ``nmsid gap`` does.

    Parameters
    ----------
    sessions : path-like or Session, or a sequence of them
    out_dir : path-like, optional
        Write each session's ``gap_report.json`` and report there (refused if it exists,
        unless ``force``). None keeps nothing on disk.
    settings : GapSettings, optional
        Candidate effects, evidence margins (default: ``docs/gap.md``).
    twin, sim_session : path-like, optional
        An external simulation under test: a twin file, or a simulated session.
    figures : bool
        Also draw the figures into ``out_dir`` (needs matplotlib).
    force : bool
        Replace an existing ``out_dir``.

    Returns
    -------
    GapRun
        ``.sessions`` (each session's report), ``.rows()`` / ``.to_dataframe()`` (one row
        per session: verdict, effect, held-out NRMSE), ``.report`` (None when nothing was
        kept).
    """
    # function-local: the gap diagnosis loads scipy and the candidate models
    from nmsid.analysis.gap.api import run_gap
    from nmsid.protocols.output_paths import output_dir  # lazy, as above
    items = _session_list(sessions)
    if figures and out_dir is None:
        raise UserError("figures=True needs out_dir (the folder the figures are drawn into)")
    if out_dir is None:
        with tempfile.TemporaryDirectory(prefix="nmsid-gap-") as tmp:
            result = run_gap(items, tmp, settings=settings, twin=twin,
                             sim_session=sim_session, plots=False)
        return replace(result, report=None)
    out = Path(out_dir)
    with output_dir(out, force=force, option="out_dir") as tmp:
        result = run_gap(items, tmp, settings=settings, twin=twin, sim_session=sim_session,
                         plots=figures)
    report = result.report
    return replace(result, report=None if report is None else _moved(report, tmp, out))


def load_twin(path: PathLike, joint: str | None = None) -> Twin:
    """Read a twin file (``twin.json``, written by :func:`identify`).

    Parameters
    ----------
    path : path-like
    joint : str, optional
        The joint whose twin to read from a file of several joints (``docs/twin-file.md``);
        default: the file's one twin.

    Returns
    -------
    Twin
        ``.parameters_at(sE)``, ``.simulate(rE, sE, fs_Hz)``; see :func:`simulate_twin`.

    Raises
    ------
    TwinFileError
        Naming the file and the item that is missing or invalid.
    TwinInputError
        A file of several joints without ``joint``, or a ``joint`` it does not hold (the
        message lists the joints it holds).
    """
    # function-local: the twin module loads the discretisation (numpy, scipy)
    from nmsid.analysis.joint_twins import joint_twin
    return joint_twin(path, joint, how="joint=NAME")


def _twin(twin, joint: str | None = None) -> Twin:
    """A twin given as a Twin or as its file (of one joint, or of several: ``joint``)."""
    if twin is None:
        raise UserError("no twin given (an identification that could select no model "
                        "across sE has none: see its .problems)")
    if isinstance(twin, (str, os.PathLike)):
        return load_twin(twin, joint)
    if joint is not None and twin.joint != joint:
        from nmsid.analysis.errors import TwinInputError  # lazy, as in load_twin
        raise TwinInputError(f"the twin given is the {twin.joint}'s, not the {joint}'s")
    return twin


def simulate_twin(twin: Twin | PathLike, rE, sE, fs_Hz: float = 2000.0, *,
                  effects: bool = True, extrapolate: bool = False,
                  joint: str | None = None) -> np.ndarray:
    """The force a twin predicts for an input, as ``nmsid twin simulate`` computes it.

    Parameters
    ----------
    twin : Twin or path-like
        A twin, or its file (of one joint, or of several: ``joint`` says which).
    rE : array-like
        The extensor share of the stimulation, in [0, 1], one value per sample.
    sE : float or array-like
        The co-activation (> 0): one value, or one per sample.
    fs_Hz : float
        The sample rate of ``rE``.
    effects : bool
        Simulate the twin's effects (fatigue, delay, ...), as the FMU steps them; False:
        the curves alone.
    extrapolate : bool
        Use the curves beyond the tested sE range (default: clip to it).
    joint : str, optional
        The joint whose twin to run, in a twin file of several joints (``nmsid twin
        simulate --joint``); default: the file's one twin.

    Returns
    -------
    numpy.ndarray
        The force in N (a torque joint's twin: its torque in N m), one value per sample
        of ``rE``.

    Raises
    ------
    TwinInputError
        An rE outside [0, 1], an sE not > 0, or an effect that cannot be simulated (give
        ``effects=False``).
    """
    # function-local: numpy and the twin's simulation
    import numpy as np

    from nmsid.analysis.errors import TwinInputError  # lazy, as above
    model = _twin(twin, joint)
    r = np.asarray(rE, dtype=float)
    s = np.broadcast_to(np.asarray(sE, dtype=float), r.shape)
    if r.ndim != 1 or r.size < 2:
        raise TwinInputError(f"rE must be a 1-D sequence of at least 2 samples, got shape "
                             f"{r.shape}")
    if not (np.isfinite(fs_Hz) and 1.0 <= fs_Hz <= 100_000.0):
        raise TwinInputError(f"fs_Hz {fs_Hz!r}: give a rate in [1, 100000] Hz")
    for name, values, ok, valid in (("rE", r, np.isfinite(r) & (r >= 0) & (r <= 1), "in [0, 1]"),
                                    ("sE", s, np.isfinite(s) & (s > 0), "finite and > 0")):
        bad = np.flatnonzero(~ok)
        if bad.size:
            raise TwinInputError(f"{name}[{bad[0]}] is {float(values[bad[0]])!r} "
                                 f"({bad.size} bad sample(s)); valid: {valid}")
    if model.effects and effects and model.muscle_model is None:
        # function-local: the FMU's own stepper (one definition of the effects)
        from nmsid.export.fmu.build import SUPPORTED_EFFECTS, unsupported_effects
        from nmsid.export.fmu.reference import TwinStepper  # lazy, as above
        unsupported = sorted(unsupported_effects(model.effects))
        if unsupported:
            raise TwinInputError(
                f"the twin's effect(s) {', '.join(unsupported)} cannot be simulated here "
                f"(simulated: {', '.join(SUPPORTED_EFFECTS)}); give effects=False to "
                "simulate the curves alone")
        return TwinStepper(model, extrapolate=extrapolate).simulate(r, s, fs_Hz)
    return model.simulate(r, s, fs_Hz, clip=not extrapolate)


def run_simulated_session(out: PathLike, config: Config | PathLike | None = None, *,
                          participant: str | None = None, seed: int | None = None,
                          sim_seed: int | None = None,
                          participant_model: str | None = None) -> RunSummary:
    """Run a session on the simulated rig, as ``nmsid run --backend sim`` does.

    The stimulation goes through the one engine (its preflight and the interlock), on
    the simulator's fast clock (no rests); the session file is written at ``out``.

    Parameters
    ----------
    out : path-like
        The new session file (``.h5``); an existing file is never replaced.
    config : Config or path-like, optional
        The protocol (a TOML file, ``docs/settings.md``); None: the paper's.
    participant : str, optional
        The participant code (overrides the configuration's).
    seed : int, optional
        The session's seed (overrides the configuration's).
    sim_seed : int, optional
        The simulated participant's seed (default: derived from the participant code).
    participant_model : str, optional
        The simulated participant (``second-order``, ``musculoskeletal``, ...).

    Returns
    -------
    RunSummary
        How the run ended: ``.path``, ``.n_completed``, ``.ended_by``; read the file with
        :func:`nmsid.read_session`.

    Raises
    ------
    ConfigError, OutputPathError
        A bad setting, or an ``out`` that exists or holds an unfinished session's journal;
        nothing was stimulated.
    """
    # function-local: the rig (engine, simulator, session writer)
    from nmsid.protocols.config import Config, load_config
    from nmsid.protocols.errors import OutputPathError  # lazy, as above
    from nmsid.protocols.output_paths import check_output  # lazy, as above
    from nmsid.rig.engine import Engine, TripPolicy  # lazy, as above
    from nmsid.rig.session_log import journal_dir  # lazy, as above
    from nmsid.rig.session_service import RigRequest, prepare_rig  # lazy, as above
    overrides = {"participant": participant, "seed": seed}
    if isinstance(config, Config):
        cfg = config.replace(**{k: v for k, v in overrides.items() if v is not None})
    else:
        cfg = load_config(config, overrides=overrides)
    if participant_model:
        cfg = cfg.replace(participant_model=participant_model)
    path = check_output(out, kind="file", option="out")
    if journal_dir(path).exists():
        raise OutputPathError(f"out {path}: a journal of an unfinished session "
                              f"({journal_dir(path)}) is here; continue it with `nmsid run "
                              f"--backend sim --resume {path}`, or give another out")
    rig = prepare_rig(RigRequest(backend="sim", session_path=path, sim_seed=sim_seed,
                                 participant_model=participant_model or None), cfg)
    box: dict[str, Any] = {}
    try:
        engine = Engine(rig.config, rig.devices, path, trip_policy=TripPolicy.END_SESSION,
                        extra_attrs=rig.extra_attrs)

        def work() -> None:
            try:
                box["summary"] = engine.run()
            except BaseException as exc:  # handed to the caller's thread
                box["error"] = exc

        # the engine runs in a worker, as in `nmsid run`: Ctrl+C in the caller's thread
        # stops the output first (E-stop), then ends the session
        worker = threading.Thread(target=work, name="nmsid-engine")
        worker.start()
        try:
            while worker.is_alive():
                worker.join(0.1)
        except KeyboardInterrupt:
            engine.commands.estop("interrupted (KeyboardInterrupt)")
            engine.commands.abort("interrupted (KeyboardInterrupt)")
            worker.join()
            raise
    finally:
        rig.devices.close()
    if "error" in box:
        raise box["error"]
    return box["summary"]


def design_controller(twin: Twin | PathLike, *, sE: float | None = None,
                      update_Hz: float | None = None, lambda_s: float | None = None,
                      learning_gain: float = 0.0) -> ControllerDesign:
    """Design the twin-based force controller, as ``nmsid control design`` does.

    Parameters
    ----------
    twin : Twin or path-like
        A twin, or its file.
    sE : float, optional
        Operating co-activation; default where wn peaks within the twin's sE range.
    update_Hz : float, optional
        Stream update rate (default: the rig's, ``docs/control.md``).
    lambda_s : float, optional
        Closed-loop time constant of the PI (default from the loop delay).
    learning_gain : float
        Trial-to-trial learning (0: off, at most 1).

    Returns
    -------
    ControllerDesign
        ``.Kc``, ``.Ti_s``, ``.levels`` (margins and predicted RMSE per sE; ``.rows()`` /
        ``.to_dataframe()``), ``.save(path)`` writes ``controller.json``.

    Raises
    ------
    ControlDesignError
        A setting outside its range, or a twin without positive parameters there.
    """
    # function-local: the control design loads scipy.linalg
    from nmsid.analysis.control import design as control_design
    model = _twin(twin)
    rate = control_design.UPDATE_HZ if update_Hz is None else update_Hz
    return control_design.design_controller(model, sE=sE, update_Hz=rate, lambda_s=lambda_s,
                                            learning_gain=learning_gain)


__all__ = ["identify", "diagnose_gap", "load_twin", "simulate_twin", "run_simulated_session",
           "design_controller"]
