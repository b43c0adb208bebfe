"""The study's one-page HTML report: sessions, Tables 1-9, Figures 4-6, gap summary."""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

from nmsid.analysis.model_selection import AVERAGE_LABEL
from nmsid.analysis.settings import PARAMETER_NAMES
from nmsid.protocols.printable import escape_controls
from nmsid.study.group import GroupResult


def _fmt(v, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.{digits}g}" if isinstance(v, float) else html.escape(str(v))


def _table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(c) if not isinstance(c, str) else html.escape(c)}"
                                    "</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _state_mark(r: dict) -> str:
    """`` (LIVE)`` / `` (INCOMPLETE)`` after a session that a run writes now or that was
    killed and not recovered (:mod:`nmsid.protocols.session_state`)."""
    state = r.get("session_state")
    return f" ({state.upper()})" if state in ("live", "incomplete") else ""


def write_report(path: Path, results: list[dict], group: GroupResult, figures: list[Path],
                 *, title: str, elapsed_s: float, mode: str) -> Path:
    """Write ``report.html`` (figures embedded, so the file stands alone)."""
    ok = [r for r in results if r.get("ok")]
    failed = [r for r in results if not r.get("ok") or r.get("error")]
    parts = [f"<h1>{html.escape(title)}</h1>",
             f"<p>{len(results)} session(s): {len(ok)} identified, "
             f"{sum(1 for r in results if not r.get('ok'))} failed; "
             f"{group.gap.get('n_sessions_diagnosed', 0)} gap-diagnosed. "
             f"Wall time {elapsed_s:.1f} s ({html.escape(mode)}).</p>"]
    marked = [r for r in results if _state_mark(r)]
    if marked:
        parts.append("<h2>Live or incomplete sessions</h2><ul>" + "".join(
            f"<li><b>{html.escape(Path(r['path']).name)}</b>: "
            f"{html.escape(r.get('state_note', ''))}</li>" for r in marked) + "</ul>")
    if failed:
        parts.append("<h2>Problems</h2><ul>" + "".join(
            f"<li><b>{html.escape(Path(r['path']).name)}</b>: {html.escape(r['error'])}</li>"
            for r in failed) + "</ul>")
    parts.append("<h2>Sessions</h2>" + _table(
        ["session", "participant", "levels identified", "lowest fit %", "gap best effect",
         "time s"],
        [[Path(r["path"]).name + _state_mark(r), r.get("label") or r.get("participant", ""),
          f"{r.get('levels_identified', 0)}/{r.get('levels', 0)}" if r.get("ok") else "failed",
          r.get("lowest_fit_pct"), (r.get("gap") or {}).get("best_effect", "-"),
          r["elapsed_s"]] for r in results]))
    g = group.gap
    if g.get("n_sessions_diagnosed"):
        parts.append("<h2>Group gap summary</h2>")
        parts.append(f"<p>Median held-out NRMSE of the nominal model "
                     f"{_fmt(g['median_nominal_heldout_nrmse_pct'])} %, with the best "
                     f"effect(s) {_fmt(g['median_augmented_heldout_nrmse_pct'])} %.</p>")
        parts.append("<h3>Best effect per session</h3>" + _table(
            ["effect", "sessions", "median held-out shrink %"],
            [[k, v["sessions"], v["median_shrink_pct"]] for k, v in g["best_effect"].items()]))
        parts.append("<h3>Effects supported on their own</h3>" + _table(
            ["effect", "sessions", "median shrink %"],
            [[k, v["sessions"], v["median_shrink_pct"]] for k, v in g["supported"].items()]))
    if group.note:
        parts.append(f"<p><b>{html.escape(group.note)}</b></p>")
    for joint, jg in group.joints.items():
        parts.append(f"<h2>{html.escape(joint)}: Tables 1-9 (Kp in "
                     f"{html.escape(jg.unit)})</h2><pre>{html.escape(jg.tables_text)}</pre>")
    if group.selection is not None:
        parts.append("<h2>Tables 1-9: AICc per participant and model, selected model and "
                     "trend, AICc sums</h2>")
        parts.append(f"<pre>{html.escape(group.tables_text)}</pre>")
        if group.selection.problems:
            parts.append("<h3>Model-selection caveats</h3><ul>" + "".join(
                f"<li>{html.escape(p)}</li>" for p in group.selection.problems) + "</ul>")
    if figures:
        parts.append("<h2>Figures 4-6: parameters against sE (participant average)</h2>")
        for fig in figures:
            data = base64.b64encode(Path(fig).read_bytes()).decode("ascii")
            parts.append(f'<figure><img alt="{html.escape(fig.stem)}" '
                         f'src="data:image/png;base64,{data}"><figcaption>'
                         f"{html.escape(fig.name)}</figcaption></figure>")
    parts.append("<p>The same numbers: sessions.csv, aicc.csv, selected_models.csv, "
                 "aicc_sums.csv, model_selection.json, gap_summary.json, study.json; per "
                 "session: sessions/NNNN-name/identify and gap.</p>")
    style = ("body{font-family:sans-serif;max-width:70em;margin:2em auto}"
             "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px}"
             "img{max-width:32em}")
    doc = (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
           f"</title><style>{style}</style></head><body>{''.join(parts)}</body></html>\n")
    path.write_text(escape_controls(doc), encoding="utf-8")  # no raw control characters
    return path


def draw_figures(group: GroupResult, out: Path) -> list[Path]:
    """Figures 4-6 (Kp, wn, zeta against sE with the fitted curves): the PNG files (a PDF of
    each is written beside it)."""
    if group.joints:     # one set per joint, in its folder
        return [f for joint, g in group.joints.items()
                for f in draw_figures(g, out / f"group-{joint}")]
    if group.selection is None:
        return []
    from nmsid.analysis.figures import plot_parameter_curves  # matplotlib: loaded only to draw
    return [plot_parameter_curves(group.selection, name, out / f"figure_{name}.png",
                                  AVERAGE_LABEL) for name in PARAMETER_NAMES]
