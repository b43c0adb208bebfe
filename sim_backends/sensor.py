"""The simulated force chain: six-axis sensor + A/D, with noise, offset, drift and mains.

The six channels are quantised like the real chain's: the sensor's analog outputs
(``volts_per_N`` / ``volts_per_Nm``) are sampled by a bipolar ``adc_bits`` A/D of range
+/- ``adc_range_V`` (the rig's Contec AI-1608AY-USB: 16 bit, +/-10 V), so every wrench
sample is ``code * LSB`` with an integer ``code``, as on the hardware.

Every term is a function of the absolute sample index of the rig's time base (sample 0 =
the first stimulation onset of the session), so the same seed gives the same samples
whatever the chunking (fast clock: long chunks; real time: short chunks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# the baseline_drift effect's wander is defined with the effect; re-exported for its users
from nmsid.protocols.effect_defs.baseline_drift import BaselineWander  # noqa: F401
from nmsid.sim_backends.errors import SimConfigError

NOISE_BLOCK = 4096
"""White noise is drawn in blocks of this many samples, each from its own seeded stream,
so any sample range can be generated without replaying the stream from the start."""


@dataclass(frozen=True)
class SensorModel:
    """Measurement chain settings.

    Parameters
    ----------
    noise_N : float
        RMS of white measurement noise, N (the paper's rig: about 0.02-0.06 N).
    offset_N : float
        Constant offset of the force reading, N.
    drift_N_per_s : float
        Slow linear drift of the reading, N per second of session time.
    mains_N : float
        Amplitude of the mains pick-up, N.
    mains_Hz : float
        Mains frequency (50 Hz in Japan east / Europe).
    mains_phase_rad : float
        Phase of the pick-up at sample 0.
    range_N : float
        Full scale of the force axes; beyond it the chain flags over-range and saturates
        (the sensor of the paper, Leptrino PFS080YA501G6, is rated 500 N).
    axis : tuple of 3 float
        Unit vector of the extension direction in the sensor frame.
    lever_arm_m : tuple of 3 float
        Point of force application relative to the sensor origin, m (gives the moments).
    cross_noise_N : float
        RMS of noise on the force components orthogonal to the axis, N.
    adc_bits : int or None
        Resolution of the A/D that samples the six analog channels (16: the Contec
        AI-1608AY-USB); None turns quantisation off (float64 readings, the chain of
        releases before the A/D model).
    adc_range_V : float
        The A/D's bipolar input range, +/- V (Contec AI-1608AY-USB: 10 V).
    volts_per_N : float
        Analog output of the force channels, V per N. Default 0.02 V/N: the A/D's full
        scale (10 V) at the sensor's rated 500 N (an assumed amplifier setting; the
        Leptrino datasheet is not at hand), so one count is 20 V / 2**16 / 0.02 V/N =
        0.0153 N and the rounding adds 0.0153 / sqrt(12) = 0.0044 N RMS, a tenth of
        ``noise_N``.
    volts_per_Nm : float
        Analog output of the moment channels, V per N*m. Default 0.5 V/(N*m): full scale
        at 20 N*m (assumed rated moment), one count 0.00061 N*m.
    """

    noise_N: float = 0.04
    offset_N: float = 0.15
    drift_N_per_s: float = 2e-4
    mains_N: float = 0.03
    mains_Hz: float = 50.0
    mains_phase_rad: float = 0.0
    range_N: float = 500.0
    axis: tuple[float, float, float] = (0.0, -0.9962, 0.0872)
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.04)
    cross_noise_N: float = 0.02
    adc_bits: int | None = 16
    adc_range_V: float = 10.0
    volts_per_N: float = 0.02
    volts_per_Nm: float = 0.5

    def __post_init__(self):
        for name in ("noise_N", "mains_N", "range_N", "cross_noise_N"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise SimConfigError(f"sensor {name} must be finite and >= 0, got {v!r}")
        if not self.range_N > 0:
            raise SimConfigError(f"sensor range_N must be > 0, got {self.range_N!r}")
        axis = np.asarray(self.axis, dtype=float)
        if axis.shape != (3,) or not np.linalg.norm(axis) > 0:
            raise SimConfigError(f"sensor axis must be a non-zero 3-vector, got {self.axis!r}")
        object.__setattr__(self, "axis", tuple(axis / np.linalg.norm(axis)))
        if self.adc_bits is not None and (isinstance(self.adc_bits, bool) or int(
                self.adc_bits) != self.adc_bits or not 2 <= self.adc_bits <= 32):
            raise SimConfigError(f"sensor adc_bits must be an integer 2-32 or None (no "
                                 f"quantisation), got {self.adc_bits!r}")
        for name in ("adc_range_V", "volts_per_N", "volts_per_Nm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise SimConfigError(f"sensor {name} must be finite and > 0, got {v!r}")

    @property
    def lsb(self) -> np.ndarray | None:
        """One A/D count of each wrench channel (Fx, Fy, Fz in N, Mx, My, Mz in N*m), or
        None without quantisation."""
        if self.adc_bits is None:
            return None
        lsb_V = 2.0 * self.adc_range_V / 2 ** int(self.adc_bits)
        return np.array([lsb_V / self.volts_per_N] * 3 + [lsb_V / self.volts_per_Nm] * 3)

    def quantise(self, wrench: np.ndarray) -> np.ndarray:
        """``wrench`` (n, 6) as the A/D reports it: ``code * lsb`` with the integer code
        ``round(value / lsb)`` clipped to the A/D's codes (saturation at its range).
        Without quantisation (``adc_bits`` None) a float64 copy."""
        w = np.array(wrench, dtype=np.float64)
        lsb, bits = self.lsb, self.adc_bits
        if lsb is None or bits is None:
            return w
        half = 2 ** (int(bits) - 1)
        code = np.clip(np.rint(w / lsb), -half, half - 1).astype(np.int64)
        return code * lsb     # integer codes: never -0.0, exactly code * lsb per channel

    @classmethod
    def ideal(cls) -> SensorModel:
        """A noiseless, offset-free, drift-free chain (for closed-form tests)."""
        return cls(noise_N=0.0, offset_N=0.0, drift_N_per_s=0.0, mains_N=0.0,
                   cross_noise_N=0.0, adc_bits=None)


def block_normal(seed: int, stream: int, n0: int, n: int, width: int = 1) -> np.ndarray:
    """Standard normal samples for absolute indices ``n0 .. n0+n-1`` of a seeded stream.

    Chunk-independent: the result for a range equals the corresponding slice of the
    result for any larger range.
    """
    if n <= 0:
        return np.zeros((0, width)) if width > 1 else np.zeros(0)
    b0, b1 = n0 // NOISE_BLOCK, (n0 + n - 1) // NOISE_BLOCK
    parts = []
    for b in range(b0, b1 + 1):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, int(stream), int(b)])
        parts.append(rng.standard_normal((NOISE_BLOCK, width), dtype=np.float32)
                     .astype(np.float64))
    blk = np.concatenate(parts) if len(parts) > 1 else parts[0]
    off = n0 - b0 * NOISE_BLOCK
    out = blk[off:off + n]
    return out[:, 0] if width == 1 else out


class SensorState:
    """The chain's seeded noise (cached per block) and its measurement function."""

    def __init__(self, model: SensorModel, seed: int, fs_Hz: float):
        self.model = model
        self.seed = int(seed)
        self.fs_Hz = float(fs_Hz)
        self._blocks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        axis = np.asarray(model.axis)
        r = np.asarray(model.lever_arm_m, dtype=float)
        # two unit vectors orthogonal to the axis carry the cross-axis noise
        helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
        v1 = np.cross(axis, helper)
        v1 /= np.linalg.norm(v1)
        v2 = np.cross(axis, v1)
        self._w_axis = np.concatenate([axis, np.cross(r, axis)])
        self._w_cross = np.vstack([np.concatenate([v, np.cross(r, v)]) for v in (v1, v2)])

    def _block(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        blk = self._blocks.get(b)
        if blk is None:
            z = block_normal(self.seed, 1, b * NOISE_BLOCK, NOISE_BLOCK)
            m = self.model
            noise = z * m.noise_N
            # RMS cross_noise_N on each of the two orthogonal force directions; the same
            # normals in other orders (uncorrelated with the axis noise sample by sample):
            # the orthogonal components are cosmetic, one draw per sample keeps them cheap
            z2 = np.column_stack([z[::-1], np.roll(z, NOISE_BLOCK // 3)])
            cross = (z2 * m.cross_noise_N) @ self._w_cross
            blk = (noise, cross)
            if len(self._blocks) >= 4:
                self._blocks.pop(min(self._blocks))
            self._blocks[b] = blk
        return blk

    def _noise(self, n0: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        b0, b1 = n0 // NOISE_BLOCK, (n0 + n - 1) // NOISE_BLOCK
        off = n0 - b0 * NOISE_BLOCK
        if b0 == b1:
            f, w = self._block(b0)
            return f[off:off + n], w[off:off + n]
        f_out = np.empty(n)
        w_out = np.empty((n, 6))
        k = 0
        for b in range(b0, b1 + 1):
            f, w = self._block(b)
            lo = off if b == b0 else 0
            m = min(NOISE_BLOCK - lo, n - k)
            f_out[k:k + m] = f[lo:lo + m]
            w_out[k:k + m] = w[lo:lo + m]
            k += m
        return f_out, w_out

    def measure(self, true_force_N: np.ndarray, n0: int
                ) -> tuple[np.ndarray, np.ndarray, bool]:
        """Reading of the chain for the true endpoint force of samples ``n0 ...``.

        Returns
        -------
        force_N : ndarray
            The force along the extension axis as the chain reports it.
        wrench : ndarray, shape (n, 6)
            Fx, Fy, Fz, Mx, My, Mz in the sensor frame (the force along ``axis`` plus
            noise orthogonal to it, and their moments about the sensor origin); its force
            projected on ``axis`` is ``force_N``.
        over_range : bool
            True if any force component exceeded ``range_N`` (the reading saturates).

        With an A/D (``model.adc_bits``) every wrench channel is quantised to its counts
        (:meth:`SensorModel.quantise`) and ``force_N`` is the projection of the quantised
        forces on ``axis`` (a combination of three channels, not itself on a grid).
        """
        m = self.model
        n = true_force_N.size
        f = np.array(true_force_N, dtype=float)
        if n == 0:
            return f, np.zeros((0, 6)), False
        if m.offset_N or m.drift_N_per_s or m.mains_N:
            t = (n0 + np.arange(n)) * (1.0 / self.fs_Hz)
            if m.drift_N_per_s:
                f += m.offset_N + m.drift_N_per_s * t
            elif m.offset_N:
                f += m.offset_N
            if m.mains_N:
                f += m.mains_N * np.sin((2 * np.pi * m.mains_Hz) * t + m.mains_phase_rad)
        noise, cross = self._noise(n0, n) if (m.noise_N or m.cross_noise_N) else (None, None)
        if m.noise_N:
            f += noise
        wrench = np.multiply.outer(f, self._w_axis)
        if m.cross_noise_N:
            wrench += cross
        # the cross-axis noise is tiny: only a reading near full scale needs the full check
        over = bool(np.abs(f).max() > 0.9 * m.range_N
                    and np.abs(wrench[:, :3]).max() > m.range_N)
        if over:
            axis = np.asarray(m.axis)
            forces = np.clip(wrench[:, :3], -m.range_N, m.range_N)
            f = forces @ axis
            wrench = np.hstack([forces, np.cross(np.asarray(m.lever_arm_m)[None, :], forces)])
        if m.adc_bits is not None:
            wrench = m.quantise(wrench)
            f = wrench[:, :3] @ np.asarray(m.axis)
        return f, wrench, over

