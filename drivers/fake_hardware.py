"""How the faithful fakes of the vendor libraries are loaded.

The fakes (package ``testing.fakes``, shipped with nmsid) stand in for McsUsbNet, CAIO,
nidaqmx and the Leptrino sensor so that ``nmsid probe`` and ``nmsid run --backend hw`` can
be exercised without hardware: set ``fake = true`` in the ``[rig]`` table of the hardware
configuration, or the environment variable ``NMSID_HW_FAKE=1``. Never use them with a
participant.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType

#: The package that holds the fakes.
PACKAGE = "nmsid.testing.fakes"


def fake_requested(config_says: bool = False) -> bool:
    return config_says or os.environ.get("NMSID_HW_FAKE", "") not in ("", "0", "false")


def load_fake(module: str) -> ModuleType:
    """Import the fake ``module`` (``fake_mcs_usb``, ``fake_caio``, ...) of :data:`PACKAGE`."""
    return importlib.import_module(f"{PACKAGE}.{module}")
