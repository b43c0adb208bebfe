"""The McsUsbNet (.NET) surface the STG drivers use, declared once, and its check.

:data:`SURFACE` lists every type, member and argument-type list that
:mod:`nmsid.drivers.stg4002`, :mod:`nmsid.drivers.mcs_usb` and
:mod:`nmsid.drivers.stg_streaming` call. Three things are held to it:

* the vendor's assembly: :func:`check_assembly` (``nmsid probe --check-assembly``) reads
  the type metadata of a given ``McsUsbNet.dll`` by .NET reflection in a SUBPROCESS and
  reports one line per member that is missing or has other argument types;
* the driver: the tests record every call the driver makes on the fake McsUsbNet and hold
  each (member, argument types) to :data:`SURFACE` (``tests/drivers/test_mcs_surface.py``);
* the fake: ``testing/fakes/fake_mcs_usb.py`` may offer only members of :data:`SURFACE`,
  and :data:`SURFACE` only what the real 5.3.15 assembly has (same test file).

Reflection, not calls: McsUsbNet 5.3.15 is a mixed-mode C++/CLI assembly. Under mono on
Linux "its metadata loads ... and .NET reflection tells which members and overloads the real
assembly has", but "any call into it aborts the mono process" (vendor README,
``shared/vendor/McsUsbNet-5.3.15/README.md``): hence the subprocess, which only reflects.
On Windows the subprocess uses .NET Framework (``pythonnet.load("netfx")``).

Argument types are .NET full names as reflection prints them (``System.UInt32``,
``System.Int32[]``, ``System.String&`` for an ``out string``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from nmsid.protocols import os_platform

NS = "Mcs.Usb"
U32, I32, U64 = "System.UInt32", "System.Int32", "System.UInt64"
U32A, I32A, U64A = "System.UInt32[]", "System.Int32[]", "System.UInt64[]"


@dataclass(frozen=True)
class Member:
    """One member of the vendor assembly the driver uses.

    Attributes
    ----------
    type_name : str
        The declaring (or inheriting) type in ``Mcs.Usb``, e.g. ``"CStg200xDownloadNet"``.
    kind : str
        ``"method"``, ``"ctor"``, ``"property"``, ``"field"``, ``"event"`` or ``"enum"``.
    name : str
        Member name (``""`` for a constructor; the enum value's name for ``"enum"``).
    args : tuple of str
        Argument types of a method or constructor overload (.NET full names).
    why : str
        What the driver uses it for (printed next to a missing member).
    """

    type_name: str
    kind: str
    name: str
    args: tuple[str, ...] = ()
    why: str = ""

    def label(self) -> str:
        """``Mcs.Usb.CStg200xDownloadNet.SendStop(System.UInt32, System.Int32)``."""
        base = f"{NS}.{self.type_name}"
        if self.kind == "ctor":
            return f"{base}({', '.join(self.args)}) constructor"
        if self.kind == "method":
            return f"{base}.{self.name}({', '.join(self.args)})"
        return f"{base}.{self.name} ({self.kind})"


def _m(type_name: str, name: str, *args: str, why: str = "") -> Member:
    return Member(type_name, "method", name, tuple(args), why)


DL = "CStg200xDownloadNet"
ST = "CStg200xStreamingNet"
SEGFLAGS = f"{NS}.Stg200xSegmentFlagsEnumNet"

SURFACE: tuple[Member, ...] = (
    # -- finding the device (mcs_usb.py; MCS example Examples/Python/DeviceList.py)
    Member("CMcsUsbListNet", "ctor", "", (f"{NS}.DeviceEnumNet",), "list STGs on USB"),
    Member("CMcsUsbListNet", "property", "Count", why="number of devices"),
    _m("CMcsUsbListNet", "GetUsbListEntry", U32, why="one device entry"),
    Member("CMcsUsbListEntryNet", "property", "SerialNumber", why="serial of a device"),
    Member("CMcsUsbListEntryNet", "property", "DeviceName", why="model of a device"),
    Member("DeviceEnumNet", "enum", "MCS_STG_DEVICE", why="list STGs only"),
    # -- download mode (stg4002.py)
    Member(DL, "ctor", "", (), "the download-mode handle"),
    Member(DL, "event", "Stg200xPollStatusEvent", why="trigger status while running"),
    _m(DL, "Connect", f"{NS}.CMcsUsbListEntryNet", why="connect"),
    _m(DL, "Disconnect", why="release the device"),
    _m(DL, "Dispose", why="release the device"),
    _m(DL, "GetNumberOfTriggerInputs", why="trigger bitmaps"),
    _m(DL, "GetNumberOfAnalogChannels", why="channel check"),
    _m(DL, "GetNumberOfSyncoutChannels", why="sync output check"),
    _m(DL, "SendStop", U32, why="immediate stop (E-stop)"),
    _m(DL, "SendStop", U32, I32, why="save stop (STOP_OPTION_SAVESTOP 0x80) at an end/abort"),
    _m(DL, "SendStart", U32, why="start trigger 1"),
    _m(DL, "QueryTriggerstatus", why="status between and after trials"),
    _m(DL, "ResetStatus", U32, why="clear a Finished status"),
    _m(DL, "ResetOvercurrent", why="clear a latched overcurrent status"),
    _m(DL, "EnableAutoReset", why="Finished -> Idle after one poll cycle"),
    _m(DL, "SetupRetriggerMode", f"{NS}.RetriggerActionEnumNet",
       f"{NS}.RetriggerActionEnumNet", why="retrigger mode set explicitly"),
    _m(DL, "SetCurrentMode", why="current mode"),
    _m(DL, "DisableMultiFileMode", why="one segment, normal mode"),
    _m(DL, "GetCurrentRangeInNanoAmp", U32, why="ceiling check"),
    _m(DL, "GetCurrentResolutionInNanoAmp", U32, why="rendering step"),
    _m(DL, "GetTotalMemory", why="memory (all segments)"),
    _m(DL, "SegmentSelect", U32, SEGFLAGS, why="select segment 0 for the download"),
    _m(DL, "GetAvailableMemory", why="memory of the selected segment"),
    _m(DL, "GetMemoryUsageDAC", U32, why="memory used per channel, read back"),
    _m(DL, "GetMemoryUsageSyncout", U32, why="memory used per sync output, read back"),
    _m(DL, "GetStgVersionInfo", "System.String&", "System.String&", why="firmware"),
    _m(DL, "SetupTrigger", U32, U32A, U32A, U32A, why="channel / sync / repeat maps"),
    _m(DL, "ClearChannelData", U32, why="clear a channel"),
    _m(DL, "ClearSyncData", U32, why="clear a sync output"),
    _m(DL, "PrepareAndSendData", U32, I32A, U64A, f"{NS}.STG_DestinationEnumNet",
       why="download a channel or sync output"),
    Member("STG_DestinationEnumNet", "enum", "channeldata_current", why="current data"),
    Member("STG_DestinationEnumNet", "enum", "syncoutdata", why="sync data"),
    Member("RetriggerActionEnumNet", "enum", "Stop", why="default retrigger action"),
    Member("RetriggerActionEnumNet", "enum", "Ignore", why="retrigger action"),
    Member("RetriggerActionEnumNet", "enum", "Restart", why="retrigger action"),
    Member("Stg200xSegmentFlagsEnumNet", "enum", "None", why="SegmentSelect flags"),
    Member("StgStatusNet", "field", "TiggerStatus", why="trigger status (vendor spelling)"),
    Member("StgStatusNet", "field", "OvercurrentStatus", why="overcurrent status"),
    # -- streaming mode (stg_streaming.py; issue 28)
    Member(ST, "ctor", "", (U32,), "streaming handle (ring buffer size)"),
    _m(ST, "Connect", f"{NS}.CMcsUsbListEntryNet", why="connect"),
    _m(ST, "Disconnect", why="release the device"),
    _m(ST, "Dispose", why="release the device"),
    _m(ST, "SetCurrentMode", why="current mode"),
    _m(ST, "SetOutputRate", U32, why="streaming output rate"),
    _m(ST, "GetCurrentRangeInNanoAmp", U32, why="ceiling check"),
    _m(ST, "GetCurrentResolutionInNanoAmp", U32, why="rendering step"),
    _m(ST, "GetNumberOfAnalogChannels", why="channel check"),
    _m(ST, "SetupTrigger", U32A, U32A, U32A, U32A, U32A, why="maps and callback thresholds"),
    _m(ST, "EnqueueData", U32, "System.Int16[]", why="queue samples"),
    _m(ST, "GetDataQueueSpace", U32, why="free queue space"),
    _m(ST, "StartLoop", why="start streaming"),
    _m(ST, "GetFramesBuffered", U32, why="start only once the STG holds data"),
    _m(ST, "StopLoop", why="stop streaming"),
    _m(ST, "SendStart", U32, why="start trigger"),
    _m(ST, "SendStop", U32, why="immediate stop"),
    _m(ST, "GetNumberOfTriggerInputs", why="trigger arrays"),
    _m(ST, "GetNumberOfSyncoutChannels", why="sync output check"),
    _m(ST, "GetTotalMemory", why="STG ring buffer layout"),
    _m(ST, "SetCapacity", U32A, why="STG ring buffer per trigger (streaming only)"),
    _m(ST, "DisableContinousMode", why="stop, not zero-fill, when the data runs out"),
    _m(ST, "EnqueueSyncout", U32, "System.UInt16[]", why="sync high while streaming"),
    _m(ST, "GetSyncoutQueueSpace", U32, why="free sync queue space"),
)
"""Everything the STG drivers call in McsUsbNet (see the module docstring)."""


def members_of(type_name: str, kind: str = "method") -> set[str]:
    """Names of :data:`SURFACE` members of ``type_name`` of ``kind``."""
    return {m.name for m in SURFACE if m.type_name == type_name and m.kind == kind}


def has_overload(type_name: str, name: str, args: tuple[str, ...]) -> bool:
    """True if :data:`SURFACE` declares ``type_name.name(args)``."""
    return any(m.type_name == type_name and m.kind == "method" and m.name == name
               and m.args == tuple(args) for m in SURFACE)


# ---------------------------------------------------------------------------------------
# The check against an assembly
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class AssemblyCheck:
    """The result of :func:`check_assembly`.

    Attributes
    ----------
    dll_path : str
    problems : tuple of str
        One line per member that is missing or has other argument types.
    n_checked : int
        Members of :data:`SURFACE` checked.
    """

    dll_path: str
    problems: tuple[str, ...]
    n_checked: int

    @property
    def ok(self) -> bool:
        return not self.problems


class AssemblyUnreadable(RuntimeError):
    """The assembly's metadata could not be read at all (one line: why and what to do)."""


def compare(listing: dict, surface: tuple[Member, ...] = SURFACE) -> list[str]:
    """Lines for every member of ``surface`` that ``listing`` (see :func:`_dump`) lacks.

    ``listing`` maps a type name to ``{"methods": [[name, [arg types]]], "ctors": [[arg
    types]], "properties": [...], "fields": [...], "events": [...], "enum": [...]}``;
    a type absent from the assembly is ``None``.
    """
    problems = []
    for m in surface:
        t = listing.get(m.type_name)
        if t is None:
            problems.append(f"missing: {m.label()}: type {NS}.{m.type_name} is not in the "
                            f"assembly ({m.why})")
            continue
        if m.kind in ("method", "ctor"):
            overloads = ([tuple(a) for n, a in t["methods"] if n == m.name]
                         if m.kind == "method" else [tuple(a) for a in t["ctors"]])
            if tuple(m.args) in overloads:
                continue
            if not overloads:
                problems.append(f"missing: {m.label()} ({m.why})")
            else:
                have = "; ".join("(" + ", ".join(a) + ")" for a in overloads)
                problems.append(f"other argument types: {m.label()} ({m.why}); the "
                                f"assembly has {have}")
            continue
        key = {"property": "properties", "field": "fields", "event": "events",
               "enum": "enum"}[m.kind]
        if m.name not in t.get(key, []):
            problems.append(f"missing: {m.label()} ({m.why})")
    return problems


def check_assembly(dll_path: str | Path, surface: tuple[Member, ...] = SURFACE,
                   timeout_s: float = 120.0) -> AssemblyCheck:
    """Check ``surface`` against the assembly at ``dll_path`` without touching a device.

    Raises
    ------
    AssemblyUnreadable
        The file is missing, pythonnet or its .NET runtime is missing, or the metadata
        could not be read (the line says which).
    """
    listing = read_listing(dll_path, sorted({m.type_name for m in surface}), timeout_s)
    return AssemblyCheck(str(dll_path), tuple(compare(listing, surface)), len(surface))


def read_listing(dll_path: str | Path, type_names: list[str],
                 timeout_s: float = 120.0) -> dict:
    """The members of ``type_names`` in the assembly (see :func:`compare`), read by
    reflection in a subprocess.

    Raises
    ------
    AssemblyUnreadable
    """
    path = Path(dll_path)
    if not path.is_file():
        raise AssemblyUnreadable(f"{path}: no such file; set stimulator.dll_path in the "
                                 "hardware config to McsUsbNet.dll")
    cmd = [sys.executable, "-m", "nmsid.drivers.mcs_surface", str(path), *type_names]
    try:
        done = subprocess.run(cmd, check=False, capture_output=True, text=True,
                              timeout=timeout_s, encoding="utf-8", errors="replace")
    except subprocess.TimeoutExpired:
        raise AssemblyUnreadable(f"{path}: reading its metadata took more than "
                                 f"{timeout_s:g} s") from None
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
    if done.returncode != 0 or not lines:
        err = [ln for ln in (done.stderr or "").strip().splitlines() if ln.strip()]
        why = err[-1] if err else f"exit status {done.returncode}"
        raise AssemblyUnreadable(f"{path}: its .NET metadata could not be read ({why}); "
                                 + _runtime_hint())
    listing = json.loads(lines[-1])
    if "error" in listing:
        raise AssemblyUnreadable(f"{path}: {listing['error']}; " + _runtime_hint())
    return listing


def assembly_report(dll_path: str | Path | None,
                    surface: tuple[Member, ...] = SURFACE) -> tuple[int, list[str]]:
    """``nmsid probe --check-assembly``: exit status and the lines to print.

    0 only when every member of ``surface`` is in the assembly; 1 when any is missing or
    has other argument types (one line each); 1 when the metadata cannot be read.
    ``dll_path`` empty means the driver's default install path.
    """
    if not dll_path:
        from nmsid.drivers.mcs_usb import DEFAULT_DLL  # noqa: PLC0415
        dll_path = DEFAULT_DLL
    try:
        result = check_assembly(dll_path, surface)
    except AssemblyUnreadable as exc:
        return 1, [f"assembly: FAILED: {exc}"]
    lines = [f"assembly {result.dll_path}: {line}" for line in result.problems]
    if result.ok:
        lines.append(f"assembly {result.dll_path}: all {result.n_checked} members the STG "
                     "drivers use are there, with the same argument types")
        return 0, lines
    lines.append(f"assembly: FAILED: {len(result.problems)} of {result.n_checked} members "
                 "missing or with other argument types")
    return 1, lines


def _runtime_hint() -> str:
    if os_platform.is_windows():
        return ("install pythonnet (pip install 'nmsid[mcs]') and .NET Framework 4.7.2 or "
                "later")
    return ("install pythonnet (pip install 'nmsid[mcs]') and mono (Debian: apt-get install "
            "mono-complete libmonosgen-2.0-dev)")


def _dump(dll_path: str, type_names: list[str]) -> dict:
    """The listing :func:`compare` reads; runs in the subprocess (reflection only)."""
    import pythonnet  # noqa: PLC0415 (optional, and only in the subprocess)
    pythonnet.load("netfx" if os_platform.is_windows() else "mono")
    import clr  # noqa: PLC0415

    clr.AddReference(str(dll_path))
    import System  # noqa: PLC0415
    from System.Reflection import BindingFlags  # noqa: PLC0415

    asm = next(a for a in System.AppDomain.CurrentDomain.GetAssemblies()
               if a.GetName().Name == "McsUsbNet")
    flags = BindingFlags.Public | BindingFlags.Instance | BindingFlags.Static
    out: dict = {}
    for name in type_names:
        t = asm.GetType(f"{NS}.{name}")
        if t is None:
            out[name] = None
            continue

        def args(m):
            return [str(p.ParameterType.FullName or p.ParameterType.Name)
                    for p in m.GetParameters()]
        out[name] = {
            "methods": [[str(m.Name), args(m)] for m in t.GetMethods(flags)],
            "ctors": [args(c) for c in t.GetConstructors()],
            "properties": [str(p.Name) for p in t.GetProperties(flags)],
            "fields": [str(f.Name) for f in t.GetFields(flags)],
            "events": [str(e.Name) for e in t.GetEvents(flags)],
            "enum": [str(n) for n in System.Enum.GetNames(t)] if t.IsEnum else [],
        }
    return out


def main(argv: list[str]) -> int:
    """``python -m nmsid.drivers.mcs_surface DLL TYPE...``: print the listing as JSON."""
    try:
        listing = _dump(argv[0], argv[1:])
    except Exception as exc:  # one JSON line for the parent, whatever failed
        print(json.dumps({"error": f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
                          if str(exc) else type(exc).__name__}), flush=True)
        return 0
    print(json.dumps(listing), flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover (run as a subprocess)
    raise SystemExit(main(sys.argv[1:]))
