"""The handlers of ``nmsid run`` and ``nmsid recover`` (registered by :mod:`nmsid.cli.run`).

``run`` builds the configuration and the rig (simulated or hardware), runs the engine in a
worker thread (Ctrl+C is an E-stop), prints progress, then identifies the new file.

The identification (``nmsid.analysis.run``: plotting, QC, model selection) and the tracking
controller (``nmsid.rig.tracking``: the control design, scipy.linalg) are imported only by
the runs that use them: a ``--no-identify`` session without ``--track`` starts ~0.4 s
sooner (bench/bench_session.py).
"""

from __future__ import annotations

import datetime as dt
import functools
import json
import logging
import sys
import threading
import zlib
from pathlib import Path

from nmsid.cli.errors import UsageError
from nmsid.cli.exit_status import EXIT_NOTHING_TO_RECOVER, run_exit_status
from nmsid.protocols.config import config_from_json, load_config
from nmsid.protocols.errors import OutputPathError
from nmsid.protocols.output_paths import check_output, default_sessions_dir, output_dir
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.cocontraction import CoContractionSession
from nmsid.rig.engine import Engine, TripPolicy
from nmsid.rig.glitch_prompt import glitch_confirmation
from nmsid.rig.lsl import finish_recording, lsl_observer, require_pylsl, start_recording
from nmsid.rig.observer import EngineObserver
from nmsid.rig.recovery import check_stored_header
from nmsid.rig.session_log import journal_dir, recover
from nmsid.rig.session_service import (
    RigRequest,
    is_plugin_spec,
    prepare_rig,
    with_participant_model,
)
from nmsid.rig.session_signals import SessionSignals, exit_code, signal_name
from nmsid.rig.trials import session_kind_from_stored


def recover_cmd(args) -> int:
    report = recover(args.file)
    print(report.summary())
    if report.action == "no-calibration":
        return EXIT_NOTHING_TO_RECOVER
    problems = validate_session(args.file)
    if problems:
        print(f"{args.file}: still INVALID after recovery: {problems[0]}")
        return EXIT_NOTHING_TO_RECOVER
    return 0


