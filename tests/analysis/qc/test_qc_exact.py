"""QC's fast paths give the very numbers of the plain computations they replace: numpy's
median and quantile, the flat-run search, the lead-in noise, the repeats' comparison with
its regressions shared between passes (bit for bit, so no verdict can move)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.analysis.qc import QCSettings, checks, repeats
from nmsid.analysis.qc.decide import _single
from tests.analysis.qc.test_qc import FS, STEADY, bump, make_level


def _arrays(draw_n, seed, kind):
    rng = np.random.default_rng(seed)
    if kind == 0:
        return rng.standard_normal(draw_n) * 10.0 ** rng.uniform(-6, 6)
    if kind == 1:                                # a quantised sensor: many equal values
        return rng.integers(-4, 5, draw_n) * 0.0013305542450396945
    return np.abs(rng.standard_cauchy(draw_n))   # heavy tails, positive (quantum's input)


@settings(max_examples=300, deadline=None)
@given(n=st.integers(1, 3000), seed=st.integers(0, 2 ** 31 - 1), kind=st.integers(0, 2))
def test_median_of_finite_is_numpys_median_bit_for_bit(n, seed, kind):
    x = _arrays(n, seed, kind)
    keep = x.copy()
    got, ref = checks.median_of_finite(x), float(np.median(x))
    assert got == ref and np.signbit(got) == np.signbit(ref)
    np.testing.assert_array_equal(x, keep)            # not scratch: the input untouched
    assert checks.median_of_finite(x.copy(), scratch=True) == ref


@settings(max_examples=300, deadline=None)
@given(n=st.integers(1, 3000), seed=st.integers(0, 2 ** 31 - 1), kind=st.integers(0, 2),
       q=st.one_of(st.sampled_from([0.0, 0.001, 0.5, 1.0]), st.floats(0.0, 1.0)))
def test_quantile_of_finite_is_numpys_quantile_bit_for_bit(n, seed, kind, q):
    x = _arrays(n, seed, kind)
    got, ref = checks.quantile_of_finite(x, q), float(np.quantile(x, q))
    assert got == ref


def test_median_of_minus_zero_is_plus_zero_as_numpys():
    assert np.signbit(np.median(np.array([-0.0, -0.0]))) == np.signbit(
        checks.median_of_finite(np.array([-0.0, -0.0])))
    assert not np.signbit(checks.median_of_finite(np.array([-0.0])))


def _flat_runs_plain(x, fs_Hz, stall_min_s, clip_min_s, noise_sd):
    """The flat-run search written plainly: every run examined in turn."""
    d = np.abs(np.diff(x))
    d = d[np.isfinite(d) & (d > 0)]
    q = 0.0 if d.size == 0 else float(np.quantile(d, 0.001))
    if not np.isfinite(noise_sd) or noise_sd < 0.5 * q:
        return []
    same = np.concatenate([[False], np.diff(x) == 0])
    m = np.concatenate([[False], same, [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    out = []
    hi, lo = np.nanmax(x), np.nanmin(x)
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        a, b = int(a) - 1, int(b)
        n = b - a
        at_edge = x[a] == hi or x[a] == lo
        if at_edge and n / fs_Hz >= clip_min_s:
            out.append(("clipping", a, b))
        elif n / fs_Hz >= stall_min_s:
            out.append(("stalled", a, b))
    return out


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), n_stall=st.integers(0, 3), n_clip=st.integers(0, 3))
def test_flat_runs_finds_what_the_plain_search_finds(seed, n_stall, n_clip):
    """A quantised sensor (hundreds of short runs of equal samples) with stalls and
    clipped stretches of random lengths around the thresholds."""
    rng = np.random.default_rng(seed)
    step = 0.01
    x = np.round(np.cumsum(rng.normal(0, 0.02, 6000)) / step) * step
    for _ in range(n_stall):
        a, k = int(rng.integers(1, 5800)), int(rng.integers(150, 260))
        x[a:a + k] = x[a]
    for _ in range(n_clip):
        a, k = int(rng.integers(1, 5800)), int(rng.integers(30, 50))
        x[a:a + k] = x.max() if rng.random() < 0.5 else x.min()
    fs, stall, clip = 2000.0, 0.1, 0.02
    noise = checks.hf_noise_sd(x)
    got = [(f.kind, *f.spans[0]) for f in checks.flat_runs(x, fs, stall, clip, noise)]
    assert got == _flat_runs_plain(x, fs, stall, clip, noise)
    assert checks.flat_runs(x, fs, stall, clip, noise, dx=np.diff(x)) == \
        checks.flat_runs(x, fs, stall, clip, noise)


def test_runs_of_an_all_false_and_an_all_true_mask():
    assert checks.runs(np.zeros(5, bool)) == []
    assert checks.runs(np.ones(5, bool)) == [(0, 5)]
    assert checks.runs(np.array([0, 1, 1, 0, 1], bool)) == [(1, 3), (4, 5)]


def test_the_lead_in_noise_is_hf_noise_sd_of_the_lead_in():
    """_single takes the lead-in's second difference from the trial's: the same number as
    checks.hf_noise_sd on the lead-in itself; the whole trial's noise likewise."""
    trials, _ = make_level(n=1, noise=0.03, seed=4)
    w = _single(trials[0], QCSettings())
    f = np.asarray(trials[0].force_N, float)
    assert w.noise_sd == checks.hf_noise_sd(f[int(0.5 * FS):int(STEADY * FS)])
    assert checks.hf_noise_sd(f, dx=np.diff(f)) == checks.hf_noise_sd(f)


