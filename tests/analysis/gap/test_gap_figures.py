"""``nmsid gap``'s figures (issue 38, item 2): every figure the report lists is a PNG at
>= 150 dpi with a PDF beside it, and the HTML report shows the PNGs."""

from __future__ import annotations

import json

from PIL import Image

from nmsid.cli import main


def test_gap_writes_each_figure_as_png_and_pdf(nominal_session, tmp_path):
    out = tmp_path / "gap"
    assert main(["gap", str(nominal_session), "--out", str(out), "--no-muscle"]) == 0
    figures = json.loads((out / "gap_report.json").read_text(encoding="utf-8"))["figures"]
    assert {"where.png", "frequency.png", "drift_fatigue.png", "example.png"} <= set(figures)
    html = (out / "report.html").read_text(encoding="utf-8")
    for name in figures:
        png = out / name
        with Image.open(png) as img:
            assert min(img.info["dpi"]) >= 149.5
        assert png.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"
        assert name in html
