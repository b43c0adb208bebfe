"""Trial QC on clean sessions whose physiology varies from trial to trial (issue: lab-grade
data; "exclude only what the evidence says").

Clean sessions of the paper's protocol, no artefact anywhere, with per-trial scatter of
the dynamics (relative SDs of Kp / wn / zeta, drawn per trial):

* template participants (``sim_backends.population``, 3 per setting): scatter scales the
  parameter curves;
* musculoskeletal participants (MuJoCo elbow, 3): scatter scales the physics behind them
  (electrode reach, muscle and mount speed, mount damping: ``trial_variant``).

Printed: clean trials excluded with the default comparison (each repeat against every
other through a +-0.3 s shared filter) and, as the baseline in the same process, with
``shared_filter_s = 0`` (gain and time shift only). Target: <= 2 % excluded.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from rates import rate  # noqa: E402
from workers import importable, process_pool  # noqa: E402

from nmsid.analysis.design.candidates import paper_candidate  # noqa: E402
from nmsid.analysis.design.validate import simulate_session  # noqa: E402
from nmsid.analysis.qc import QCSettings, assess_session  # noqa: E402
from nmsid.sim_backends.population import make_population  # noqa: E402

SCATTERS = [None, {"Kp": 0.1, "wn_rad_s": 0.05, "zeta": 0.05}, {"wn_rad_s": 0.1},
            {"zeta": 0.1}, {"Kp": 0.2, "wn_rad_s": 0.1, "zeta": 0.1}]


def _label(sc) -> str:
    if not sc:
        return "none"
    return ", ".join(f"{k} {100 * v:g} %" for k, v in sc.items())


def _excluded(sessions, settings) -> tuple[int, int]:
    n_ex = n = 0
    for s in sessions:
        n_ex += len(assess_session(s, settings).excluded())
        n += len(s.trials)
    return n_ex, n


def _people(kind: str):
    if kind == "template":
        return make_population(3, seed=5)
    from nmsid.sim_backends.msk_population import make_msk_population  # mujoco extra
    return make_msk_population(3, seed=21)


def setting(args: tuple[str, dict | None]) -> tuple[int, int, int]:
    """(excluded by default, excluded by gain+shift only, trials) for one participant kind
    and scatter; depends on its arguments only (any process, any order)."""
    kind, sc = args
    sessions = [simulate_session(vp, paper_candidate(), scatter=sc, seed=k)
                for k, vp in enumerate(_people(kind))]
    a, n = _excluded(sessions, QCSettings())
    b, _ = _excluded(sessions, QCSettings(shared_filter_s=0))
    return a, b, n


def main(jobs: int = 2) -> None:
    """``jobs`` worker processes (2: the bench machine's cores); the figures do not
    depend on it."""
    t0 = time.perf_counter()
    print(f"{'participants':16s} {'scatter per trial':36s} {'excluded (default)':>20s} "
          f"{'excluded (gain+shift only)':>28s}")
    work = [("template", sc) for sc in SCATTERS]
    try:
        import nmsid.sim_backends.msk_population  # noqa: F401 - the mujoco extra
        work += [("MuJoCo", sc) for sc in SCATTERS[:2]]
    except ImportError as exc:
        print(f"(musculoskeletal participants unavailable: {exc})")
    if jobs > 1:
        with process_pool(jobs) as ex:
            results = list(ex.map(importable(setting), work))
    else:
        results = [setting(w) for w in work]
    total = [0, 0]
    base_total = []
    for (kind, sc), (a, b, n) in zip(work, results, strict=True):
        total[0] += a
        total[1] += n
        base_total.append(b)
        print(f"{kind + ' x3':16s} {_label(sc):36s} {f'{a}/{n} = {100 * a / n:.1f} %':>20s} "
              f"{f'{b}/{n} = {100 * b / n:.1f} %':>28s}")
    print(f"all, clean trials excluded: {rate(total[0], total[1], '<=', 2.0)}   "
          f"({time.perf_counter() - t0:.0f} s, {jobs} worker process(es))")
    base = sum(base_total)
    print(f"  baseline in the same run (gain + time shift only): {base}/{total[1]} = "
          f"{100 * base / total[1]:.1f} %, "
          + (f"x{base / total[0]:.0f} the default's" if total[0] else "the default: none"))


if __name__ == "__main__":
    main()
