"""Identification and model selection: the paper's analysis in Python.

Per sE level a second-order model G(s) = Kp wn^2 / (s^2 + 2 zeta wn s + wn^2) is fitted
from rE to endpoint force; each parameter's dependence on sE is chosen among linear,
quadratic and exponential models by AICc; the result is written as a digital twin. The
sim-to-real gap diagnosis lives in ``analysis.gap``.
"""
