"""link_problems' fast scan (HDF5's own traversal) decides as the h5py walk does: a file
of hard links and its own storage passes; each way of reaching other data is refused by
name."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from nmsid.protocols import session_checks
from nmsid.protocols.session_checks import link_problems


def _plain(path):
    with h5py.File(path, "w") as f:
        g = f.create_group("trials/t001")
        g["rE"] = np.zeros(10)
        g["force_N"] = np.arange(10.0)
        f.create_group("events/e00001").attrs["kind"] = "x"
    return path


def _soft(f, tmp_path):
    f["trials/t001/alias"] = h5py.SoftLink("/trials/t001/rE")


def _external_link(f, tmp_path):
    f["calibration"] = h5py.ExternalLink(str(_plain(tmp_path / "other.h5")), "/trials")


def _external_storage(f, tmp_path):
    raw = tmp_path / "raw.bin"
    raw.write_bytes(np.zeros(10).tobytes())
    f.create_dataset("trials/t001/sync", shape=(10,), dtype="<f8",
                     external=[(str(raw), 0, 80)])


def _virtual(f, tmp_path):
    other = _plain(tmp_path / "other.h5")
    layout = h5py.VirtualLayout(shape=(10,), dtype="<f8")
    layout[:] = h5py.VirtualSource(str(other), "/trials/t001/rE", shape=(10,))
    f["trials"].create_virtual_dataset("wrench", layout)


@pytest.mark.parametrize("make,words", [(_soft, "is a soft link"),
                                        (_external_link, "is an external link"),
                                        (_external_storage, "external file(s)"),
                                        (_virtual, "virtual dataset")])
def test_each_way_to_other_data_is_refused_by_name(tmp_path, make, words):
    path = _plain(tmp_path / "s.h5")
    with h5py.File(path, "a") as f:
        make(f, tmp_path)
    with h5py.File(path, "r") as f:
        assert not session_checks._only_hard_links_and_own_storage(f)
        problems = link_problems(f)
    assert len(problems) == 1 and words in problems[0], problems


def test_a_plain_file_passes_without_the_walk(tmp_path, monkeypatch):
    path = _plain(tmp_path / "s.h5")
    with h5py.File(path, "r") as f:
        assert session_checks._only_hard_links_and_own_storage(f)
        walked = []
        monkeypatch.setattr(f, "visititems_links", lambda fn: walked.append(fn))
        assert link_problems(f) == [] and walked == []
