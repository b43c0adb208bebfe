"""``nmsid identify --no-figures`` loads only what the run uses: not the drawing code
(``nmsid.analysis.figures``, matplotlib), not the TOML reader (no settings file is read),
not the exporters. Each import is start-up time of every run (bench/bench_identify_io.py,
whole process). scipy is loaded: the analysis filters and fits through its public
packages (issue 38)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

NOT_FOR_NO_FIGURES = ("nmsid.analysis.figures", "nmsid.analysis.plot_style", "matplotlib",
                      "tomllib", "nmsid.export")

_CODE = """
import json, sys
import nmsid.cli.identify_command
after_import = sorted(sys.modules)
from nmsid.cli import main
status = main(["identify", sys.argv[1], "--out", sys.argv[2], "--no-figures"])
print(json.dumps({"status": status, "import": after_import, "run": sorted(sys.modules)}))
"""


def _loaded(modules: list[str]) -> list[str]:
    return [m for m in modules
            if any(m == p or m.startswith(p + ".") for p in NOT_FOR_NO_FIGURES)]


def test_identify_without_figures_imports_no_drawing_toml_or_export(small_session, tmp_path):
    path, _ = small_session
    out = tmp_path / "out"
    text = subprocess.run([sys.executable, "-c", _CODE, str(path), str(out)],
                          capture_output=True, text=True, check=True, cwd=ROOT,
                          timeout=120).stdout
    got = json.loads(text.strip().splitlines()[-1])
    assert got["status"] == 0 and (out / "twin.json").exists()   # the run did run
    assert _loaded(got["import"]) == []
    assert _loaded(got["run"]) == []
    # the handler's import does load what every run needs (the guard is not vacuous)
    assert "nmsid.analysis.run" in got["import"] and "h5py" in got["import"]
