"""``nmsid run`` (a whole session, headless) and ``nmsid recover FILE``.

``nmsid run --backend sim`` runs calibration and the schedule on the simulated rig as fast
as possible (``--realtime`` paces it like hardware), prints a progress line per trial, then
runs the identification on the file. Ctrl+C is an E-stop: output to zero, the session ends
cleanly and the file stays valid; ``--resume FILE`` continues it.
"""

from __future__ import annotations
from protocols.session_file import read_session, validate_session


class BackendUnavailable(RuntimeError):
    """The requested backend cannot be built (a missing module or function)."""


def register(sub) -> None:
    p = sub.add_parser("run", help="run a whole session (calibration + schedule) headless, "
                       "then identify it",
                       description="Run calibration and the trial schedule on the simulated "
                       "rig (--backend sim, fast clock by default) or on hardware (--backend "
                       "hw), write the session file, then run the identification.")
    p.add_argument("--backend", choices=("sim", "hw"), default="sim",
                   help="sim: the simulated rig; hw: the hardware in --hw-config")
    p.add_argument("--participant", metavar="CODE",
                   help="participant code [A-Za-z0-9_-]{1,64} (overrides the config)")
    p.add_argument("--config", metavar="FILE", help="protocol configuration (TOML)")
    p.add_argument("--seed", type=int, metavar="N",
                   help="schedule randomisation seed (overrides the config; default: drawn "
                        "and recorded)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--out", metavar="FILE", help="session file to write (must not exist)")
    out.add_argument("--outdir", metavar="DIR",
                     help="folder for <participant>-<UTC time>.h5 (default: sessions)")
    out.add_argument("--resume", metavar="FILE",
                     help="continue this session (recovering it first if needed): skip its "
                          "completed trials, re-run its aborted ones")
    p.add_argument("--realtime", action="store_true",
                   help="sim: pace the simulation in real time (default: as fast as possible)")
    p.add_argument("--hw-config", metavar="FILE", help="hw: the rig's hardware configuration")
    p.add_argument("--participant-model", choices=("template", "musculoskeletal"),
                   help="sim: the virtual participant: the paper's second-order model "
                        "(template, default) or MyoSuite's MuJoCo elbow under FES "
                        "(musculoskeletal; needs the 'mujoco' extra); overrides the "
                        "config's [participant] model")
    p.add_argument("--sim-seed", type=int, metavar="N",
                   help="sim: seed of the virtual participant and its noise (default: from "
                        "the participant code)")
    p.add_argument("--no-identify", action="store_true",
                   help="do not run the identification after the schedule")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(handler="rig.cli_run:run")

    r = sub.add_parser("recover", help="rebuild a session file from its journal after a crash",
                       description="Bring a session file in line with its write-ahead journal "
                       "(<file>.journal/): append trials missing from it, or rebuild a damaged "
                       "file (kept aside as <file>.damaged-<time>). The trial in progress when "
                       "the program ended becomes an aborted trial.")
    r.add_argument("file", metavar="FILE", help="the session file (.h5)")
    r.set_defaults(handler="rig.cli_run:recover_cmd")


# -- handlers ------------------------------------------------------------------------
def recover_cmd(args) -> int:
    from rig.session_log import recover

    report = recover(args.file)
    print(report.summary())
    if report.action == "no-calibration":
        return 1
    problems = validate_session(args.file)
    if problems:
        print(f"{args.file}: still INVALID after recovery: {problems[0]}")
        return 1
    return 0


def run(args) -> int:
    import logging
    import signal
    import threading
    from pathlib import Path

    from protocols.config import load_config
    from rig.engine import Engine, TripPolicy

    log = logging.getLogger("rig.cli_run")
    if args.resume and (args.config or args.participant or args.seed is not None
                        or args.participant_model):
        raise ValueError("--resume continues a session with the configuration stored in its "
                         "file; do not give --config, --participant, --participant-model or "
                         "--seed with it")
    if args.realtime and args.backend != "sim":
        raise ValueError("--realtime applies to --backend sim (hardware is always real time)")
    if args.resume:
        path = Path(args.resume)
        config = _stored_config(path)
    else:
        config = load_config(args.config, overrides={"participant": args.participant,
                                                     "seed": args.seed})
        if args.participant_model:
            config = config.replace(participant_model=args.participant_model)
        if args.backend == "sim" and not args.realtime and config.protocol.rest_s != 0:
            log.info("fast clock: rest_s %g -> 0", config.protocol.rest_s)
            config = config.with_protocol(rest_s=0.0)
        path = Path(args.out) if args.out else _free_path(Path(args.outdir or "sessions"),
                                                          config.participant)
    stored = _stored_attrs(path) if args.resume else {}
    sim_seed = None
    if args.backend == "sim":
        sim_seed = (args.sim_seed if args.sim_seed is not None else
                    stored.get("sim_seed", _seed_from_code(config.participant)))
    devices = _make_devices(args, config, sim_seed)
    progress = _Progress(quiet=args.quiet)
    try:
        engine = Engine(config, devices, path, resume=bool(args.resume), observer=progress,
                        trip_policy=TripPolicy.END_SESSION,
                        extra_attrs={} if sim_seed is None else {
                            "sim_seed": int(sim_seed),
                            "participant_model": config.participant_model})
        progress.total = len(engine.schedule)
        progress.done = sum(1 for t in engine.schedule if t.status.value == "done")
        if engine.recovery is not None and engine.recovery.action != "none":
            print(engine.recovery.summary(), flush=True)
        box: dict = {}

        def work():
            try:
                box["summary"] = engine.run()
            except BaseException as exc:  # handed to the main thread
                box["error"] = exc

        worker = threading.Thread(target=work, name="nmsid-engine")

        def on_sigint(signum, frame):  # runs in the main thread, which holds no engine lock
            engine.estop("Ctrl+C (operator E-stop)")
            engine.abort()
            print("\nE-stop: output off; ending the session cleanly...", flush=True)

        old = signal.signal(signal.SIGINT, on_sigint)
        try:
            worker.start()
            while worker.is_alive():
                worker.join(0.1)
        finally:
            signal.signal(signal.SIGINT, old)
    finally:
        devices.close()
    if "error" in box:
        raise box["error"]
    s = box["summary"]
    progress.finish()
    print(f"{s.path}: {s.n_completed} completed, {s.n_aborted} aborted, {s.n_pending} not run "
          f"({s.ended_by})", flush=True)
    if s.n_pending or s.n_aborted:
        print(f"  continue with: nmsid run --backend {args.backend} --resume {s.path}",
              flush=True)
    if not args.no_identify and s.n_completed:
        _identify(s.path)
    return 0 if s.ended_by == "schedule complete" else 1


