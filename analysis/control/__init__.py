"""Closed-loop force control designed from the twin (issue 28, ``docs/control.md``).

``plant`` (the twin's second-order model with dead time, sampled), ``margins`` (loop
frequency responses, gain / phase / delay margins), ``controllers`` (the twin-based
controller: feedforward inverse + Smith predictor + PI with anti-windup; the twin-free
baseline: a PID tuned by relay feedback, Astrom-Hagglund), ``targets`` (steps, ramps,
sines; a CSV of one's own), ``design`` (``nmsid control design``), ``report``
(``nmsid control report``).
"""
