"""The driver's McsUsbNet surface (drivers/mcs_surface.py) held to the real 5.3.15 assembly,
the fake McsUsbNet and the driver's own calls (issue 25, What to build 2).

The tests that read the real assembly need pythonnet and mono (vendor README: "Needed from
Debian: mono-complete ... and libmonosgen-2.0-dev"); they are skipped with that reason
elsewhere. The comparison itself runs everywhere against a small stand-in listing.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from nmsid.drivers import mcs_surface
from nmsid.drivers.mcs_surface import SURFACE, Member, compare
from nmsid.testing.platforms import under_wine, wine_version

# the shared folder beside the checkout (as CI clones it); NMSID_MCSUSBNET_DLL names another
REAL_DLL = Path(os.environ.get("NMSID_MCSUSBNET_DLL") or (
    Path(__file__).resolve().parents[3] / "shared" / "vendor" / "McsUsbNet-5.3.15"
    / "McsUsbNet.dll"))

_why_not = ("" if REAL_DLL.is_file() else f"the vendor assembly {REAL_DLL} is not here")
if not _why_not and under_wine():  # pythonnet would start .NET Framework: Wine aborts
    _why_not = f"Wine {wine_version()}: no .NET Framework (nor Mono) in the prefix"
if not _why_not and importlib.util.find_spec("pythonnet") is None:
    _why_not = "pythonnet is not installed (pip install 'nmsid[mcs]')"
if not _why_not and shutil.which("mono") is None:
    _why_not = "mono is not installed (apt-get install mono-complete libmonosgen-2.0-dev)"
needs_mono = pytest.mark.skipif(bool(_why_not), reason=_why_not)


def _hw_config(tmp_path, dll):
    example = Path(__file__).resolve().parents[2] / "docs" / "hw-config.example.toml"
    text = example.read_text(encoding="utf-8")
    lines = [f"dll_path = '{dll}'" if ln.startswith("dll_path") else ln
             for ln in text.splitlines()]
    path = tmp_path / "rig.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _probe(*args):
    return subprocess.run([sys.executable, "-m", "nmsid", "probe", *args], check=False,
                          capture_output=True, text=True, timeout=180)


@needs_mono
def test_probe_check_assembly_on_the_real_5_3_15_assembly_finds_every_member(tmp_path):
    done = _probe("--hw-config", str(_hw_config(tmp_path, REAL_DLL)), "--check-assembly")
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"all {len(SURFACE)} members" in done.stdout


def test_check_assembly_names_the_dll_without_a_hardware_file(tmp_path, monkeypatch, capsys):
    # issue 42: --check-assembly touches no device, so it needs no hardware file
    from nmsid.cli import main
    asked = []
    monkeypatch.setattr(mcs_surface, "assembly_report",
                        lambda dll: asked.append(str(dll)) or (1, [f"assembly {dll}: checked"]))
    dll = str(tmp_path / "McsUsbNet.dll")
    assert main(["probe", "--check-assembly", dll]) == 1      # the report's status
    assert asked == [dll] and f"assembly {dll}: checked" in capsys.readouterr().out
    # the hardware file's dll_path, as before, when no DLL is named
    assert main(["probe", "--hw-config", str(_hw_config(tmp_path, "C:/x/Mcs.dll")),
                 "--check-assembly"]) == 1
    assert asked == [dll, "C:/x/Mcs.dll"]
    # neither: one line naming both ways, exit 2, nothing checked
    for argv in (["probe"], ["probe", "--check-assembly"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "--hw-config FILE" in err and "--check-assembly DLL" in err
        assert "Traceback" not in err
    assert len(asked) == 2


@pytest.fixture(scope="module")
def real_listing():
    """The real 5.3.15 assembly's members (one reflection subprocess for the module)."""
    types_ = sorted({m.type_name for m in SURFACE} | {"CStg200xDownloadNet"})
    return mcs_surface.read_listing(REAL_DLL, types_)