def _stored_attrs(path) -> dict:
    """Extra root attributes of a session (journal header first, else the file)."""
    import json

    from rig.session_log import journal_dir

    j = journal_dir(path) / "header.json"
    if j.exists():
        return dict(json.loads(j.read_text()).get("extra_attrs") or {})
    return dict(read_session(path, load_data=False).attrs)


def _stored_config(path):
    import json

    from protocols.config import config_from_json
    from rig.session_log import journal_dir

    j = journal_dir(path) / "header.json"
    if j.exists():
        return config_from_json(json.loads(j.read_text())["config_json"], source=str(j))
    return config_from_json(read_session(path, load_data=False).config_json, source=str(path))


def _free_path(outdir, participant: str):
    import datetime as dt

    from rig.session_log import journal_dir

    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    for k in range(1, 1000):
        p = outdir / (f"{participant}-{stamp}" + (f"-{k}" if k > 1 else "") + ".h5")
        if not p.exists() and not journal_dir(p).exists():
            return p
    raise FileExistsError(f"{outdir}: no free session file name for {participant}-{stamp}")


def _make_devices(args, config, sim_seed):
    if args.backend == "hw":
        if not args.hw_config:
            raise ValueError("--backend hw needs --hw-config FILE (the rig's hardware "
                             "configuration)")
        try:
            from drivers.hardware import make_hw_rig
        except ImportError as exc:
            raise BackendUnavailable(f"the hardware backend is not available in this build "
                                     f"(drivers.hardware.make_hw_rig: {exc})") from None
        return make_hw_rig(args.hw_config)
    try:
        from sim_backends import make_sim_rig
    except ImportError as exc:
        raise BackendUnavailable(f"the simulated rig is not available in this build "
                                 f"(sim_backends.make_sim_rig: {exc})") from None
    from sim_backends.participant_models import participant_for_model
    return make_sim_rig(participant_for_model(config.participant_model, int(sim_seed)),
                        realtime=args.realtime)


def _seed_from_code(code: str) -> int:
    import zlib
    return zlib.crc32(code.encode("utf-8"))


def _identify(path) -> None:
    """Run the identification on the new file into ``<file stem>-analysis/``."""
    out = path.with_name(path.stem + "-analysis")
    try:
        from analysis.run import run_identification, summary_line
    except ImportError as exc:
        print(f"identification skipped: analysis.run is not available ({exc})", flush=True)
        return
    outputs = run_identification([path], out)
    if outputs.tables_text:
        print(outputs.tables_text, flush=True)
    print(summary_line(outputs), flush=True)
    print(f"identification written to {out}", flush=True)


class _Progress:
    """Engine observer that prints a progress bar and one line per finished trial."""

    def __init__(self, quiet: bool = False):
        import sys
        self.quiet = quiet
        self.tty = sys.stdout.isatty()
        self.total = 0
        self.done = 0

    # EngineObserver interface (duck-typed to keep `nmsid --help` light)
    def on_state(self, old, new, reason): ...

    def on_event(self, event):
        if event.kind in ("interlock_trip", "calibration", "calibration_failed", "recovered",
                          "session_end") and not self.quiet:
            self._clear()
            print(f"[{event.kind}] {event.detail}", flush=True)

    def on_calibration_step(self, muscle, current_mA, force_N): ...

    def on_calibration_result(self, calibration): ...

    def on_trial_started(self, index, planned):
        if self.tty and not self.quiet:
            self._bar(f"trial {index}: sE {planned.sE:.2f} repeat {planned.repeat}")

    def on_chunk(self, *a): ...

    def on_trial_finished(self, index, trial):
        import zlib
        if trial.completed:
            self.done += 1
        if self.quiet:
            return
        self._clear()
        crc = zlib.crc32(trial.force_N.astype("<f8").tobytes())
        status = "completed" if trial.completed else f"aborted ({trial.abort_reason})"
        print(f"{trial.name} {status}: schedule index {index} sE {trial.sE:.2f} repeat "
              f"{trial.repeat} n {trial.n_samples} crc {crc:08x} "
              f"[{self.done}/{self.total}]", flush=True)

    def on_level_completed(self, sE, trials): ...

    def on_finished(self, path): ...

    def _bar(self, text):
        width = 30
        k = int(width * self.done / max(1, self.total))
        print(f"\r[{'#' * k}{'.' * (width - k)}] {self.done}/{self.total} {text:40s}",
              end="", flush=True)

    def _clear(self):
        if self.tty:
            print("\r" + " " * 80 + "\r", end="")

    def finish(self):
        self._clear()
