"""Run every benchmark in bench/ (``bench_*.py``), print its figures, and write them to one file.

Each benchmark module has ``main() -> None`` that prints its figures (each with a ratio
against the fairest baseline run in the same process). Benchmarks are not tests: nothing
here fails a build.

    python bench/run.py                        # all, printed and written to docs/benchmarks.md
    python bench/run.py identification gap     # those whose name contains a word (printed only)
    python bench/run.py --out FILE             # write the results file elsewhere

``docs/benchmarks.md`` is the one place the README and docs quote figures from. It names
the commit whose code was measured, the date, the machine and its load, and holds every
benchmark's printed output from that one run. A run with uncommitted changes outside
``bench/`` and ``docs/`` says so at the top (its figures then belong to no commit).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import importlib.util
import io
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = ROOT / "docs" / "benchmarks.md"


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


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f", {kb / 2**20:.0f} GiB memory"
    except (OSError, ValueError, IndexError):
        pass
    import numpy  # the benchmarks' own dependency
    return (f"{cpu}, {os.cpu_count()} cores{mem}; {platform.system()} {platform.release()}; "
            f"Python {platform.python_version()}, numpy {numpy.__version__}")


def _code_changes() -> list[str]:
    """Uncommitted changes outside bench/ and docs/ (figures of such a run fit no commit)."""
    lines = _git("status", "--porcelain").splitlines()
    paths = [ln[3:] for ln in lines if ln[3:]]
    return [p for p in paths if not p.startswith(("bench/", "docs/", "README.md"))]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def run(names: list[str], out: Path | None) -> int:
    if str(HERE) not in sys.path:
        sys.path.insert(0, str(HERE))
    sections = []
    started = _dt.datetime.now(_dt.timezone.utc)
    load0 = os.getloadavg()[0]
    for path in sorted(HERE.glob("bench_*.py")):
        if names and not any(w in path.stem for w in names):
            continue
        print(f"\n=== {path.stem} ===", flush=True)
        tee = _Tee(sys.stdout)
        la = os.getloadavg()[0]
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(tee):
            _load(path).main()
        took = time.perf_counter() - t0
        lb = os.getloadavg()[0]
        print(f"({path.stem} took {took:.1f} s)", flush=True)
        sections.append((path.stem, took, la, lb, tee.copy.getvalue()))
    if out is None:
        return 0
    commit = _git("rev-parse", "HEAD")
    dirty = _code_changes()
    total = sum(s[1] for s in sections)
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
        f"- load average (1 min): {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end",
        "",
        "| benchmark | took | load before -> after |",
        "|---|---|---|",
        *[f"| [{name}](#{name}) | {took:.1f} s | {la:.2f} -> {lb:.2f} |"
          for name, took, la, lb, _ in sections],
        "",
    ]
    body = []
    for name, took, la, lb, text in sections:
        body += [f"## {name}", "", "```", text.strip("\n"), "```", ""]
    out.write_text("\n".join(head + body), encoding="utf-8")
    print(f"\nwrote {out}", flush=True)
    return 0


def main(argv: list[str]) -> int:
    args = argv[1:]
    out: Path | None = RESULTS
    if "--out" in args:
        i = args.index("--out")
        out = Path(args[i + 1])
        del args[i:i + 2]
    if args and "--out" not in argv[1:]:
        out = None  # a partial run is printed, never written over the whole run's file
    return run(args, out)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
