"""McsUsbNet (.NET, through pythonnet): loading the assembly and finding an STG on USB.

Names and argument types as in MCS's public examples (``multichannelsystems/
McsUsbNet_Examples``: ``Examples/Python/Stimulation.py``, ``DeviceList.py``):
``clr.AddReference(<McsUsbNet.dll>)``, ``CMcsUsbListNet(DeviceEnumNet.MCS_STG_DEVICE)``,
``.Count``, ``.GetUsbListEntry(i)`` (``.SerialNumber``, ``.DeviceName``).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

from nmsid.drivers.errors import DeviceNotFound, VendorLibraryMissing

DEFAULT_DLL = r"C:\Program Files\Multi Channel Systems\McsUsbNet\x64\McsUsbNet.dll"


def load_mcs_usb(dll_path: str) -> SimpleNamespace:
    """Import pythonnet, load McsUsbNet.dll and return the names the driver uses.

    Raises
    ------
    VendorLibraryMissing
        If pythonnet or the assembly is missing (one line saying how to install).
    """
    try:
        import clr  # noqa: PLC0415 (pythonnet; lazy: Windows vendor library)
    except ImportError:
        raise VendorLibraryMissing(
            "the Python package pythonnet", "the MCS STG4002 stimulator",
            "install it with: pip install 'nmsid[mcs]' (Windows, .NET Framework 4.x)"
        ) from None
    try:
        clr.AddReference(str(dll_path))
        from Mcs.Usb import (CMcsUsbListNet, CStg200xDownloadNet,  # noqa: PLC0415
                             DeviceEnumNet, STG_DestinationEnumNet)
        from System import Array, Int32, UInt32, UInt64  # noqa: PLC0415
    except Exception as exc:  # .NET FileNotFoundException is not a Python OSError
        raise VendorLibraryMissing(
            f"McsUsbNet.dll ({dll_path})", "the MCS STG4002 stimulator",
            "get it from github.com/multichannelsystems/McsUsbNet (or MC_Stimulus II) and "
            f"set stimulator.dll_path in the hardware config ({type(exc).__name__})"
        ) from None
    return SimpleNamespace(CMcsUsbListNet=CMcsUsbListNet, DeviceEnumNet=DeviceEnumNet,
                           CStg200xDownloadNet=CStg200xDownloadNet,
                           STG_DestinationEnumNet=STG_DestinationEnumNet, Array=Array,
                           Int32=Int32, UInt32=UInt32, UInt64=UInt64)


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
