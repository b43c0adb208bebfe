"""The digital twin as an FMI 2.0 FMU (``nmsid twin export TWIN.json --fmu``); see
``docs/fmu.md``."""

from nmsid.export.fmu.build import FmuResult, check_exportable, export_fmu

__all__ = ["FmuResult", "check_exportable", "export_fmu"]
