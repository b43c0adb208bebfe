"""The ``nmsid`` command: one entry point, one sub-command per job.

Each sub-command lives in the module of the package that does the job and exposes
``register(subparsers)``; registering imports nothing heavy, so ``nmsid --help`` is
instant. The handler named by the sub-command (``"module:function"``) is imported only when
it runs. User mistakes (bad file, bad setting) end in one clear line and exit status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

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
)

EXIT_USER_ERROR = 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nmsid",
        description="FES neuromuscular-system identification: run sessions on a simulated "
                    "or real rig, identify the second-order model per sE, select models "
                    "across sE, and diagnose the sim-to-real gap.")
    parser.add_argument("--debug", action="store_true",
                        help="show full tracebacks instead of one-line error messages")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output (-v info, -vv debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that command is not part of this build
                continue
            raise
        module.register(sub)
    return parser


def _user_error_types() -> tuple[type[BaseException], ...]:
    return (ValueError, OSError, KeyError, ImportError, RuntimeError)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)],
        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return EXIT_USER_ERROR
    module_name, func_name = handler.split(":")
    try:
        func = getattr(importlib.import_module(module_name), func_name)
        result = func(args)
    except KeyboardInterrupt:
        print("nmsid: interrupted", file=sys.stderr)
        return 130
    except _user_error_types() as exc:
        if args.debug:
            raise
        if isinstance(exc, ImportError) and getattr(exc, "name", None):
            print(f"nmsid: error: the Python package {exc.name!r} is needed for "
                  f"`nmsid {args.command}`; install nmsid with the matching extra, e.g. "
                  "pip install 'nmsid[gui,plot,serial]'", file=sys.stderr)
        else:
            print(f"nmsid: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    return int(result or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
