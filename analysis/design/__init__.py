"""Protocol design: how much stimulation a twin of a given precision needs (``nmsid design``).

Modules, lowest first: :mod:`.prior` (what we believe about the participant),
:mod:`.candidates` (protocols the engine runs unchanged), :mod:`.predict` (Cramer-Rao
bounds of the per-level parameters, of the curves over sE and of the AICc choice),
:mod:`.search` (the least stimulation that meets a target), :mod:`.validate` (the same
protocols run on simulated participants and identified), :mod:`.report` (outputs),
:mod:`.api` (all of it in one call, as ``nmsid design`` runs it).
"""
