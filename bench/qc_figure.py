"""Draw docs/figures/qc_example.png: the worked example of docs/identification.md, section 0.

A synthetic session (seed 2) with one contaminated repeat at three levels, as bench_qc
makes them; the figure shows the repeats of the level with a contraction, the excluded
trial's span, and the level with a baseline jump before and after the repair.

    python bench/qc_figure.py [OUT.png]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from bench_qc import contaminate  # noqa: E402

from nmsid.analysis.qc import assess_session  # noqa: E402
from nmsid.protocols.session_file import read_session  # noqa: E402
from nmsid.testing.sessions import write_synthetic_session  # noqa: E402


def main(out: str = str(HERE.parent / "docs" / "figures" / "qc_example.png")) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "P07.h5"
        write_synthetic_session(path, seed=2, participant="P07")
        ses = read_session(path, datasets=("rE", "force_N"))
    contaminate(ses, np.random.default_rng(2))
    qc = assess_session(ses)
    shown = [lv for lv in qc.levels if any(v.decision != "used" for v in lv.verdicts)][:2]
    fig, axes = plt.subplots(len(shown), 1, figsize=(9, 3.2 * len(shown)), sharex=True)
    for ax, lv in zip(np.atleast_1d(axes), shown, strict=True):
        trials = [t for t in ses.trials if round(t.sE, 6) == round(lv.sE, 6)]
        kept = {t.name: t for t in lv.kept}
        for v, tr in zip(sorted(lv.verdicts, key=lambda v: v.trial),
                         sorted(trials, key=lambda t: t.name), strict=True):
            t = tr.t_s
            style = {"used": "-", "repaired": "--", "excluded": "-"}[v.decision]
            colour = {"used": "0.6", "repaired": "tab:orange", "excluded": "tab:red"}[
                v.decision]
            ax.plot(t, tr.force_N, style, color=colour, lw=0.6,
                    label=f"{v.trial} repeat {v.repeat}: {v.decision}")
            if v.decision == "repaired" and v.trial in kept:
                ax.plot(t, kept[v.trial].force_N, "-", color="tab:green", lw=0.6,
                        label=f"{v.trial} after the repair")
            for a, b in v.spans:
                ax.axvspan(a, b, color=colour, alpha=0.15)
        ax.axvline(trials[0].steady_s, color="k", lw=0.5, ls=":")
        ax.set_ylabel("force (N)")
        ax.set_title(f"sE = {lv.sE:.2f}: " + "; ".join(
            f"{v.trial} {v.decision} ({v.reasons[0].split(' (RMS')[0]})" for v in lv.verdicts
            if v.decision != "used"), fontsize=8)
        ax.legend(fontsize=7, loc="lower left")
        ax.set_xlim(4, 15)
    np.atleast_1d(axes)[-1].set_xlabel("time after stimulation onset (s); dotted: analysed "
                                       "window starts")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main(*sys.argv[1:])