def _regress_plain(s, ref, fs, keep, half_s):
    """One repeat's L1 regression on another written plainly: its regressors built and
    every normal matrix formed by _weighted_solve, from scratch."""
    Xall = repeats.shared_regressors(ref, fs, half_s)
    edge = repeats.filter_edge(ref.size, fs, half_s)
    inside = keep.copy()
    inside[:edge] = False
    inside[ref.size - edge:] = False
    if inside.sum() < 3 * Xall.shape[1]:
        inside = keep
    X, y = Xall[inside], s[inside]
    beta = repeats._weighted_solve(X, y, np.ones(y.size))
    floor = 1e-9 * max(float(np.std(y)), 1e-12)
    r = y - X @ beta
    l1 = float(np.sum(np.abs(r)))
    for _ in range(30):
        beta = repeats._weighted_solve(X, y, 1.0 / np.maximum(np.abs(r), floor))
        r = y - X @ beta
        l1, before = float(np.sum(np.abs(r))), l1
        if before - l1 < 1e-3 * l1:
            break
    u = s - Xall @ beta
    if edge:
        u[:edge] = 0.0
        u[u.size - edge:] = 0.0
    return u


def _unshared_plain(signals, fs, s, calls):
    """The repeats' comparison written plainly: every regression of every pass from
    scratch (its regressors rebuilt each time), np.median for the partner choice."""
    n = len(signals)
    S = np.vstack(signals)
    w = int(round(s.window_s * fs))
    keep = [np.ones(S.shape[1], bool) for _ in range(n)]
    response = float(np.std(np.median(S, axis=0)[S.shape[1] // 3:]))
    for _ in range(2):
        u, rms, partner = [], [], []
        for i in range(n):
            pairs = []
            for j in range(n):
                if j != i:
                    calls.append(1)
                    uij = _regress_plain(S[i], S[j], fs, keep[i], s.shared_filter_s)
                    pairs.append((uij, repeats._window_rms(uij, w), j))
            best = min(pairs, key=lambda p: float(np.median(p[1])))
            u.append(best[0])
            rms.append(np.min(np.vstack([p[1] for p in pairs]), axis=0))
            partner.append(best[2])
        typical = float(np.median(np.concatenate(rms)))
        limit = max(s.deviation_k * typical, s.deviation_min_frac * response)
        flags = [r > limit for r in rms]
        new_keep = [~f if (~f).sum() > 0.5 * f.size else np.ones_like(f) for f in flags]
        if all(np.array_equal(a, b) for a, b in zip(new_keep, keep, strict=True)):
            break
        keep = new_keep
    return u, flags, rms, typical, response, [S[j] for j in partner], limit


@pytest.mark.parametrize("artefact", [False, True])
def test_unshared_is_the_plain_comparison_bit_for_bit(artefact, monkeypatch):
    """With a contraction in one repeat the comparison runs a second pass (the flagged
    stretch left out): only the regressions of that repeat are redone, and every output
    is the plain computation's exactly."""
    trials, t = make_level(n=3, seed=7)
    if artefact:
        trials[1].force_N = trials[1].force_N + bump(t, 9.0, 1.2, 2.5)
    s = QCSettings()
    sig, fs_s = [], 0.0
    for tr in trials:
        y, fs_s = repeats.smoothed(tr.force_N, FS, s)
        sig.append(y)
    calls = []
    real = repeats._regress
    monkeypatch.setattr(repeats, "_regress", lambda *a, **k: calls.append(1) or real(*a, **k))
    got = repeats.unshared(sig, fs_s, s)
    n_fast = len(calls)
    ref = _unshared_plain(sig, fs_s, s, calls)
    n_plain = len(calls) - n_fast
    for g, r in zip(got, ref, strict=True):
        if isinstance(g, list):
            assert len(g) == len(r)
            for a, b in zip(g, r, strict=True):
                np.testing.assert_array_equal(a, b)
        else:
            assert g == r
    assert n_plain == (12 if artefact else 6)       # a second pass when a repeat is flagged
    assert n_fast == (6 + 2 if artefact else 6)     # ... redoing only the flagged repeat's
    assert bool(np.any(got[1][1])) == artefact
