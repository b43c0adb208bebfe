"""Where the faithful fakes of the vendor libraries live, and how to load them.

The fakes (``tests/drivers/fakes/``) stand in for McsUsbNet, CAIO, nidaqmx and the
Leptrino sensor so that ``nmsid probe`` and ``nmsid run --backend hw`` can be exercised
without hardware: set ``fake = true`` in the ``[rig]`` table of the hardware
configuration, or the environment variable ``NMSID_HW_FAKE=1``. The fakes are found in
the source checkout next to this package, or in the folder named by ``NMSID_HW_FAKES``.
They are loaded as the package ``nmsid_hw_fakes``. Never use them with a participant.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from pathlib import Path
from types import ModuleType

PACKAGE = "nmsid_hw_fakes"


def fakes_dir() -> Path:
    env = os.environ.get("NMSID_HW_FAKES")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1] / "tests" / "drivers" / "fakes"


def fake_requested(config_says: bool = False) -> bool:
    return config_says or os.environ.get("NMSID_HW_FAKE", "") not in ("", "0", "false")


def load_fake(module: str) -> ModuleType:
    """Import ``nmsid_hw_fakes.<module>`` from :func:`fakes_dir`.

    Raises
    ------
    FileNotFoundError
        If the fakes are not there (an installed copy without the tests folder).
    """
    folder = fakes_dir()
    if PACKAGE not in sys.modules:
        if not (folder / f"{module}.py").is_file():
            raise FileNotFoundError(
                f"hardware fakes not found in {folder} (fake = true needs the source "
                "checkout's tests/drivers/fakes, or NMSID_HW_FAKES pointing to it)")
        spec = importlib.util.spec_from_loader(PACKAGE, loader=None, is_package=True)
        pkg = importlib.util.module_from_spec(spec)
        pkg.__path__ = [str(folder)]
        sys.modules[PACKAGE] = pkg
    return importlib.import_module(f"{PACKAGE}.{module}")
