"""nmsid: FES neuromuscular-system identification, from the rig to the digital twin.

One importable name. Its sub-packages are the repository's top-level folders, lowest layer
first (``docs/architecture.md``): ``nmsid.protocols`` and ``nmsid.testing``,
``nmsid.drivers``, ``nmsid.sim_backends``, ``nmsid.analysis`` and ``nmsid.export``,
``nmsid.study``, ``nmsid.rig``, and the command line ``nmsid.cli``. Exceptions:
``nmsid.errors``.
"""

from __future__ import annotations



def __getattr__(name: str) -> str:
    # __version__ on first use: importlib.metadata costs ~20-50 ms at every start-up
    # (`nmsid identify`'s budget is 0.3 s), and most commands never ask for it
    if name != "__version__":
        raise AttributeError(f"module 'nmsid' has no attribute {name!r}")
    from importlib import metadata
    try:
        version = metadata.version("nmsid")
    except metadata.PackageNotFoundError:  # a source tree that was never installed
        version = "0+unknown"
    globals()["__version__"] = version
    return version
