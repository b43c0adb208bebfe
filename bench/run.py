"""Run every benchmark in bench/ (``bench_*.py``), print its figures, and write them to one file.

Each benchmark module has ``main() -> None`` that prints its figures (each with a ratio
against the fairest baseline run in the same process, and "missed" beside a target it
misses). Benchmarks are not tests: nothing here fails a build.

    python bench/run.py                        # all, printed and written to docs/benchmarks.md
    python bench/run.py identification gap     # those whose name contains a word (printed only)
    python bench/run.py --out FILE             # write the results file elsewhere
    python bench/run.py --budget 30            # the whole run's time budget, minutes (default 30)

``docs/benchmarks.md`` is the one place the README and docs quote figures from. It names
the commit whose code was measured, the date, the machine and its load, and holds every
benchmark's printed output from that one run, a time summary against the budget, and every
line a benchmark printed with "missed" in it (the missed targets, in one place). A run
with uncommitted changes outside ``bench/`` and ``docs/`` says so at the top (its figures
then belong to no commit). A benchmark that raises is reported (its traceback in its
section, "FAILED" in the table) and the run goes on to the next.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime as _dt
import importlib.util
import io
import os
import platform
import re
import subprocess
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = ROOT / "docs" / "benchmarks.md"
BUDGET_MIN = 30.0
"""The whole run's time budget on 2 idle cores, minutes (the integrator's window)."""
SLOWEST = 8
"""How many of the slowest benchmarks the budget summary names."""
_MISSED = re.compile(r"\bmissed\b", re.IGNORECASE)


@dataclasses.dataclass
class Section:
    """One benchmark's run: its name, wall time, load before/after and what it printed."""

    name: str
    took_s: float
    load_before: float
    load_after: float
    text: str
    failed: bool = False

    def misses(self) -> list[str]:
        """Every printed line that says "missed" (a missed target), stripped."""
        return [ln.strip() for ln in self.text.splitlines() if _MISSED.search(ln)]


class _Tee(io.TextIOBase):
    """Write to the console and keep a copy."""

    def __init__(self, console):
        self.console = console
        self.copy = io.StringIO()

    def write(self, text: str) -> int:
        self.console.write(text)
        self.console.flush()
        return self.copy.write(text)

    def flush(self) -> None:
        self.console.flush()


def _git(*args: str, strip: bool = True) -> str:
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout
        return out.strip() if strip else out
    except (OSError, subprocess.CalledProcessError):
        return ""


def _load_average() -> float:
    """The 1-min load average, or NaN where the OS has none (Windows)."""
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return float("nan")


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text(encoding="utf-8").split()[1])
        mem = f", {kb / 2**20:.0f} GiB memory"
    except (OSError, ValueError, IndexError):
        pass
    import numpy  # the benchmarks' own dependency
    return (f"{cpu}, {os.cpu_count()} cores{mem}; {platform.system()} {platform.release()}; "
            f"Python {platform.python_version()}, numpy {numpy.__version__}")


def _code_changes() -> list[str]:
    """Uncommitted changes outside bench/ and docs/ (figures of such a run fit no commit)."""
    # not stripped: porcelain's first column is a space for a change not staged
    lines = _git("status", "--porcelain", strip=False).splitlines()
    paths = [ln[3:] for ln in lines if ln[3:]]
    return [p for p in paths if not p.startswith(("bench/", "docs/", "README.md"))]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"{path}: not a loadable Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def budget_lines(sections: list[Section], budget_min: float) -> list[str]:
    """The time summary: whole run against the budget, and the slowest benchmarks."""
    total = sum(s.took_s for s in sections)
    verdict = "within" if total <= budget_min * 60 else "missed"
    out = [f"whole run {total / 60:.1f} min for {len(sections)} benchmark(s); budget "
           f"{budget_min:g} min: {verdict} ({total / (budget_min * 60):.2f} of it)"]
    for s in sorted(sections, key=lambda s: -s.took_s)[:SLOWEST]:
        out.append(f"  {s.name:28s} {s.took_s:7.1f} s  {100 * s.took_s / max(total, 1e-9):5.1f} %"
                   + ("  FAILED" if s.failed else ""))
    return out


def miss_lines(sections: list[Section], budget_min: float = BUDGET_MIN) -> list[str]:
    """Every "missed" line of the run, each behind its benchmark's name; failures and a
    whole run over its budget too."""
    total = sum(s.took_s for s in sections)
    out = [f"run.py: whole run {total / 60:.1f} min, budget {budget_min:g} min: missed"] \
        if total > budget_min * 60 else []
    out += [f"{s.name}: FAILED (see its section)" for s in sections if s.failed]
    for s in sections:
        out += [f"{s.name}: {ln}" for ln in s.misses()]
    return out


