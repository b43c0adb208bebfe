"""Trial quality control: which repeats are a response to rE, before anything is averaged.

A lab's first session contains artefacts the paper's mean-then-fit cannot see: a voluntary
contraction in one repeat, a cable knock, a clipped or stalled A/D, a baseline jump. Each
completed trial is checked on its own (:mod:`nmsid.analysis.qc.checks`) and against the other
repeats of its sE (:mod:`nmsid.analysis.qc.repeats`), and gets a decision
(:mod:`nmsid.analysis.qc.decide`): ``used``, ``repaired`` (a short artefact bridged, said where)
or ``excluded`` (with reasons and time spans). :mod:`nmsid.analysis.qc.table` prints and writes
the verdicts (``nmsid qc``, ``qc.csv``).

Examples
--------
>>> from nmsid.analysis.qc import QCSettings
>>> QCSettings().spike_k
8.0
"""

from nmsid.analysis.qc.decide import SessionQC, TrialQC, assess_level, assess_session
from nmsid.analysis.qc.settings import QCSettings

__all__ = ["QCSettings", "SessionQC", "TrialQC", "assess_level", "assess_session"]