@needs_mono
def test_an_assembly_lacking_a_member_fails_with_a_line_naming_it(real_listing, monkeypatch):
    # a doctored surface: what an older assembly without the save stop would lack, and
    # the download-mode capacity calls the real assembly does not have (vendor README)
    doctored = SURFACE + (
        Member("CStg200xDownloadNet", "method", "SetCapacity",
               ("System.UInt32[]", "System.UInt32[]"), "download-mode capacity"),
        Member("CStg200xDownloadNet", "method", "SendStop", ("System.UInt64",), "x"))
    monkeypatch.setattr(mcs_surface, "read_listing", lambda *a, **k: real_listing)
    status, lines = mcs_surface.assembly_report(REAL_DLL, doctored)
    assert status == 1
    assert any("missing: Mcs.Usb.CStg200xDownloadNet.SetCapacity(System.UInt32[], "
               "System.UInt32[])" in ln for ln in lines)
    assert any("other argument types: Mcs.Usb.CStg200xDownloadNet.SendStop(System.UInt64)"
               in ln and "(System.UInt32, System.Int32)" in ln for ln in lines)
    assert "2 of" in lines[-1]


def test_a_missing_assembly_file_is_one_line_and_a_non_zero_exit(tmp_path):
    status, lines = mcs_surface.assembly_report(tmp_path / "McsUsbNet.dll")
    assert status == 1 and len(lines) == 1
    assert "no such file" in lines[0] and "stimulator.dll_path" in lines[0]


def _stand_in_listing():
    """A tiny stand-in assembly: every SURFACE member, then one taken away."""
    listing: dict = {}
    for m in SURFACE:
        t = listing.setdefault(m.type_name, {"methods": [], "ctors": [], "properties": [],
                                             "fields": [], "events": [], "enum": []})
        if m.kind == "method":
            t["methods"].append([m.name, list(m.args)])
        elif m.kind == "ctor":
            t["ctors"].append(list(m.args))
        else:
            t[{"property": "properties", "field": "fields", "event": "events",
               "enum": "enum"}[m.kind]].append(m.name)
    return listing


def test_compare_names_a_member_the_stand_in_assembly_lacks():
    listing = _stand_in_listing()
    assert compare(listing) == []
    dl = listing["CStg200xDownloadNet"]
    dl["methods"] = [x for x in dl["methods"] if x[0] != "GetMemoryUsageDAC"]
    listing["RetriggerActionEnumNet"]["enum"].remove("Ignore")
    problems = compare(listing)
    assert len(problems) == 2
    assert "missing: Mcs.Usb.CStg200xDownloadNet.GetMemoryUsageDAC(System.UInt32)" \
        in problems[0]
    assert "RetriggerActionEnumNet.Ignore" in problems[1]
    listing["StgStatusNet"] = None
    assert any("type Mcs.Usb.StgStatusNet is not in the assembly" in p
               for p in compare(listing))


@needs_mono
def test_surface_is_exactly_what_the_real_assembly_offers(real_listing):
    assert compare(real_listing) == []


@needs_mono
def test_the_fake_mcsusbnet_offers_nothing_the_real_assembly_lacks(real_listing):
    from nmsid.drivers.fake_hardware import load_fake
    fake = load_fake("fake_mcs_usb")
    listing = real_listing
    real = {name for name, _args in listing["CStg200xDownloadNet"]["methods"]}
    offered = {n for n in vars(fake.CStg200xDownloadNet) if n[:1].isupper()}
    assert offered - real == set()
    for enum_name in ("RetriggerActionEnumNet", "Stg200xSegmentFlagsEnumNet"):
        names = {m.name for m in getattr(fake, enum_name)}
        assert names == set(listing[enum_name]["enum"])
    assert {"channeldata_current", "syncoutdata"} <= set(listing["STG_DestinationEnumNet"]
                                                        ["enum"])


@needs_mono
def test_the_fake_streaming_class_offers_nothing_the_real_assembly_lacks(real_listing):
    from nmsid.drivers.fake_hardware import load_fake
    fake = load_fake("fake_stg_streaming").CStg200xStreamingNet
    real = {name for name, _args in real_listing["CStg200xStreamingNet"]["methods"]}
    offered = {n for n in vars(fake) if n[:1].isupper()}
    assert offered and offered - real == set()
