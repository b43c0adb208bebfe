"""``nmsid run`` loads only what a session uses: a simulated session without --track and
with --no-identify imports neither the identification, plotting nor the tracking
controller. Each of these cost 0.2-1 s of start-up (bench/bench_session.py, whole process).
The simulator filters through public ``scipy.signal`` (protocols/lti_kernels.py), so scipy
is loaded (issue 38: start-up is a reported figure, not a reason to copy a library)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

NOT_FOR_A_PLAIN_SESSION = ("matplotlib", "nmsid.analysis.run", "nmsid.analysis.identify",
                           "nmsid.rig.tracking", "nmsid.analysis.control")

_CODE = """
import json, sys, logging
from pathlib import Path
logging.disable(logging.WARNING)
import nmsid.cli.run_command  # the handler of nmsid run, as the command line loads it
from nmsid.protocols.config import config_from_dict
from nmsid.rig.engine import Engine, TripPolicy
from nmsid.sim_backends import make_sim_rig
cfg = config_from_dict({"participant": "T01", "seed": 1,
                        "protocol": {"rest_s": 0.0, "sE_levels": [0.5], "repeats": 1}})
summary = Engine(cfg, make_sim_rig(seed=1), Path(sys.argv[1]),
                 trip_policy=TripPolicy.END_SESSION).run()
print(json.dumps({"completed": summary.n_completed, "modules": sorted(sys.modules)}))
"""


def test_a_simulated_session_imports_no_identification_plotting_or_tracking(tmp_path):
    out = subprocess.run([sys.executable, "-c", _CODE, str(tmp_path / "s.h5")],
                         capture_output=True, text=True, check=True, cwd=ROOT,
                         timeout=120).stdout
    got = json.loads(out.strip().splitlines()[-1])
    assert got["completed"] == 1                      # the session did run a trial
    loaded = [m for m in got["modules"]
              if any(m == p or m.startswith(p + ".") for p in NOT_FOR_A_PLAIN_SESSION)]
    assert loaded == []
