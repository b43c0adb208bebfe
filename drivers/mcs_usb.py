"""McsUsbNet (.NET, through pythonnet): loading the assembly and finding an STG on USB.

Names and argument types as in MCS's public examples (``multichannelsystems/
McsUsbNet_Examples``: ``Examples/Python/Stimulation.py``, ``DeviceList.py``):
``clr.AddReference(<McsUsbNet.dll>)``, ``CMcsUsbListNet(DeviceEnumNet.MCS_STG_DEVICE)``,
``.Count``, ``.GetUsbListEntry(i)`` (``.SerialNumber``, ``.DeviceName``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from nmsid.drivers.errors import DeviceNotFound, VendorLibraryMissing
from nmsid.protocols import os_platform

DEFAULT_DLL = r"C:\Program Files\Multi Channel Systems\McsUsbNet\x64\McsUsbNet.dll"


def load_mcs_usb(dll_path: str) -> SimpleNamespace:
    """Import pythonnet, load McsUsbNet.dll and return the names the driver uses.

    On Windows pythonnet's runtime is pinned to .NET Framework first
    (``pythonnet.load("netfx")``): McsUsbNet 5.3.15 is a C++/CLI assembly for .NET
    Framework 4.7.2 (vendor README), which .NET Core / 5+ (pythonnet's other runtime)
    cannot load.

    Raises
    ------
    VendorLibraryMissing
        pythonnet missing, or the assembly missing, blocked by Windows (a downloaded file,
        Mark-of-the-Web) or unloadable for want of the VC++ 2015-2022 x64 runtime: one line
        saying which and what to do (:func:`diagnose_load_failure`).
    """
    missing = VendorLibraryMissing(
        "the Python package pythonnet", "the MCS STG4002 stimulator",
        "install it with: pip install 'nmsid[mcs]' (Windows, .NET Framework 4.x)")
    if os_platform.is_windows():
        try:
            import pythonnet  # noqa: PLC0415 (lazy: Windows vendor library)
        except ImportError:
            raise missing from None
        _start_net_framework(pythonnet)
    try:
        import clr  # noqa: PLC0415 (pythonnet; lazy: Windows vendor library)
    except ImportError:
        raise missing from None
    try:
        clr.AddReference(str(dll_path))
        from Mcs.Usb import (  # noqa: PLC0415
            CMcsUsbListNet,
            CStg200xDownloadNet,
            DeviceEnumNet,
            RetriggerActionEnumNet,
            Stg200xSegmentFlagsEnumNet,
            STG_DestinationEnumNet,
        )
        from System import Array, Int32, UInt32, UInt64  # noqa: PLC0415
    except Exception as exc:  # .NET FileNotFoundException is not a Python OSError
        raise diagnose_load_failure(dll_path, exc) from None
    return SimpleNamespace(CMcsUsbListNet=CMcsUsbListNet, DeviceEnumNet=DeviceEnumNet,
                           CStg200xDownloadNet=CStg200xDownloadNet,
                           STG_DestinationEnumNet=STG_DestinationEnumNet,
                           RetriggerActionEnumNet=RetriggerActionEnumNet,
                           Stg200xSegmentFlagsEnumNet=Stg200xSegmentFlagsEnumNet,
                           Array=Array, Int32=Int32, UInt32=UInt32, UInt64=UInt64)


def _start_net_framework(pythonnet) -> None:
    """``pythonnet.load("netfx")``, tolerating only a runtime already loaded.

    pythonnet 3 returns at once when a runtime is loaded ("further invocations will return
    immediately", ``pythonnet.load``); its "has already been loaded" ``RuntimeError`` (from
    ``set_runtime``) is tolerated too. Any other failure (no .NET Framework 4.x, a broken
    install) is one clear line, not swallowed to fail later at ``import clr``.
    """
    try:
        pythonnet.load("netfx")
    except RuntimeError as exc:
        if "already been loaded" in str(exc):
            return
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise VendorLibraryMissing(
            ".NET Framework 4.7.2 or later", "the MCS STG4002 stimulator (McsUsbNet)",
            f"pythonnet could not start it ({first}); install .NET Framework 4.8 from "
            "Microsoft (Windows Update or dotnet.microsoft.com)") from None


def is_blocked_download(dll_path: str | Path) -> bool:
    """True if Windows marked the file as downloaded (Mark-of-the-Web).

    Windows stores the zone of a downloaded file in the NTFS alternate data stream
    ``<file>:Zone.Identifier`` (Microsoft, "Attachment Manager" / [MS-FSCC] alternate
    streams); .NET Framework refuses to load an assembly from such a file ("An attempt was
    made to load an assembly from a network location", HRESULT 0x80131515) until it is
    unblocked. Only asked on Windows (:mod:`nmsid.protocols.os_platform`); ``open`` of the
    stream name is how the stream is read there.
    """
    if not os_platform.is_windows():
        return False
    try:
        with open(f"{dll_path}:Zone.Identifier", encoding="utf-8", errors="replace") as f:
            text = f.read()
    except OSError:
        return False
    zone = [ln.split("=", 1)[1].strip() for ln in text.splitlines()
            if ln.strip().lower().startswith("zoneid=")]
    return not zone or zone[0] not in ("0", "1", "2")  # 3 Internet, 4 Restricted


_BLOCKED_TEXT = ("0x80131515", "network location", "loadFromRemoteSources")
_DEPENDENCY_TEXT = ("one of its dependencies", "0x8007007E", "0x8007007e",
                    "specified module could not be found", "DllNotFoundException",
                    "vcruntime140", "msvcp140")


def diagnose_load_failure(dll_path: str | Path, exc: BaseException) -> VendorLibraryMissing:
    """One line for a failed ``clr.AddReference``: missing file, blocked download or
    missing VC++ 2015-2022 x64 runtime (the vendor README: the assembly "needs the VC++
    2015-22 runtime and WinUSB on Windows"), else the .NET error itself."""
    path = Path(dll_path)
    text = f"{type(exc).__name__}: {exc}"
    what, needed = f"McsUsbNet.dll ({path})", "the MCS STG4002 stimulator"
    if not path.is_file():
        return VendorLibraryMissing(
            what, needed, "no such file: get it from github.com/multichannelsystems/McsUsbNet "
            "(or the MC_Stimulus II install) and set stimulator.dll_path in the hardware "
            "config")
    if is_blocked_download(path) or any(t in text for t in _BLOCKED_TEXT):
        return VendorLibraryMissing(
            what, needed, "the file is there but Windows BLOCKED it (downloaded from the "
            "internet, Mark-of-the-Web): right-click it > Properties > Unblock, or in "
            f"PowerShell: Unblock-File '{path}'")
    if any(t in text for t in _DEPENDENCY_TEXT) or "FileNotFoundException" in text:
        return VendorLibraryMissing(
            what, needed, "the file is there but could not be loaded: install the Microsoft "
            "Visual C++ 2015-2022 Redistributable (x64), vc_redist.x64.exe, which this "
            "mixed-mode assembly needs, and use 64-bit Python")
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return VendorLibraryMissing(
        what, needed, f"the file is there but .NET refused it ({type(exc).__name__}: "
        f"{first}); check it is the x64 McsUsbNet.dll and that .NET Framework 4.7.2 or later "
        "is installed")


@dataclass(frozen=True)
class StgDeviceInfo:
    name: str
    serial: str


def list_stg_devices(api: SimpleNamespace) -> list[StgDeviceInfo]:
    devices = api.CMcsUsbListNet(api.DeviceEnumNet.MCS_STG_DEVICE)
    out = []
    for i in range(int(devices.Count)):
        entry = devices.GetUsbListEntry(api.UInt32(i))
        out.append(StgDeviceInfo(name=str(entry.DeviceName), serial=str(entry.SerialNumber)))
    return out


def find_stg(api: SimpleNamespace, serial: str = ""):
    """The ``CMcsUsbListEntryNet`` of the STG to use: the one with ``serial``, or the only one.

    Raises
    ------
    DeviceNotFound
        None present, no such serial, or several and no serial configured.
    """
    devices = api.CMcsUsbListNet(api.DeviceEnumNet.MCS_STG_DEVICE)
    entries = [devices.GetUsbListEntry(api.UInt32(i)) for i in range(int(devices.Count))]
    if not entries:
        raise DeviceNotFound("no MCS STG stimulator found on USB; check the cable and "
                             "power, and that MC_Stimulus II is closed")
    found = ", ".join(str(e.SerialNumber) for e in entries)
    if serial:
        matches = [e for e in entries if str(e.SerialNumber) == serial]
        if not matches:
            raise DeviceNotFound(f"no STG with serial {serial!r} (found: {found}); check "
                                 "stimulator.serial in the hardware config")
        return matches[0]
    if len(entries) > 1:
        raise DeviceNotFound(f"{len(entries)} STGs found ({found}); set stimulator.serial "
                             "in the hardware config to choose one")
    return entries[0]