def run(args) -> int:
    log = logging.getLogger("nmsid.cli.run_command")
    if args.resume and (args.config or args.participant or args.seed is not None
                        or getattr(args, "joint", None)):
        raise UsageError("--resume continues a session with the configuration stored in its "
                         "file; do not give --config, --participant, --seed or --joint with it "
                         "(--participant-model only names its plug-in again)")
    if args.realtime and args.backend != "sim":
        raise UsageError("--realtime applies to --backend sim (hardware is always real time)")
    track = _tracking_engine(args)   # --track / --target: checked before any device
    sweep_rE = getattr(args, "cocontraction", None)
    if sweep_rE is not None and (track is not None or args.resume):
        raise UsageError("--cocontraction runs a new co-contraction sweep: not with --track, "
                         "--target or --resume (a resumed sweep continues as recorded)")
    if args.resume:
        path = Path(args.resume)
        check_stored_header(path)  # a damaged journal header: rebuilt, or one line
        config = _stored_config(path)
    else:
        config = load_config(args.config, overrides={
            "participant": args.participant, "seed": args.seed,
            "joint": getattr(args, "joint", None),
            "confirm_weakened_safety": getattr(args, "allow_weakened_safety", False)})
        config = with_participant_model(  # issue 39: not the template's P01 under its name
            config, args.participant_model,
            participant_given=bool(args.participant or args.config))
        outdir = Path(args.outdir) if args.outdir else default_sessions_dir()
        path = Path(args.out) if args.out else _free_path(outdir, config.participant)
        # a taken, dangling or unwritable --out is refused before any device is touched
        check_output(path, kind="file", option="--out" if args.out else "--outdir")
        if journal_dir(path).exists():
            raise OutputPathError(f"{path}: a journal of an unfinished session "
                                  f"({journal_dir(path)}) is here; continue it with "
                                  f"--resume {path}, or give another --out")
        if sweep_rE is not None:   # sE steps at a fixed rE, on the one engine
            p = config.protocol
            track = functools.partial(Engine, session=CoContractionSession(
                p.sE_levels, sweep_rE, p.trial_s, repeats=p.repeats,
                source=f"--cocontraction {sweep_rE:g} with {config.source}"))
    # --lsl / --lsl-record: the same settings as the protocol file's [lsl] table
    lsl = config.lsl.with_command_line(bool(getattr(args, "lsl", False)),
                                       getattr(args, "lsl_record", None))
    if lsl is not config.lsl:
        config = config.replace(lsl=lsl)
    design = getattr(track, "keywords", {}).get("design")
    if design is not None and getattr(design, "joint", "elbow") != config.joint:
        raise UsageError(f"--track {args.track}: the controller was designed on a "
                         f"{design.joint} twin ({design.measured_unit}); this session is of "
                         f"the {config.joint} (give --joint {design.joint}, or design a "
                         f"controller from a {config.joint} twin)")
    stored, stored_backend = _stored_attrs(path) if args.resume else ({}, "")
    kind = session_kind_from_stored(stored, str(path)) if args.resume else None
    if kind is not None:   # e.g. tracking: its recorded controller and targets, no code
        track = functools.partial(Engine, session=kind)
    request = RigRequest(backend=args.backend, session_path=path, resume=bool(args.resume),
                         hw_config=Path(args.hw_config) if args.hw_config else None,
                         sim_seed=args.sim_seed if args.backend == "sim" else None,
                         realtime=bool(args.realtime), stored=stored,
                         stored_backend=stored_backend,
                         participant_model=args.participant_model or None)
    if args.backend == "hw" and args.sim_seed is not None:
        log.warning("--sim-seed %s ignored: it applies to --backend sim (the simulated "
                    "participant)", args.sim_seed)
    box: dict = {}

    def on_signal(signum, reason):  # main thread, which holds no engine lock
        engine = box.get("engine")
        if engine is not None:  # output to zero first, then end the session
            engine.commands.estop(reason)
            engine.commands.abort(reason)
        # before the engine exists nothing has been stimulated: run() checks `received`

    def stop_output(reason):  # Windows console event: its own thread, at once
        engine = box.get("engine")
        if engine is not None:
            engine.commands.estop(reason)

    if config.lsl.active:
        require_pylsl()                      # one line before any device is opened
    recorder = start_recording(list(config.lsl.record))   # issue 43
    observer: EngineObserver = EngineObserver()
    with SessionSignals(on_signal, stop_output) as signals:
        rig = prepare_rig(request, config)   # a resume on another rig is refused here
        devices, config = rig.devices, rig.config
        if config.protocol.rest_s == 0 and rig.extra_attrs.get("configured_rest_s"):
            log.info("fast clock: rest_s %g -> 0", rig.extra_attrs["configured_rest_s"])
        progress = _Progress(quiet=args.quiet)
        observer = progress
        if config.lsl.publish:               # issue 43: LSL outlets, off by default
            observer = lsl_observer(progress, config.protocol.fs_Hz, config.participant)
        try:
            engine = (track or Engine)(config, devices, path, resume=bool(args.resume),
                            observer=observer, trip_policy=TripPolicy.END_SESSION,
                            on_device_glitch=glitch_confirmation(
                                getattr(args, "resume_after_reconnect", False)),
                            extra_attrs=rig.extra_attrs)
            if signals.received is not None:
                print(f"nmsid: {signal_name(signals.received)} received before the session "
                      f"started: nothing stimulated, no session file written",
                      file=sys.stderr, flush=True)
                return exit_code(signals.received)
            box["engine"] = engine
            progress.total = len(engine.schedule)
            progress.done = sum(1 for t in engine.schedule if t.status.value == "done")
            done_before = progress.done
            if not args.quiet:  # issue 39: a real-time run said nothing for 25 s
                _print_quietly(f"{path}: {'resuming' if args.resume else 'starting'}: "
                               f"{progress.done} of {progress.total} trials done; "
                               f"Ctrl+C stops the session (E-stop)")
            if engine.recovery is not None and engine.recovery.action != "none":
                print(engine.recovery.summary(), flush=True)

            def work():
                try:
                    box["summary"] = engine.run()
                except BaseException as exc:  # handed to the main thread
                    box["error"] = exc

            worker = threading.Thread(target=work, name="nmsid-engine")
            worker.start()
            while worker.is_alive():  # short joins: the signal handler runs between them
                worker.join(0.1)
        finally:
            devices.close()
            finish_recording(recorder, path, observer)
    if "error" in box:
        raise box["error"]
    s = box["summary"]
    progress.finish()
    if signals.received is not None:
        # one line on stderr; stdout (maybe a closed terminal after SIGHUP) may fail
        _print_quietly(f"{s.path}: {s.n_completed} completed, {s.n_aborted} aborted, "
                       f"{s.n_pending} not run ({s.ended_by})")
        print(signals.stderr_line(s.path, complete=s.complete,
                                  file_written=Path(s.path).exists()),
              file=sys.stderr, flush=True)
        return signals.exit_code
    print(f"{s.path}: {s.n_completed} completed, {s.n_aborted} aborted, {s.n_pending} not run "
          f"({s.ended_by})", flush=True)
    if s.n_pending or s.n_aborted:
        plugin = config.participant_model if is_plugin_spec(config.participant_model) \
            and args.backend == "sim" else None
        print(f"  continue with: nmsid run --backend {args.backend} --resume {s.path}"
              + (f" --participant-model {plugin}" if plugin else ""), flush=True)
    if not args.no_identify and s.n_completed and track is None:
        # a resume that ran no trial (the session was complete) names the earlier analysis
        _identify(s.path, reuse=bool(args.resume) and s.n_completed == done_before)
    return run_exit_status(s)


