"""One module per unmodelled effect, each its complete definition (:mod:`.base` says what
a module holds); :mod:`nmsid.protocols.effects` lists them in the order of physics."""
