"""nmsid: FES neuromuscular-system identification, from the rig to the digital twin.

The entry points a scientist uses (each loaded on first use, so ``import nmsid`` costs
nothing; the page ``docs/api.md`` has a runnable example):

>>> import nmsid                                                  # doctest: +SKIP
>>> session = nmsid.read_session("P01.h5")                        # doctest: +SKIP
>>> result = nmsid.identify(session)                              # doctest: +SKIP
>>> result.to_dataframe()                                         # doctest: +SKIP

read_session
    Read a session file (``.h5``) into a :class:`~nmsid.protocols.session_file.Session`.
identify
    Identify one session or a group: parameters per sE, models across sE, the twin.
diagnose_gap
    Where, which and how far a simulation misses a session (the sim-to-real gap).
load_twin, simulate_twin
    Read a twin file; the force it predicts for an input.
run_simulated_session
    Run a session on the simulated rig through the one engine.
design_controller
    Design the twin-based force controller.
IdentificationSettings, GapSettings
    The settings of :func:`identify` and :func:`diagnose_gap`.

Results are objects with short reprs (``<Identification | P01, ...>``); tables offer
``.rows()`` and ``.to_dataframe()`` (with pandas). Exceptions: :mod:`nmsid.errors`
(``UserError``, ``DeviceFault``, ``SafetyError``).

The sub-packages are the repository's top-level folders, lowest layer first
(``docs/architecture.md``): ``nmsid.protocols`` and ``nmsid.testing``, ``nmsid.drivers``,
``nmsid.sim_backends``, ``nmsid.analysis`` and ``nmsid.export``, ``nmsid.study``,
``nmsid.rig``, the command line ``nmsid.cli`` and this API (:mod:`nmsid.api`, on the top
layer like the command line).
"""

from __future__ import annotations

import importlib

#: Each public name and the module that defines it, imported on first use: the
#: identification loads scipy and the rig loads the simulator, which ``nmsid.errors``
#: (imported by every module) and ``nmsid --help`` must not pay for.
_EXPORTS = {
    "read_session": "nmsid.protocols.session_file",
    "identify": "nmsid.api",
    "diagnose_gap": "nmsid.api",
    "load_twin": "nmsid.api",
    "simulate_twin": "nmsid.api",
    "run_simulated_session": "nmsid.api",
    "design_controller": "nmsid.api",
    "IdentificationSettings": "nmsid.analysis.settings",
    "GapSettings": "nmsid.analysis.gap.diagnose",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> object:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    # __version__ on first use: importlib.metadata costs ~20-50 ms, and most commands
    # never ask for it
    if name != "__version__":
        raise AttributeError(f"module 'nmsid' has no attribute {name!r}")
    from importlib import metadata
    try:
        version = metadata.version("nmsid")
    except metadata.PackageNotFoundError:  # a source tree that was never installed
        version = "0+unknown"
    globals()["__version__"] = version
    return version


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
