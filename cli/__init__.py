"""The ``nmsid`` command: one entry point, one sub-command per job.

Each sub-command is a registration module here (``nmsid.cli.<name>``: argparse only,
``register(subparsers)``, so ``nmsid --help`` imports no numpy or Qt) and a handler module
(``nmsid.cli.<name>_command``), imported only when the sub-command runs.

What ends a command (:mod:`nmsid.errors`):

* a user error (bad file, setting or value; a missing optional package; a file-system error
  on a path the user gave): one line, exit status 2;
* a device fault: one line, exit status 3; a safety refusal: one line, exit status 4;
* anything else is a bug: its traceback, one line saying so, exit status 1;
* a closed pipe (``nmsid ... | head``): nothing more is printed, the command goes on to
  its end, exit status :data:`EXIT_CLOSED_PIPE` (as a shell reports a command ended by
  SIGPIPE) unless the command failed on its own.

``--debug`` shows the traceback of every error; ``--version`` prints the version.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
import sys
import traceback

from nmsid.errors import (
    EXIT_BUG,
    EXIT_USER_ERROR,
    DeviceFault,
    MissingDependency,
    NmsidError,
    SafetyError,
    UserError,
)
from nmsid.protocols.printable import escape_controls

#: Modules that each add one or more sub-commands.
COMMAND_MODULES = (
    "nmsid.cli.run",          # run, recover
    "nmsid.cli.validate",     # validate
    "nmsid.cli.identify",  # identify, twin
    "nmsid.cli.qc",      # qc
    "nmsid.cli.gap",     # gap
    "nmsid.cli.design",  # design
    "nmsid.cli.probe",    # probe
    "nmsid.cli.gui",          # gui
    "nmsid.cli.export",    # export nwb
    "nmsid.cli.study",      # study
    "nmsid.cli.stimulation",  # stimulation
    "nmsid.cli.control",  # control design, control report
)

#: The registration module of each sub-command: a command line that names one imports only
#: that module (``nmsid identify`` does not register the eleven others); ``nmsid --help``
#: and anything unrecognised register them all. A test holds it equal to what the
#: modules register.
COMMAND_OF = {
    "run": "nmsid.cli.run", "recover": "nmsid.cli.run", "validate": "nmsid.cli.validate",
    "identify": "nmsid.cli.identify", "twin": "nmsid.cli.identify", "qc": "nmsid.cli.qc",
    "gap": "nmsid.cli.gap", "design": "nmsid.cli.design", "probe": "nmsid.cli.probe",
    "gui": "nmsid.cli.gui", "export": "nmsid.cli.export", "study": "nmsid.cli.study",
    "stimulation": "nmsid.cli.stimulation", "control": "nmsid.cli.control",
}

#: Commands whose linear algebra is many small solves (a few dozen columns): BLAS worker
#: threads cost them more in start-up and hand-over than they gain, and on a loaded
#: machine much more (``nmsid identify`` of a 45-trial session on 2 busy cores: 5.9-8.3 s of
#: CPU with OpenBLAS's default threads, 1.3-1.5 s with one; ``nmsid gap`` of a template
#: session 13.3 s against 4.4 s, docs/gap.md). They start single-threaded unless the user set
#: a thread count.
SINGLE_THREAD_COMMANDS = frozenset({"identify", "qc", "gap"})
#: The thread-count variables of the BLAS builds numpy ships with (OpenBLAS) or may be
#: built against (MKL, OpenMP); read when numpy is first imported.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def limit_blas_threads(environ=None) -> list[str]:
    """Set each BLAS thread-count variable the user left unset to 1; returns those set.

    Effective only before numpy is imported (the CLI calls it before the handler's
    import); a count the user chose is kept.
    """
    env = os.environ if environ is None else environ
    chosen = [name for name in BLAS_THREAD_VARIABLES if name not in env]
    for name in chosen:
        env[name] = "1"
    return chosen


#: Exit status when the reader of stdout went away (``nmsid ... | head``): 128 + SIGPIPE (13),
#: what a shell reports for a command the signal ended, on every platform.
EXIT_CLOSED_PIPE = 141


#: errno values of file-system errors that are the user's to fix (a path that does not
#: exist, is not allowed, is full, is read-only, ...), not bugs.
_USER_ERRNOS = frozenset({errno.EPERM, errno.ENOENT, errno.EACCES, errno.EEXIST, errno.ENOTDIR,
                          errno.EISDIR, errno.ENOSPC, errno.EROFS, errno.ENAMETOOLONG,
                          errno.ENOTEMPTY, errno.EDQUOT})


class _EscapingStream:
    """A text stream that writes control characters as visible escapes: names and notes
    read from files never reach the terminal raw (:mod:`nmsid.protocols.printable`).

    When its reader goes away (``nmsid run ... | head``) it says so in ``closed_pipe`` and
    drops what follows: the command goes on (a session is not ended by a closed pipe, and
    the engine thread's progress lines raise nothing) and ends with
    :data:`EXIT_CLOSED_PIPE`."""

    def __init__(self, stream):
        self._stream = stream
        self.closed_pipe = False

    def write(self, text: str) -> int:
        if not self.closed_pipe:
            try:
                return self._stream.write(escape_controls(text))
            except OSError as exc:
                if not _reader_gone(exc):
                    raise
                self._drop_output()
        return len(text)

    def flush(self) -> None:
        if not self.closed_pipe:
            try:
                self._stream.flush()
            except OSError as exc:
                if not _reader_gone(exc):
                    raise
                self._drop_output()

    def _drop_output(self) -> None:
        self.closed_pipe = True
        _to_null_device(self._stream)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _reader_gone(exc: OSError) -> bool:
    """A write failed because the pipe's reader went away: EPIPE (BrokenPipeError), or
    EINVAL, which is how Windows' C runtime reports a write into a closed pipe."""
    return isinstance(exc, BrokenPipeError) or exc.errno == errno.EINVAL


@contextlib.contextmanager
def _escaped_output():
    out, err = sys.stdout, sys.stderr
    streams = (_EscapingStream(out), _EscapingStream(err))
    sys.stdout, sys.stderr = streams
    try:
        yield streams
    finally:
        sys.stdout, sys.stderr = out, err


class _VersionAction(argparse.Action):
    """``--version``: print ``nmsid <version>`` and exit 0. The version is looked up only
    when asked for (:data:`nmsid.__version__` reads the installed package's metadata)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="print nmsid's version and exit"):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        import nmsid  # the root package's lazy __version__ (package metadata)
        print(f"nmsid {nmsid.__version__}")  # on stdout, as argparse's own "version"
        parser.exit(0)


class _OneLineParser(argparse.ArgumentParser):
    """An argument parser whose refusals are one line on stderr (exit 2), naming the
    command and pointing at its --help, instead of argparse's usage block."""

    def error(self, message: str):
        text = escape_controls(message).replace("\n", "\\n")
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def _one_line(text: str) -> str:
    """A message as one line: a newline inside a value read from a file is shown, not obeyed."""
    return escape_controls(text).replace("\n", "\\n")


def _named_command(argv: list[str]) -> str | None:
    """The sub-command an argument list names before any other word, or None."""
    for word in argv:
        if word in ("--debug", "--verbose") or (word.startswith("-v")
                                                and set(word[1:]) == {"v"}):
            continue
        return word if word in COMMAND_OF else None
    return None


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The ``nmsid`` parser: every sub-command, or only the one ``argv`` names."""
    named = _named_command(argv) if argv is not None else None  # None: all
    modules = (COMMAND_OF[named],) if named else COMMAND_MODULES
    parser = _OneLineParser(
        prog="nmsid",
        description="FES neuromuscular-system identification: run sessions on a simulated "
                    "or real rig, identify the second-order model per sE, select models "
                    "across sE, and diagnose the sim-to-real gap.")
    parser.add_argument("--debug", action="store_true",
                        help="show full tracebacks instead of one-line error messages")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output: -v info, -vv debug of nmsid's own modules; "
                             "-vvv also debug of the libraries (h5py, matplotlib, ...)")
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in modules:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that command is not part of this build
                continue
            raise
        module.register(sub)
    return parser


def _third_party_missing(exc: BaseException) -> str | None:
    """The name of a missing optional third-party package, or None."""
    if isinstance(exc, ImportError) and not isinstance(exc, NmsidError):
        name = getattr(exc, "name", None)
        if name and not name.split(".")[0] == "nmsid":
            return name
    return None


def _user_os_error(exc: BaseException) -> bool:
    """A file-system error on a path (the user's to fix), not an internal failure."""
    return (isinstance(exc, OSError) and not isinstance(exc, NmsidError)
            and exc.errno in _USER_ERRNOS and exc.filename is not None)


def report(exc: BaseException, command: str) -> int:
    """Print one line for an error the user can act on; return the exit status.

    Returns ``EXIT_BUG`` (and prints nothing) for anything that is not such an error.
    """
    missing = _third_party_missing(exc)
    if missing:
        print(f"nmsid: error: the Python package {missing!r} is needed for "
              f"`nmsid {command}`; install nmsid with the matching extra, e.g. "
              "pip install 'nmsid[gui,plot,serial]'", file=sys.stderr)
        return EXIT_USER_ERROR
    if isinstance(exc, (UserError, MissingDependency)):
        print(f"nmsid: error: {_one_line(str(exc))}", file=sys.stderr)
        return EXIT_USER_ERROR
    if isinstance(exc, OSError) and _user_os_error(exc):
        print(f"nmsid: error: {_one_line(str(exc.filename))}: {exc.strerror}", file=sys.stderr)
        return EXIT_USER_ERROR
    if isinstance(exc, DeviceFault):
        print(f"nmsid: device error: {_one_line(str(exc))}", file=sys.stderr)
        return DeviceFault.exit_code
    if isinstance(exc, SafetyError):
        print(f"nmsid: safety: {_one_line(str(exc))}", file=sys.stderr)
        return SafetyError.exit_code
    return EXIT_BUG


def main(argv: list[str] | None = None) -> int:
    """Run the ``nmsid`` command line; returns the exit status."""
    try:
        status = _main(argv)
        sys.stdout.flush()  # here, not at exit: a closed pipe is met inside the try
        return status
    except BrokenPipeError:
        _to_null_device(sys.stdout)
        return EXIT_CLOSED_PIPE


def _to_null_device(stream) -> None:
    """Point a stream's file descriptor at the null device: its reader is gone, and
    Python's own flush at exit would otherwise report the broken pipe again (the recipe of
    Python's ``signal`` documentation, "Note on SIGPIPE")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, stream.fileno())
        finally:
            os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no descriptor (a test's captured stream)
        pass


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    # third-party loggers (h5py's DEBUG lines flooded -vv, issue 39) stay at WARNING
    # unless -vvv asks for them: only nmsid's own logger follows -v / -vv
    logging.basicConfig(level=level if args.verbose >= 3 else logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.verbose:
        logging.getLogger("nmsid").setLevel(level)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return EXIT_USER_ERROR
    module_name, func_name = handler.split(":")
    if args.command in SINGLE_THREAD_COMMANDS:
        limit_blas_threads()      # before the handler imports numpy
    try:
        func = getattr(importlib.import_module(module_name), func_name)
        with _escaped_output() as streams:
            result = func(args)
    except KeyboardInterrupt:
        print("nmsid: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away: not a bug, nothing to say
        raise
    except Exception as exc:  # noqa: BLE001 - sorted into user errors and bugs below
        if args.debug:
            raise
        status = report(exc, args.command)
        if status == EXIT_BUG:
            traceback.print_exc()
            print(f"nmsid: internal error in `nmsid {args.command}` (a bug, not your "
                  "input): please report it with the traceback above", file=sys.stderr)
        return status
    status = int(result or 0)
    if status == 0 and any(s.closed_pipe for s in streams):
        return EXIT_CLOSED_PIPE  # the work is done; part of what it printed was not read
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
