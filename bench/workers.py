"""Worker processes for the benchmarks, the same on Windows as on Linux.

The pools start their workers by spawn on every platform (:data:`MP_CONTEXT`; fork, Linux's
default, would inherit the parent's modules, and its threads' locks). Each worker is a fresh
interpreter that unpickles the worker function by ``module.qualname`` and imports that
module itself. A bench script loaded under another name than its file's (tests/conftest.py's
``load_bench_script`` registers ``bench_<stem>_under_test``) then fails in every worker
with ``ModuleNotFoundError``. :func:`importable` hands the pool the same function as found
by importing the script under its own file name (``bench/`` on ``sys.path``, which spawned
workers inherit), and :func:`process_pool` opens the pool with :data:`MP_CONTEXT`
(tests/test_bench_spawn.py).

    with process_pool(jobs) as ex:
        rows = list(ex.map(importable(run_case), cases))
"""

from __future__ import annotations

import importlib
import multiprocessing
import os
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.context import BaseContext
from pathlib import Path
from typing import TypeVar

HERE = Path(__file__).resolve().parent

#: The start method of the benchmarks' pools: spawn on every platform, as Windows and
#: macOS start them. Not fork: ``bench/run.py`` runs every benchmark in one process, which
#: by then holds other benchmarks' threads (liblsl's, Qt's), and a forked child of a
#: threaded process may crash (POSIX fork: only async-signal-safe calls are safe in the
#: child; Python 3.12 warns of it). Seen: after bench_lsl, every forked worker of
#: bench_muscle and bench_musculoskeletal died at once in libc (SIGSEGV).
MP_CONTEXT: BaseContext | None = multiprocessing.get_context("spawn")

F = TypeVar("F", bound=Callable)


def importable(func: F) -> F:
    """``func`` as a fresh process finds it: for a function of a ``bench/`` script, the
    attribute of the script imported by its file name. Unchanged when the script is
    registered under that name already (``bench/run.py``) and for functions of other
    modules (a test's fake: importable by its own name). A script run as ``__main__``
    (``python bench/x.py``) is resolved the same way: one behaviour everywhere."""
    module = sys.modules.get(func.__module__)
    path = getattr(module, "__file__", None)
    if path is None or Path(path).resolve().parent != HERE:
        return func                    # not a bench script: importable by its own name
    stem = Path(path).stem
    if func.__module__ == stem:
        return func
    if str(HERE) not in sys.path:
        sys.path.insert(0, str(HERE))
    target = importlib.import_module(stem)
    for part in func.__qualname__.split("."):
        target = getattr(target, part)
    return target  # type: ignore[return-value]


def process_pool(jobs: int) -> ProcessPoolExecutor:
    """A pool of ``jobs`` worker processes started by :data:`MP_CONTEXT`'s method."""
    if str(HERE) not in sys.path:      # spawned workers import the scripts from bench/
        sys.path.insert(0, str(HERE))
    return ProcessPoolExecutor(jobs, mp_context=MP_CONTEXT)


def child_env() -> dict:
    """The environment of a timed child process (``python -m nmsid ...``): this one's, with
    the checkout first on ``PYTHONPATH`` so the child runs the code under test."""
    env = dict(os.environ)
    root = str(HERE.parent)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH")
                                else "")
    return env
