"""One session's work in a study: identification (the same headless run as
``nmsid identify``) and gap diagnosis. Runs in a Dask worker; takes and returns paths
and small summaries, never signal arrays.

The session file is read once (the datasets identification, quality control and the gap
diagnosis need) and the decoded session is passed to each of them: on a cluster's shared
file system that is one read per session instead of four.
"""

from __future__ import annotations

import math
import time
import traceback
from pathlib import Path

from nmsid.analysis.gap.api import run_gap
from nmsid.analysis.gap.data import GAP_DATASETS
from nmsid.analysis.identify import NEEDED_DATASETS
from nmsid.analysis.model_selection import participant_parameters
from nmsid.analysis.run import run_identification
from nmsid.analysis.settings import PARAMETER_NAMES, IdentificationSettings
from nmsid.protocols import os_platform
from nmsid.protocols.session_file import read_session
from nmsid.protocols.session_state import session_state

#: What one task reads of a session file: the datasets of identification (and its QC) and
#: of the gap diagnosis.
SESSION_DATASETS = tuple(dict.fromkeys(NEEDED_DATASETS + GAP_DATASETS))


def session_folder_name(path: Path, index: int) -> str:
    """Output sub-folder of a session (index keeps equal stems apart)."""
    return f"{index:04d}-{Path(path).stem}"


def peak_rss_MB() -> float:
    """Peak resident memory of this process in MB (NaN where the platform cannot say).

    POSIX: ``resource.getrusage`` (Linux reports KiB). Windows has no ``resource``
    module: psutil's ``peak_wset`` (the peak working set; psutil comes with distributed,
    which the study extra installs).
    """
    if os_platform.is_windows():
        try:
            import psutil  # Windows only, behind the switch; installed with distributed

            return float(psutil.Process().memory_info().peak_wset) / 2**20
        except (ImportError, AttributeError):  # peak_wset exists on Windows only
            return float("nan")
    import resource  # POSIX only, behind the switch

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _num(v) -> float | None:
    return float(v) if v is not None and math.isfinite(float(v)) else None


def run_session(path: str, out_dir: str, settings: IdentificationSettings, *,
                gap: bool = True) -> dict:
    """Identify (and optionally diagnose) one session; never raises.

    Parameters
    ----------
    path : str
        The session file.
    out_dir : str
        This session's output folder (``identify/`` and ``gap/`` are written in it).
    settings : IdentificationSettings
    gap : bool
        Also run the gap diagnosis (``analysis.gap.api.run_gap``).

    Returns
    -------
    dict
        ``ok`` (identification succeeded), ``error`` (one line naming the failed stage;
        a failed gap diagnosis leaves ``ok`` True), ``participant``, ``sE`` and
        ``values`` (the identified parameters per sE, NaN as None), ``levels``,
        ``levels_identified``, ``lowest_fit_pct``, ``problems``, ``gap`` (summary or
        None), ``elapsed_s``, ``cpu_s`` (CPU time of the process meanwhile),
        ``peak_rss_MB``.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    out = Path(out_dir)
    result: dict = {"path": str(path), "ok": False, "error": "", "participant": "",
                    "gap": None, "problems": []}
    stage = "reading"
    # a live or killed (incomplete) session is marked (the file's trials counted from the
    # one read below: the file is read once)
    state = session_state(path, count_file_trials=False)
    result["session_state"], result["state_note"] = state.label, state.describe()
    try:
        # an unreadable file: say so in one line; identify, QC and gap use this one read
        session = read_session(path, datasets=SESSION_DATASETS)
        state.file_trials = len(session.trials)
        result["session_state"], result["state_note"] = state.label, state.describe()
        stage = "identification"
        ident = run_identification([session], out / "identify", settings, figures=False)
        res = ident.sessions[0]
        pp = participant_parameters(res)
        fits = [lv.fit.fit_pct for lv in res.levels if lv.fit is not None]
        result.update(
            participant=res.participant,
            sE=[float(x) for x in pp.sE],
            values={k: [_num(v) for v in pp.values[k]] for k in PARAMETER_NAMES},
            levels=len(res.levels),
            levels_identified=sum(1 for lv in res.levels if lv.fit is not None),
            lowest_fit_pct=_num(min(fits)) if fits else None,
            problems=list(ident.problems),
            joint=res.joint, measured_unit=res.unit)
        result["ok"] = True
        if gap:
            stage = "gap diagnosis"
            rep = run_gap([session], out / "gap", plots=False).sessions[0]
            result["gap"] = {
                "best_effect": rep["best_effect"],
                "best_pair": rep.get("best_pair"),
                "heldout": rep["heldout"],
                "supported": [{"effect": r["effect"], "shrink_pct": r["shrink_pct"]}
                              for r in rep["ranking"] if r.get("supported")],
            }
    except Exception as exc:  # a failing session is reported; the study goes on
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        # a failed gap diagnosis keeps the identification (ok stays True)
        result["error"] = f"{stage} failed: {type(exc).__name__}: {text}"
        result["traceback"] = traceback.format_exc(limit=5)
    result["elapsed_s"] = time.perf_counter() - t0
    result["cpu_s"] = time.process_time() - c0  # the whole process: a worker's own threads too
    result["peak_rss_MB"] = peak_rss_MB()
    return result
