"""nmsid: FES neuromuscular-system identification, from the rig to the digital twin.

One importable name. Its sub-packages are the repository's top-level folders, lowest layer
first (``docs/architecture.md``): ``nmsid.protocols`` and ``nmsid.testing``,
``nmsid.drivers``, ``nmsid.sim_backends``, ``nmsid.analysis`` and ``nmsid.export``,
``nmsid.study``, ``nmsid.rig``, and the command line ``nmsid.cli``. Exceptions:
``nmsid.errors``.
"""

from __future__ import annotations

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("nmsid")
except _metadata.PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
