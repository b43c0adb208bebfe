"""``import nmsid``: the entry points, the example of docs/api.md (run as it stands), the
results' short reprs and tables."""

from __future__ import annotations

import dataclasses
import pydoc
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import nmsid
from nmsid.errors import MissingDependency, UserError
from nmsid.protocols.reprs import REPR_MAX_CHARS, short_repr

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"
ENTRY_POINTS = ("read_session", "identify", "diagnose_gap", "load_twin", "simulate_twin",
                "run_simulated_session", "design_controller")


def doc_example() -> str:
    """The ```python blocks of docs/api.md, in order."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    assert blocks, "docs/api.md has no python example"
    return "\n".join(blocks)


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """The namespace left by docs/api.md's example, run in an empty folder."""
    folder = tmp_path_factory.mktemp("api_example")
    namespace: dict = {"__name__": "api_example"}
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(folder)
        exec(compile(doc_example(), str(DOC), "exec"), namespace)  # noqa: S102 - our doc
    namespace["folder"] = folder
    return namespace


def test_the_documented_example_runs_and_gives_what_it_says(example):
    assert example["run"].n_completed == 10 and example["run"].complete
    assert len(example["session"].trials) == 10
    result = example["result"]
    assert [lv.fit is not None for lv in result.sessions[0].levels] == [True] * 5
    assert result.files == []             # out_dir=None: nothing kept on disk
    assert sorted(example["folder"].iterdir()) == [example["folder"] / "P01.h5",
                                                   example["folder"] / "quick.toml"]
    assert example["twin"] is result.twins["P01"]
    assert example["force_N"].shape == example["rE"].shape
    assert np.all(np.isfinite(example["force_N"]))
    assert example["gap"].report is None and len(example["gap"].sessions) == 1
    assert example["controller"].participant == "P01"


def test_help_lists_every_entry_point():
    text = pydoc.render_doc(nmsid, renderer=pydoc.plaintext)
    for name in ENTRY_POINTS:
        assert re.search(rf"^    {name}\(", text, re.M), name
        assert callable(getattr(nmsid, name)) and getattr(nmsid, name).__doc__
    assert set(ENTRY_POINTS) <= set(nmsid.__all__) <= set(dir(nmsid))


def test_import_nmsid_loads_no_heavy_library():
    code = ("import sys, nmsid; print(sorted(m for m in ('numpy', 'scipy', 'h5py', "
            "'nmsid.api', 'nmsid.analysis') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, check=True)
    assert done.stdout.strip() == "[]"


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'identfy'"):
        nmsid.identfy  # noqa: B018


def _objects(example):
    """Every result object the example holds, and the objects inside them."""
    session, result = example["session"], example["result"]
    level = result.sessions[0].levels[0]
    yield from (example["run"], session, session.calibration, *session.trials,
                *session.events, result, *result.sessions, level, level.fit, level.data,
                result.selection, *result.selection.comparisons, example["twin"],
                example["gap"], example["controller"], *example["controller"].levels)


def test_every_repr_is_short_and_says_what_it_is(example):
    for obj in _objects(example):
        text = repr(obj)
        assert len(text) <= REPR_MAX_CHARS, (type(obj).__name__, len(text))
        assert text.startswith(f"<{type(obj).__name__}"), text
        assert "\n" not in text and "array(" not in text
        html = getattr(obj, "_repr_html_", None)
        if html is not None:
            assert html().startswith("<pre>&lt;") and len(html()) < 2 * REPR_MAX_CHARS


def _inside(obj, depth=0, seen=None):
    """``obj`` and every dataclass reachable through its fields (first items of lists and
    dicts), to ``depth`` 4."""
    seen = set() if seen is None else seen
    if id(obj) in seen or depth > 4:
        return
    seen.add(id(obj))
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        yield obj
        for f in dataclasses.fields(obj):
            yield from _inside(getattr(obj, f.name), depth + 1, seen)
    elif isinstance(obj, (list, tuple)):
        for item in obj[:3]:
            yield from _inside(item, depth, seen)
    elif isinstance(obj, dict):
        for item in list(obj.values())[:5]:
            yield from _inside(item, depth, seen)


def test_no_object_inside_a_result_has_a_long_repr(example):
    long = [(type(o).__name__, len(repr(o))) for top in ("result", "session", "gap",
                                                         "controller", "twin", "run")
            for o in _inside(example[top]) if len(repr(o)) > REPR_MAX_CHARS]
    assert long == []


def test_the_session_repr_reads_like_mne(example):
    assert repr(example["session"]).startswith(
        "<Session | P01, 10 trials, 5 sE levels 0.2-1, 2000 Hz, sim, ")


def test_a_repr_is_cut_at_its_bound_and_escapes_controls():
    text = short_repr("Session", "x" * 5000)
    assert len(text) == REPR_MAX_CHARS and text.endswith("...>")
    assert short_repr("Trial", "P01\x1b[2J") == "<Trial | P01\\x1b[2J>"


def test_tables_as_rows_and_dataframes(example):
    result, gap, controller = example["result"], example["gap"], example["controller"]
    rows = result.rows()
    assert [r["sE"] for r in rows] == [0.2, 0.4, 0.6, 0.8, 1.0]
    frame = result.to_dataframe()
    assert list(frame["wn_rad_s"]) == [r["wn_rad_s"] for r in rows]
    assert gap.to_dataframe().loc[0, "participant"] == "P01"
    assert len(controller.to_dataframe()) == len(controller.levels)
    assert {r["parameter"] for r in result.selection.rows()} == {"Kp", "wn_rad_s", "zeta"}


def test_a_dataframe_without_pandas_is_one_clear_line(example, monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)  # `import pandas` now fails
    with pytest.raises(MissingDependency, match=r"needs pandas.*\.rows\(\) gives"):
        example["result"].to_dataframe()
    assert example["result"].rows()  # the same table without pandas


def test_results_are_frozen(example):
    with pytest.raises(dataclasses.FrozenInstanceError):
        example["result"].problems = []
    with pytest.raises(dataclasses.FrozenInstanceError):
        example["gap"].report = Path("x")


def test_identify_into_a_folder_writes_what_the_command_writes(example, tmp_path):
    out = tmp_path / "analysis"
    result = nmsid.identify(example["session"], out)
    names = {p.name for p in result.files}
    assert {"parameters.csv", "twin.json", "model_selection.json"} <= names
    assert all(p.parent == out and p.exists() for p in result.files)
    assert nmsid.load_twin(out / "twin.json").parameters.keys() == \
        example["twin"].parameters.keys()
    with pytest.raises(UserError, match="exists"):   # never replaced unless force=True
        nmsid.identify(example["session"], out)


def test_bad_input_is_one_line_before_anything_runs(example, tmp_path):
    twin = example["twin"]
    with pytest.raises(UserError, match=r"rE\[1\] is 1.5 .*valid: in \[0, 1\]"):
        nmsid.simulate_twin(twin, [0.5, 1.5, 0.5], sE=0.5)
    with pytest.raises(UserError, match=r"sE\[0\] is -0.1"):
        nmsid.simulate_twin(twin, [0.5, 0.5], sE=-0.1)
    with pytest.raises(UserError, match="no twin given"):
        nmsid.simulate_twin(None, [0.5, 0.5], sE=0.5)
    with pytest.raises(UserError, match="no session given"):
        nmsid.identify([])
    existing = example["folder"] / "P01.h5"
    before = existing.read_bytes()
    with pytest.raises(UserError):
        nmsid.run_simulated_session(existing, example["folder"] / "quick.toml")
    assert existing.read_bytes() == before
