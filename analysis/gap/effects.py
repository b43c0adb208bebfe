"""The candidate effects: the registry's names (:mod:`nmsid.protocols.effects`), re-exported
for the gap diagnosis; each effect's analysis form is in :mod:`nmsid.analysis.gap.models`."""

from __future__ import annotations

from nmsid.protocols.effects import CANDIDATES, Effect

__all__ = ["Effect", "CANDIDATES"]
