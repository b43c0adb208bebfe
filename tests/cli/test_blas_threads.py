"""``nmsid identify`` and ``nmsid qc`` start with one BLAS thread unless the user chose a
count: their many small solves lose more to worker threads than they gain (on a loaded
2-core machine 5.9-8.3 s of CPU instead of 1.3-1.5 s for a 45-trial session)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from nmsid.cli import BLAS_THREAD_VARIABLES, SINGLE_THREAD_COMMANDS, limit_blas_threads


def test_unset_variables_are_set_to_one_and_a_users_choice_is_kept():
    env = {"MKL_NUM_THREADS": "4"}
    chosen = limit_blas_threads(env)
    assert chosen == ["OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"]
    assert env == {"MKL_NUM_THREADS": "4", "OPENBLAS_NUM_THREADS": "1",
                   "OMP_NUM_THREADS": "1"}
    assert limit_blas_threads(env) == []          # a second call changes nothing


_PROBE = """
import json, sys
from nmsid.cli import main
before = "numpy" in sys.modules
code = main(sys.argv[1:])
import os
print(json.dumps({"numpy_before": before, "code": code,
                  "env": {k: os.environ.get(k) for k in %r}}))
"""


def _run(args, tmp_path, **extra):
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    env.update(extra)
    proc = subprocess.run([sys.executable, "-c", _PROBE % (BLAS_THREAD_VARIABLES,)] + args,
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_identify_sets_the_count_before_numpy_is_imported(tmp_path):
    # a file that is not a session: the handler is imported (numpy with it), then refuses
    bad = tmp_path / "not_a_session.h5"
    bad.write_bytes(b"not hdf5")
    out = _run(["identify", str(bad), "--out", str(tmp_path / "o"), "--no-figures"],
               tmp_path, MKL_NUM_THREADS="3")
    assert "identify" in SINGLE_THREAD_COMMANDS
    assert out["numpy_before"] is False           # registration imports no numpy
    assert out["code"] == 2
    assert out["env"] == {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "3",
                          "OMP_NUM_THREADS": "1"}


def test_other_commands_keep_the_default(tmp_path):
    out = _run(["validate", str(tmp_path / "missing.toml")], tmp_path)
    assert out["env"] == dict.fromkeys(BLAS_THREAD_VARIABLES)
