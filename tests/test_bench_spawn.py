"""The benchmarks' worker pools on Windows' start method (spawn), run here on Linux.

A spawned worker is a fresh interpreter: it unpickles the worker function by module name and
imports that module itself, so a bench script loaded under another name (conftest's
``load_bench_script``) or a worker defined where a fresh process cannot import it fails in
every worker. bench/workers.py hands the pools importable functions; this runs
bench_control's pool by spawn on two tiny items (a participant model that does not exist:
each worker imports the script, runs ``_one_safe`` and returns its one-line failure)."""

from __future__ import annotations

import multiprocessing
import sys

import pytest

from nmsid.testing.platforms import WINE_PROCESS_POOL


@pytest.fixture
def spawn_workers(load_bench_script, monkeypatch):
    b = load_bench_script("bench_control")
    workers = sys.modules["workers"]
    monkeypatch.setattr(workers, "MP_CONTEXT", multiprocessing.get_context("spawn"))
    return b, workers


@pytest.mark.wine_gap(WINE_PROCESS_POOL)
def test_a_bench_pool_runs_its_workers_by_spawn(spawn_workers, tmp_path):
    b, workers = spawn_workers
    assert b.__name__ != "bench_control"          # loaded under a test-only name
    work = [("no-such-model", 0, str(tmp_path), 1), ("no-such-model-2", 0, str(tmp_path), 1)]
    got = b.outcomes_of(work, 2)
    assert [r for r, _ in got] == [None, None]
    assert "no-such-model" in got[0][1] and "no-such-model-2" in got[1][1]
    # the in-process path says the same
    assert b.outcomes_of(work, 1) == got


def test_importable_resolves_a_script_loaded_under_another_name(spawn_workers):
    b, workers = spawn_workers
    f = workers.importable(b._one_safe)
    assert f.__module__ == "bench_control" and f.__qualname__ == "_one_safe"
    assert workers.importable(f) is f               # already importable: unchanged
    # what the pool would send without it: a module a fresh process cannot import
    assert b._one_safe.__module__ not in ("bench_control", "__main__")


def test_bench_pools_start_their_workers_by_spawn_everywhere(load_bench_script):
    # bench/run.py runs every benchmark in one process that by then holds other
    # benchmarks' threads (liblsl's): forked workers died at once in libc after bench_lsl
    load_bench_script("bench_control")
    workers = sys.modules["workers"]
    assert workers.MP_CONTEXT is not None
    assert workers.MP_CONTEXT.get_start_method() == "spawn"