def _tracking_engine(args):
    """:func:`nmsid.rig.tracking.tracking_engine`, imported only when ``--track`` or
    ``--target`` is given (a plain session does not load the control design)."""
    if getattr(args, "track", None) is None and getattr(args, "target", None) is None:
        return None
    # lazy: the tracking controller imports the control design (scipy.linalg)
    from nmsid.rig.tracking import tracking_engine
    return tracking_engine(args)


def _print_quietly(text: str) -> None:
    """Print to stdout, ignoring a terminal that has gone (SIGHUP: EIO / broken pipe)."""
    try:
        print(text, flush=True)
    except OSError:
        pass


def _stored_attrs(path) -> tuple[dict, str]:
    """Extra root attributes and the backend text of a session (journal header first,
    else the file)."""
    j = journal_dir(path) / "header.json"
    if j.exists():
        header = json.loads(j.read_text(encoding="utf-8"))
        return dict(header.get("extra_attrs") or {}), str(header.get("backend", ""))
    s = read_session(path, load_data=False)
    return dict(s.attrs), str(s.backend)


def _stored_config(path):
    j = journal_dir(path) / "header.json"
    if j.exists():
        return config_from_json(json.loads(j.read_text(encoding="utf-8"))["config_json"],
                                source=str(j))
    return config_from_json(read_session(path, load_data=False).config_json, source=str(path))


def _free_path(outdir, participant: str):
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    for k in range(1, 1000):
        p = outdir / (f"{participant}-{stamp}" + (f"-{k}" if k > 1 else "") + ".h5")
        if not p.exists() and not journal_dir(p).exists():
            return p
    raise UsageError(f"{outdir}: no free session file name for {participant}-{stamp}")


def _identify(path, reuse: bool = False) -> None:
    """Run the identification on the new file into ``<file stem>-analysis/`` (or
    ``-analysis-2``, ... if that exists: an earlier result is never replaced). ``reuse``
    (a resume that ran no trial): an existing analysis of this file is named instead of
    repeated (issue 39: each resume of a complete session re-identified)."""
    # lazy: the identification's modules (figures, QC, model selection) cost ~0.4 s of
    # start-up, which a --no-identify or tracking session never uses
    from nmsid.analysis.run import analysis_of, run_identification, summary_line
    if reuse and (done := analysis_of(path)) is not None:
        print(f"identification of this file already in {done}; not repeated", flush=True)
        return
    out = next(p for k in range(1, 10_000) if not (p := path.with_name(
        path.stem + "-analysis" + (f"-{k}" if k > 1 else ""))).exists())
    with output_dir(out) as tmp:
        outputs = run_identification([path], tmp)
    if outputs.tables_text:
        print(outputs.tables_text, flush=True)
    print(summary_line(outputs), flush=True)
    print(f"identification written to {out}", flush=True)


class _Progress(EngineObserver):
    """Engine observer that prints a progress bar and one line per finished trial."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.tty = sys.stdout.isatty()
        self.total = 0
        self.done = 0

    # EngineObserver interface (duck-typed)
    def on_state(self, old, new, reason): ...

    def on_event(self, event):
        if event.kind in ("interlock_trip", "calibration", "calibration_failed", "recovered",
                          "session_end") and not self.quiet:
            self._clear()
            print(f"[{event.kind}] {event.detail}", flush=True)
        elif event.kind == "trial_start" and self.tty and not self.quiet:
            self._bar(event.detail)   # the trial as the file names it (``trial t012 (...)``)

    def on_calibration_step(self, muscle, current_mA, force_N): ...

    def on_calibration_result(self, calibration): ...

    def on_trial_started(self, index, planned): ...

    def on_chunk(self, *a): ...

    def on_trial_finished(self, index, trial):
        if trial.completed:
            self.done += 1
        if self.quiet:
            return
        self._clear()
        crc = zlib.crc32(trial.force_N.astype("<f8").tobytes())
        status = "completed" if trial.completed else f"aborted ({trial.abort_reason})"
        print(f"{trial.name} {status}: sE {trial.sE:.2f} repeat {trial.repeat} attempt "
              f"{trial.extra_attrs.get('attempt', 1)} n {trial.n_samples} crc {crc:08x} "
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
