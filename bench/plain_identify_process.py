"""The plain baseline of ``bench_identify_process``, run as its own process.

    python bench/plain_identify_process.py SESSION.h5 [--raw]

What a careful newcomer would write: read the session (the same reader), preprocess each
sE level the same way as ``nmsid identify`` (so both fit identical data; ``--raw`` keeps
the 2000 Hz rate instead of the 200 Hz fitting rate), then per level
``scipy.optimize.least_squares`` over the discretised model (zero-order-hold
``cont2discrete`` of Kp wn^2 / (s^2 + 2 zeta wn s + wn^2), simulated with ``lfilter``,
plus an offset and a ramp), from three starting wn (10, 30, 60 rad/s), keeping the best.
Prints Kp, wn, zeta per level.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import cont2discrete, lfilter

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from nmsid.analysis.preprocess import preprocess_trials  # noqa: E402
from nmsid.analysis.settings import IdentificationSettings  # noqa: E402
from nmsid.protocols.session_file import read_session  # noqa: E402


def plain_fit(u: np.ndarray, y: np.ndarray, fs_Hz: float) -> np.ndarray:
    """(Kp, wn_rad_s, zeta) by least squares over the ZOH-discretised model."""
    dt = 1.0 / fs_Hz
    t = np.arange(len(y)) * dt
    tau = (t - t.mean()) / max(t.max() - t.mean(), dt)

    def resid(p):
        kp, wn, zeta, c0, c1 = p
        num, den, _ = cont2discrete(([kp * wn * wn], [1.0, 2 * zeta * wn, wn * wn]), dt,
                                    method="zoh")
        return lfilter(np.ravel(num), den, u) + c0 + c1 * tau - y

    best = None
    for wn0 in (10.0, 30.0, 60.0):
        r = least_squares(resid, [1.0, wn0, 0.5, 0.0, 0.0],
                          bounds=([-np.inf, 0.1, 0.01, -np.inf, -np.inf],
                                  [np.inf, 1e4, 100.0, np.inf, np.inf]))
        if best is None or r.cost < best.cost:
            best = r
    return best.x[:3]


def main(argv: list[str]) -> int:
    path = argv[1]
    settings = IdentificationSettings()
    if "--raw" in argv:
        settings = settings.replace(fit_fs_Hz=None)
    session = read_session(path, datasets=("rE", "force_N"))
    groups: dict[float, list] = {}
    for tr in session.trials:
        groups.setdefault(round(float(tr.sE), 9), []).append(tr)
    for sE in sorted(groups):
        data = preprocess_trials(groups[sE], settings)
        kp, wn, zeta = plain_fit(data.u, data.y_N, data.fs_Hz)
        print(f"sE {sE:.3f}: Kp {kp:.4g} N, wn {wn:.4g} rad/s, zeta {zeta:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
