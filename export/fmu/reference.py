"""The FMU's co-simulation step in Python: the twin with its effects, stepped exactly as
``c/nmsid_model.c`` steps it, so that tests hold the binary to this definition.

Without effects this is :meth:`nmsid.analysis.twin.Twin.simulate` (``nmsid twin simulate``),
which the tests also hold it to (one definition of the nominal dynamics; the effects
extend it as ``docs/twin-file.md`` describes them: recruitment map on each muscle's
intensity, activation lag, flexor/extensor dynamics, fatigue gain on the dynamic force),
composed at the chain's slots by :func:`nmsid.protocols.effects.chain_of` from each
effect's one definition. An effect at the ``additive`` slot (a random baseline) has no FMU
step: ``build.py`` refuses it.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from nmsid.analysis.twin import Twin
from nmsid.protocols.effects import chain_of
from nmsid.sim_backends.effects import effects_from_list


class TwinStepper:
    """The FMU's model for one twin (``extrapolate`` as the FMU parameter)."""

    def __init__(self, twin: Twin, *, extrapolate: bool = False):
        self.twin = twin
        self.extrapolate = extrapolate
        # the twin's effects composed at the chain's slots (nmsid.protocols.effects)
        self.chain = chain_of(effects_from_list(twin.effects))
        self.maps_intensity = self.chain.maps_intensity
        self.lag_s = self.chain.lag_s
        self.ratios = self.chain.flexor_ratios
        self.two_paths = self.ratios != (1.0, 1.0)
        self.has_gain = self.chain.has_gain
        self.delay_s = self.chain.delay_s
        self._cache: dict[tuple, np.ndarray] = {}

    def _s(self, sE: float) -> float:
        lo, hi = self.twin.sE_range
        return sE if self.extrapolate else min(max(sE, lo), hi)

    def params(self, sE: float) -> tuple[float, float, float]:
        s = self._s(sE)
        p = self.twin.parameters
        return float(p["Kp"](s)), float(p["wn_rad_s"](s)), float(p["zeta"](s))

    def offset(self, sE: float) -> float:
        return float(self.twin.offset_N(self._s(sE)))

    def drives(self, rE: float, sE: float) -> tuple[float, float]:
        """(extensor, flexor) path drives, as ``drives()`` in the C source."""
        kp = self.params(sE)[0]
        if not self.maps_intensity and not self.two_paths:
            return kp * (rE - 0.5), 0.0
        if not sE > 0:
            return 0.0, 0.0
        h = self.chain.h
        k, h0 = kp / (2.0 * sE), float(h(0.5 * sE))
        we = k * (float(h(rE * sE)) - h0)
        wf = -k * (float(h((1.0 - rE) * sE)) - h0)
        return (we, wf) if self.two_paths else (we + wf, 0.0)

    def _path_step(self, x: np.ndarray, wn: float, zeta: float, h: float, w0: float,
                   w1: float) -> np.ndarray:
        nx = len(x)
        key = (nx, wn, zeta, h)
        e = self._cache.get(key)
        if e is None:
            e = self._cache[key] = self._transition(nx, wn, zeta, h)
        return e[:nx, :nx] @ x + e[:nx, nx] * w0 + e[:nx, nx + 1] * (w1 - w0)

    def _transition(self, nx: int, wn: float, zeta: float, h: float) -> np.ndarray:
        """exp of [[hA, hB, 0], [0, 0, 1], [0, 0, 0]] (Van Loan 1978)."""
        n = nx + 2
        m = np.zeros((n, n))
        if nx == 2:
            m[0, 1] = h
            m[1, 0], m[1, 1], m[1, 2] = -wn * wn * h, -2 * zeta * wn * h, wn * wn * h
        else:
            tau = self.lag_s
            m[0, 0], m[0, 3] = -h / tau, h / tau
            m[1, 2] = h
            m[2, 0], m[2, 1], m[2, 2] = wn * wn * h, -wn * wn * h, -2 * zeta * wn * h
        m[nx, nx + 1] = 1.0
        return expm(m)

    def simulate(self, rE, sE, fs_Hz: float, *, rest_lead_s: float | None = None
                 ) -> np.ndarray:
        """Force in N at each sample, co-simulating at the sampling step with inputs that
        are straight lines between samples (``rest_lead_s`` default one period, as
        ``nmsid twin simulate``). With a dead time the dynamics see the inputs ``L_s``
        late, the interval cut where the delayed input has a corner, as the C code does."""
        r = np.asarray(rE, float)
        s = np.broadcast_to(np.asarray(sE, float), r.shape)
        dt = 1.0 / fs_Hz
        lead = dt if rest_lead_s is None else rest_lead_s
        L = self.delay_s
        # the input history: straight segments (t0, r0, s0, t1, r1, s1); rest before them
        segs = [(-lead, 0.5, s[0], 0.0, r[0], s[0])] if lead > 0 else []
        segs += [((k - 1) * dt, r[k - 1], s[k - 1], k * dt, r[k], s[k])
                 for k in range(1, len(r))]
        starts = np.array([g[0] for g in segs])
        nx = 3 if self.lag_s > 0 else 2
        state = {"e": np.zeros(nx), "f": np.zeros(nx)}

        def value(k, t):
            if k < 0:
                return 0.5, s[0]
            t0, r0, s0, t1, r1, s1 = segs[k]
            a = min(max((t - t0) / (t1 - t0), 0.0), 1.0) if t1 > t0 else 1.0
            return r0 + a * (r1 - r0), s0 + a * (s1 - s0)

        def advance(a, b):
            while b - a > 0:
                k = int(np.searchsorted(starts, a, side="right")) - 1
                q = b
                if k + 1 < len(segs) and segs[k + 1][0] < q:
                    q = segs[k + 1][0]
                if k >= 0 and a < segs[k][3] < q:
                    q = segs[k][3]
                if q - a <= 1e-12 * (abs(a) + 1.0) and q < b:
                    a = q
                    continue
                (r0, s0), (r1, s1) = value(k, a), value(k, q)
                self._advance(state, q - a, r0, s0, r1, s1)
                a = q

        out = np.empty(len(r))
        c = 0.0
        if lead > 0:
            advance(-lead - L, -L)
        for k in range(len(r)):
            if k > 0:
                advance((k - 1) * dt - L, k * dt - L)
                if s[k - 1] > 0:
                    c += dt
            g = self.chain.gain(c) if self.has_gain else 1.0
            out[k] = self.offset(s[k]) + g * (state["e"][-2] + state["f"][-2])
        return out

    def _advance(self, state: dict, h: float, r0: float, s0: float, r1: float, s1: float):
        p0, p1 = self.params(s0), self.params(s1)
        wn, z = 0.5 * (p0[1] + p1[1]), 0.5 * (p0[2] + p1[2])
        we0, wf0 = self.drives(r0, s0)
        we1, wf1 = self.drives(r1, s1)
        state["e"] = self._path_step(state["e"], wn, z, h, we0, we1)
        if self.two_paths:
            state["f"] = self._path_step(state["f"], wn * self.ratios[0], z * self.ratios[1],
                                         h, wf0, wf1)
