"""One entry point for setting up and running nmsid, on Windows, macOS and Linux alike.

    python3 dev.py demo      (Windows: py dev.py demo)
    python3 dev.py test [--windows-emulation] [-- PYTEST ARGS...]
    python3 dev.py bench
    python3 dev.py gui
    python3 dev.py clean

Each command creates ``.venv`` beside this file (``.venv/Scripts/python.exe`` on Windows,
``.venv/bin/python`` elsewhere) and installs nmsid into it, editable, with every extra, on
first use; it installs again when pyproject.toml has changed since (a stamp file in .venv
named after pyproject.toml's hash). Plain Python, standard library only: it runs before
anything is installed, so no ``make``, ``cksum`` or shell is needed. The Makefile calls it.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
# mcs (pythonnet): the STG driver on Windows, and the check of its .NET surface against the
# real McsUsbNet assembly under mono in the tests
EXTRAS = "gui,plot,serial,test,mujoco,nwb,study,mcs,lsl"
MIN_PYTHON = (3, 11)
#: One BLAS thread per process: the suite runs on two pytest workers over two cores, and
#: small matrix operations get slower, not faster, with threads competing for them.
TEST_ENV = {"QT_QPA_PLATFORM": "offscreen", "OPENBLAS_NUM_THREADS": "1"}


def venv_python(venv_dir: Path = VENV, windows: bool | None = None) -> Path:
    """The venv's interpreter: ``Scripts/python.exe`` on Windows, ``bin/python`` elsewhere.

    ``windows`` defaults to this machine (``os.name``: the venv's layout is the real
    system's, whatever nmsid's platform switch says; nmsid is not installed yet here).
    """
    if windows is None:
        windows = os.name == "nt"
    return venv_dir / ("Scripts/python.exe" if windows else "bin/python")


def stamp_path(venv_dir: Path = VENV, pyproject: Path = ROOT / "pyproject.toml") -> Path:
    """The file whose presence says: installed from this pyproject.toml."""
    digest = hashlib.sha256(pyproject.read_bytes()).hexdigest()[:16]
    return venv_dir / f".installed-{digest}"


def ensure_venv(venv_dir: Path = VENV) -> Path:
    """Create the venv and install nmsid with its extras if needed; return its python."""
    py = venv_python(venv_dir)
    stamp = stamp_path(venv_dir)
    if py.exists() and stamp.exists():
        return py
    if not py.exists():
        print(f"dev.py: creating {venv_dir}", flush=True)
        venv.EnvBuilder(with_pip=True).create(venv_dir)
    print(f"dev.py: installing nmsid[{EXTRAS}] into {venv_dir} (first use, or "
          "pyproject.toml changed)", flush=True)
    _run([py, "-m", "pip", "install", "--quiet", "--upgrade", "pip"])
    _run([py, "-m", "pip", "install", "--quiet", "-e", f".[{EXTRAS}]"])
    for old in venv_dir.glob(".installed-*"):
        old.unlink()
    stamp.touch()
    return py


def _run(cmd: list, env: dict | None = None) -> int:
    merged = dict(os.environ, **(env or {}))
    code = subprocess.call([str(c) for c in cmd], cwd=str(ROOT), env=merged)
    if code and cmd[1:3] == ["-m", "pip"]:
        sys.exit(f"dev.py: {' '.join(str(c) for c in cmd[1:])} failed (exit {code})")
    return code


def pytest_args(extra: list[str], windows_emulation: bool = False) -> list[str]:
    """The README's test command: ``pytest -q -n 2`` plus the given arguments."""
    args = ["-m", "pytest", "-q"]
    if "no:xdist" not in extra and not any(a == "-n" or a.startswith("-n") and a[2:].isdigit()
                                           for a in extra):
        args += ["-n", "2"]
    if windows_emulation:
        args.append("--windows-emulation")
    return args + extra


def main(argv: list[str] | None = None) -> int:
    """Run one command (see the module docstring); returns its exit status."""
    if sys.version_info < MIN_PYTHON:
        sys.exit(f"dev.py: nmsid needs Python {'.'.join(map(str, MIN_PYTHON))} or newer; "
                 f"this is {sys.version.split()[0]} ({sys.executable})")
    argv = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1:]
    parser = argparse.ArgumentParser(prog="dev.py", description=__doc__.split("\n")[0])
    parser.add_argument("command", choices=["demo", "test", "bench", "gui", "clean"])
    parser.add_argument("--windows-emulation", action="store_true",
                        help="test: run the suite under nmsid.testing.windows_emulation")
    args = parser.parse_args(argv)
    if args.command == "clean":
        for p in (VENV, ROOT / "build", *ROOT.glob("*.egg-info")):
            shutil.rmtree(p, ignore_errors=True)
        return 0
    py = ensure_venv()
    if args.command == "demo":
        return _run([py, "-m", "nmsid", "run", "--backend", "sim", "--participant", "DEMO",
                     "--outdir", "sessions", *extra])
    if args.command == "test":
        return _run([py, *pytest_args(extra, args.windows_emulation)], env=TEST_ENV)
    if args.command == "bench":
        return _run([py, "bench/run.py", *extra], env=TEST_ENV)
    return _run([py, "-m", "nmsid", "gui", "--backend", "sim", *extra])


if __name__ == "__main__":
    sys.exit(main())
