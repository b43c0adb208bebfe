"""Local harmonic regression along the chirp: time maps to frequency.

The chirp's phase phi(t) is known, so in a window of a few cycles any signal can be
regressed on ``cos(h phi), sin(h phi)`` (h = 1, 2, 3) plus a local offset and slope. The
h = 1 coefficient is the response at the instantaneous frequency (its ratio to the input's
gives the transfer function), h = 2 and 3 are the harmonics that a static nonlinearity
makes, and the share of the signal's variance that the fundamental explains is the local
coherence (1 for a noise-free linear response).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class HarmonicWindows:
    """Harmonic amplitudes of a set of signals in chirp windows."""

    f_Hz: np.ndarray
    """(n_windows,) instantaneous chirp frequency at each window centre."""
    amplitude: np.ndarray
    """(n_signals, n_windows, n_orders) complex amplitude ``A`` with
    ``signal ~ Re(A exp(i h phi))``."""
    orders: tuple[float, ...]
    coherence: np.ndarray
    """(n_signals, n_windows) variance share explained by the fundamental (after the local
    offset and slope)."""
    rms: np.ndarray
    """(n_signals, n_windows) RMS of the signal after the local offset and slope."""


def window_edges(phase_rad: np.ndarray, cycles_per_window: float) -> list[np.ndarray]:
    """Sample indices of consecutive windows spanning ``cycles_per_window`` chirp cycles."""
    cyc = (phase_rad - phase_rad[0]) / (2 * np.pi)
    idx = np.floor(cyc / cycles_per_window).astype(int)
    out = []
    for m in range(idx.max() + 1):
        sel = np.flatnonzero(idx == m)
        if len(sel) >= 8 and (cyc[sel[-1]] - cyc[sel[0]]) > 0.8 * cycles_per_window:
            out.append(sel)
    return out


def local_harmonics(sig: np.ndarray, phase_rad: np.ndarray, f_inst_Hz: np.ndarray,
                    t_s: np.ndarray, *, cycles_per_window: float = 2.0,
                    orders: tuple[float, ...] = (1, 2, 3)) -> HarmonicWindows:
    """Regress each row of ``sig`` on the chirp's harmonics window by window.

    Parameters
    ----------
    sig : (n_signals, n_samples) ndarray
    phase_rad, f_inst_Hz, t_s : (n_samples,) ndarray
        Chirp phase, instantaneous frequency and time of each sample.
    cycles_per_window : float
        Window length in chirp cycles (2: fine enough to follow the frequency, long enough
        to separate the harmonics).
    orders : tuple of int
        Harmonic orders to estimate.

    Returns
    -------
    HarmonicWindows
    """
    sig = np.atleast_2d(sig)
    wins = window_edges(phase_rad, cycles_per_window)
    n_o = len(orders)
    amp = np.zeros((sig.shape[0], len(wins), n_o), dtype=complex)
    coh = np.zeros((sig.shape[0], len(wins)))
    rms = np.zeros((sig.shape[0], len(wins)))
    fc = np.zeros(len(wins))
    for w, sel in enumerate(wins):
        ph = phase_rad[sel]
        tt = t_s[sel] - t_s[sel].mean()
        cols = [np.ones_like(tt), tt]
        for h in orders:
            cols += [np.cos(h * ph), np.sin(h * ph)]
        X = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(X, sig[:, sel].T, rcond=None)
        base = X[:, :2] @ coef[:2]
        detr = sig[:, sel].T - base
        fund = X[:, 2:4] @ coef[2:4]
        var = np.sum(detr ** 2, axis=0)
        coh[:, w] = np.sum(fund ** 2, axis=0) / np.where(var > 0, var, 1.0)
        rms[:, w] = np.sqrt(var / len(sel))
        for k in range(n_o):
            a = coef[2 + 2 * k]
            b = coef[3 + 2 * k]
            amp[:, w, k] = a - 1j * b
        fc[w] = float(np.exp(np.mean(np.log(f_inst_Hz[sel]))))
    return HarmonicWindows(f_Hz=fc, amplitude=amp, orders=tuple(orders), coherence=coh,
                           rms=rms)


def levy_second_order(f_Hz: np.ndarray, H: np.ndarray,
                      weight: np.ndarray | None = None) -> tuple[float, float, float]:
    """Linear least-squares (Levy) start for ``Kp wn^2 / (s^2 + 2 zeta wn s + wn^2)``.

    Solves ``H (a0 + a1 s) - b0 = -H s^2`` at ``s = j 2 pi f`` in the least-squares sense;
    returns ``(Kp, wn_rad_s, zeta)`` clipped to physically sensible ranges.
    """
    s = 2j * np.pi * np.asarray(f_Hz)
    H = np.asarray(H)
    w = np.ones_like(f_Hz) if weight is None else np.asarray(weight)
    M = np.column_stack([H, H * s, -np.ones_like(H)]) * w[:, None]
    rhs = -H * s ** 2 * w
    A = np.vstack([M.real, M.imag])
    b = np.concatenate([rhs.real, rhs.imag])
    (a0, a1, b0), *_ = np.linalg.lstsq(A, b, rcond=None)
    if not (a0 > 0):
        return float(np.abs(H[0])), 40.0, 0.7
    wn = float(np.sqrt(a0))
    zeta = float(np.clip(a1 / (2 * wn), 0.05, 5.0))
    return float(b0 / a0), float(np.clip(wn, 2.0, 600.0)), zeta
