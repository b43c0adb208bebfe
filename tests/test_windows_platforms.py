"""The platform marks skip by the platform, each with its reason (nmsid.testing.platforms):
posix_only on Windows (interpreter or emulation), emulation_only on the Windows interpreter,
wine_gap under Wine only."""

from __future__ import annotations

import sys

import pytest

from nmsid.testing import platforms


class _Item:
    """What the collection hook reads of a test item: its marks; what it writes: skips."""

    def __init__(self, **marks: str):
        self.marks = {name: getattr(pytest.mark, name)(reason).mark
                      for name, reason in marks.items()}
        self.skips: list[str] = []

    def get_closest_marker(self, name):
        return self.marks.get(name)

    def add_marker(self, mark):
        self.skips.append(mark.mark.kwargs["reason"])


def _skips(monkeypatch, *, windows: bool, wine: str | None, emulation=None):
    monkeypatch.setattr(platforms, "real_windows", lambda: windows)
    monkeypatch.setattr(platforms, "wine_version", lambda: wine)
    monkeypatch.setattr(platforms, "_session_emulation", emulation)
    items = [_Item(posix_only="forks"), _Item(emulation_only="the fake's bookkeeping"),
             _Item(wine_gap="no symbolic links"), _Item()]
    platforms.pytest_collection_modifyitems(None, items)
    return [item.skips for item in items]


def test_on_linux_nothing_is_skipped(monkeypatch):
    assert _skips(monkeypatch, windows=False, wine=None) == [[], [], [], []]


def test_under_the_emulation_only_posix_only_tests_are_skipped(monkeypatch):
    assert _skips(monkeypatch, windows=False, wine=None, emulation=object()) == [
        ["Windows emulation: forks"], [], [], []]


def test_on_a_windows_pc_wine_gaps_run(monkeypatch):
    assert _skips(monkeypatch, windows=True, wine=None) == [
        ["Windows: forks"], ["Windows: needs the Linux emulation: the fake's bookkeeping"],
        [], []]


def test_under_wine_a_wine_gap_is_skipped_naming_wine_and_the_gap(monkeypatch):
    assert _skips(monkeypatch, windows=True, wine="8.0")[2] == ["Wine 8.0: no symbolic links"]


@pytest.mark.skipif(sys.platform == "win32", reason="Windows: the answer on Linux; "
                    "here real_windows() is True")
def test_linux_is_neither_windows_nor_wine():
    assert not platforms.real_windows() and platforms.wine_version() is None
    assert not platforms.under_wine()
