"""bench/run.py: the results file, the time budget and the missed-targets section.

Benchmarks here are tiny modules written into a temporary folder, so the test runs in
well under a second and checks what the runner writes, not the real benchmarks' figures.
"""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def bench_run(load_bench_script):
    return load_bench_script("run")


def _benches(tmp_path: Path) -> Path:
    d = tmp_path / "benches"
    d.mkdir()
    (d / "bench_alpha.py").write_text(
        "import time\n"
        "def main():\n"
        "    time.sleep(0.05)\n"
        "    print('speed x3.0 against the plain loop (target >= 5x: missed)')\n"
        "    print('found 19/20 = 95 %, Wilson 95 % CI [76, 99] %: point estimate only')\n",
        encoding="utf-8")
    (d / "bench_beta.py").write_text(
        "def main():\n"
        "    print('all targets met')\n"
        "    raise RuntimeError('a bug in beta')\n", encoding="utf-8")
    (d / "bench_gamma.py").write_text(
        "import sys\n"
        "def main():\n    print('Missed: 1 of 3')\n", encoding="utf-8")
    (d / "bench_delta.py").write_text(
        "import argparse\n"
        "def main():\n    argparse.ArgumentParser().parse_args(['--unknown'])\n",
        encoding="utf-8")
    (d / "helper.py").write_text("raise SystemExit('not a benchmark: never run')\n",
                                 encoding="utf-8")
    return d


def test_results_file_has_table_budget_misses_and_failures(bench_run, tmp_path, capsys):
    out = tmp_path / "results.md"
    # the hand-written summary (moved from the README, issue 39) survives the rewrite
    out.write_text("# old run\n## bench_old\n\n" + bench_run.KEPT_MARKER
                   + "\n\n## Summary\nkept line\n", encoding="utf-8")
    rc = bench_run.run([], out, budget_min=0.0005, directory=_benches(tmp_path))
    text = out.read_text(encoding="utf-8")
    assert "bench_old" not in text and text.endswith(bench_run.KEPT_MARKER
                                                     + "\n\n## Summary\nkept line\n")
    printed = capsys.readouterr().out
    assert rc == 1  # beta failed
    assert "- commit: `" in text and "load average (1 min)" in text
    for name in ("bench_alpha", "bench_beta", "bench_gamma"):
        assert f"| [{name}](#{name}) |" in text
        assert f"## {name}" in text
    assert "helper" not in text
    assert "**FAILED**" in text.split("## Time budget")[0]  # beta's row in the table
    assert "RuntimeError: a bug in beta" in text.split("## bench_beta")[1]
    misses = text.split("## Missed targets")[1].split("## bench_alpha")[0]
    assert "- bench_alpha: speed x3.0 against the plain loop (target >= 5x: missed)" in misses
    assert "- bench_gamma: Missed: 1 of 3" in misses
    assert "- bench_beta: FAILED" in misses
    assert "- run.py: whole run 0.0 min, budget 0.0005 min: missed" in misses
    assert "- bench_delta: FAILED" in misses  # a SystemExit (argparse) ends only its bench
    assert "point estimate only" not in misses  # only lines that say missed
    budget = text.split("## Time budget")[1].split("## Missed targets")[0]
    assert "budget 0.0005 min: missed" in budget  # 0.03 s < the run's time
    assert budget.index("bench_alpha") < budget.index("bench_beta")  # slowest first
    assert "min so far)" in printed and "=== missed targets ===" in printed


def test_within_budget_and_no_misses(bench_run, tmp_path):
    d = tmp_path / "ok"
    d.mkdir()
    (d / "bench_fine.py").write_text("def main():\n    print('x2.0 vs baseline')\n",
                                     encoding="utf-8")
    out = tmp_path / "r.md"
    assert bench_run.run([], out, budget_min=30, directory=d) == 0
    text = out.read_text(encoding="utf-8")
    assert "budget 30 min: within" in text
    assert "- none" in text.split("## Missed targets")[1]


def test_partial_run_is_not_written_and_names_select(bench_run, monkeypatch):
    monkeypatch.setattr(bench_run, "run",
                        lambda names, out, budget: (names, out, budget))
    assert bench_run.main(["run.py", "gamma"]) == (["gamma"], None, 30.0)
    assert bench_run.main(["run.py"]) == ([], bench_run.RESULTS, 30.0)
    assert bench_run.main(["run.py", "gamma", "--out", "x.md", "--budget", "20"]) == \
        (["gamma"], Path("x.md"), 20.0)
    with pytest.raises(SystemExit):
        bench_run.main(["run.py", "--budget", "0"])


def test_the_dirty_list_keeps_the_first_path_whole(bench_run, monkeypatch):
    # git status --porcelain starts an unstaged change with a space; stripping the output
    # once turned " M bench/bench_session.py" into "ench/bench_session.py", counted as code
    class Done:
        stdout = " M bench/bench_session.py\n M rig/engine.py\n?? docs/new.md\n"

    monkeypatch.setattr(bench_run.subprocess, "run", lambda *a, **k: Done())
    assert bench_run._code_changes() == ["rig/engine.py"]


def test_every_benchmark_main_runs_without_arguments():
    # bench/run.py calls each bench_*.py's main() with no arguments: a main that needs one
    # fails only in the whole run (bench_myoleg's main(argv) did, round 37)
    import ast

    bench_dir = Path(__file__).resolve().parents[1] / "bench"
    scripts = sorted(bench_dir.glob("bench_*.py"))
    assert len(scripts) > 30
    needing = []
    for script in scripts:
        tree = ast.parse(script.read_text(encoding="utf-8"))
        (main,) = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main"]
        args = main.args
        positional = args.posonlyargs + args.args
        if len(args.defaults) < len(positional) or None in args.kw_defaults:
            needing.append(script.name)
    assert needing == []
