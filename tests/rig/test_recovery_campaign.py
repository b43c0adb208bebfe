"""A small kill-and-damage campaign (issue 26, 7; the 30-run version is
bench/bench_recovery_campaign.py): real ``nmsid`` processes killed with SIGKILL at random
moments, one journal entry or the header damaged, then ``recover`` and ``run --resume``."""

import importlib.util
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.rig.forked_cli import fork_main

ROOT = Path(__file__).resolve().parents[2]


def _campaign_module():
    spec = importlib.util.spec_from_file_location(
        "bench_recovery_campaign", ROOT / "bench" / "bench_recovery_campaign.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


class _Forked:
    """``nmsid`` in a forked child (imports shared: no interpreter start-up), with the
    part of ``subprocess.Popen``'s interface the campaign uses."""

    def __init__(self, argv, log, env):
        self.pid = fork_main(argv, log)
        self.code = None

    def poll(self):
        if self.code is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.code = os.waitstatus_to_exitcode(status)
        return self.code

    def wait(self, timeout=None):
        t0 = time.monotonic()
        while self.poll() is None:
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise subprocess.TimeoutExpired("nmsid", timeout)
            time.sleep(0.005)
        return self.code


@pytest.mark.timeout(240)
def test_three_kills_with_damage_keep_every_intact_trial_and_repeat_none(tmp_path):
    camp = _campaign_module()
    import nmsid.cli
    import nmsid.rig.engine
    import nmsid.sim_backends.rig  # noqa: F401
    rng = random.Random(2611)
    # three kills, more while none landed with a journal to damage (a fast-clock session of
    # four trials may end before a kill; at most 9 runs)
    results = []
    while len(results) < 3 or (not any(camp.damaged(r) for r in results)
                               and len(results) < 9):
        results.append(camp.one_run(tmp_path, len(results), rng, levels=(0.4, 0.8),
                                    max_kill_s=0.03, launch=_Forked))
    for r in results:
        assert r.tracebacks == 0, r
        assert (r.valid and r.all_done) or not r.resumable, r
        assert r.kept == r.intact, r        # every intact completed trial kept
        assert r.twice == 0, r              # no completed trial stimulated again
    # the campaign really killed sessions with trials completed, and damaged them
    assert sum(r.completed for r in results) >= 1
    assert any(camp.damaged(r) for r in results), results