def run_one(path: Path) -> Section:
    """Run one benchmark's ``main()``, printing and keeping what it prints."""
    tee = _Tee(sys.stdout)
    la = _load_average()
    t0 = time.perf_counter()
    failed = False
    with contextlib.redirect_stdout(tee):
        try:
            _load(path).main()
        except (Exception, SystemExit):  # noqa: BLE001 - one bug must not cost the run
            failed = True
            print(f"FAILED:\n{traceback.format_exc()}")
    return Section(path.stem, time.perf_counter() - t0, la, _load_average(),
                   tee.copy.getvalue(), failed)


def write_results(out: Path, sections: list[Section], started: _dt.datetime, load0: float,
                  budget_min: float) -> None:
    """Write the results file (docs/benchmarks.md)."""
    commit = _git("rev-parse", "HEAD")
    dirty = _code_changes()
    total = sum(s.took_s for s in sections)
    misses = miss_lines(sections, budget_min)
    head = [
        "# Benchmark results",
        "",
        "Written by `make bench` (`bench/run.py`); README.md and docs/ quote figures from this "
        "file only. Timings are wall-clock on the machine below; every speed figure carries "
        "its baseline from the same run.",
        "",
        f"- commit: `{commit or 'unknown'}`"
        + (f" **plus uncommitted changes to {', '.join(dirty)}**" if dirty else ""),
        f"- date: {started:%Y-%m-%d %H:%M} UTC; whole run {total / 60:.1f} min",
        f"- machine: {_machine()}",
        f"- load average (1 min): {load0:.2f} at the start, {_load_average():.2f} at the end",
        "",
        "| benchmark | took | load before -> after |",
        "|---|---|---|",
        *[f"| [{s.name}](#{s.name}) | {s.took_s:.1f} s"
          + (" **FAILED**" if s.failed else "") + f" | {s.load_before:.2f} -> "
          f"{s.load_after:.2f} |" for s in sections],
        "",
        "## Time budget",
        "",
        "```",
        *budget_lines(sections, budget_min),
        "```",
        "",
        "## Missed targets",
        "",
        "Every line a benchmark printed with \"missed\" in it (and any benchmark that failed):",
        "",
        *([f"- {m}" for m in misses] or ["- none"]),
        "",
    ]
    body = []
    for s in sections:
        body += [f"## {s.name}", "", "```", s.text.strip("\n"), "```", ""]
    out.write_text("\n".join(head + body) + _kept_part(out), encoding="utf-8")


#: The results file's hand-written part (the one-line summary moved from the README) starts
#: at this line; a rewrite keeps it.
KEPT_MARKER = ("<!-- bench/run.py keeps everything below this line when it rewrites the file "
               "above -->")


def _kept_part(out: Path) -> str:
    """The part of an existing results file from :data:`KEPT_MARKER` on, else ""."""
    try:
        old = out.read_text(encoding="utf-8")
    except OSError:
        return ""
    at = old.find(KEPT_MARKER)
    return "" if at < 0 else "\n" + old[at:]


def run(names: list[str], out: Path | None, budget_min: float = BUDGET_MIN,
        directory: Path = HERE) -> int:
    """Run the benchmarks of ``directory`` whose name contains one of ``names`` (all if
    none); write ``out`` when given. Returns 1 if a benchmark failed, else 0."""
    if str(directory) not in sys.path:
        sys.path.insert(0, str(directory))
    sections: list[Section] = []
    started = _dt.datetime.now(_dt.UTC)
    load0 = _load_average()
    for path in sorted(directory.glob("bench_*.py")):
        if names and not any(w in path.stem for w in names):
            continue
        print(f"\n=== {path.stem} ===", flush=True)
        sections.append(run_one(path))
        s = sections[-1]
        so_far = sum(x.took_s for x in sections)
        print(f"({s.name} {'FAILED after' if s.failed else 'took'} {s.took_s:.1f} s; "
              f"{so_far / 60:.1f} min so far)", flush=True)
    print("\n=== time budget ===")
    print("\n".join(budget_lines(sections, budget_min)))
    print("\n=== missed targets ===")
    print("\n".join(miss_lines(sections, budget_min)) or "none")
    if out is not None:
        write_results(out, sections, started, load0, budget_min)
        print(f"\nwrote {out}", flush=True)
    return int(any(s.failed for s in sections))


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench/run.py", description=__doc__.split("\n")[0])
    parser.add_argument("names", nargs="*",
                        help="run only benchmarks whose name contains one of these words "
                             "(printed, not written, unless --out is given)")
    parser.add_argument("--out", type=Path, default=None,
                        help=f"results file (default {RESULTS.relative_to(ROOT)} for a whole run)")
    parser.add_argument("--budget", type=float, default=BUDGET_MIN, metavar="MIN",
                        help=f"the whole run's time budget, minutes (default {BUDGET_MIN:g})")
    args = parser.parse_args(argv[1:])
    if args.budget <= 0:
        parser.error(f"--budget {args.budget:g}: give a positive number of minutes")
    out = args.out
    if out is None and not args.names:
        out = RESULTS  # a partial run is printed, never written over the whole run's file
    return run(args.names, out, args.budget)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
