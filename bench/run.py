"""Run every benchmark in bench/ (``bench_*.py``) and print its figures.

Each benchmark module has ``main() -> None`` that prints a table. Benchmarks are not tests:
they measure speed and accuracy and print figures (and ratios against a baseline run in
the same process); nothing here fails a build.

    python bench/run.py                 # all
    python bench/run.py identification  # those whose name contains the word
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    wanted = argv[1:]
    for path in sorted(HERE.glob("bench_*.py")):
        if wanted and not any(w in path.stem for w in wanted):
            continue
        print(f"\n=== {path.stem} ===", flush=True)
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[path.stem] = module  # dataclasses look their module up by name
        sys.path.insert(0, str(HERE))
        spec.loader.exec_module(module)
        t0 = time.perf_counter()
        module.main()
        print(f"({path.stem} took {time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
