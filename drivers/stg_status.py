"""What McsUsbNet reports about an STG, decoded as the vendor documents it.

Sources (McsUsbNet 5.3.15, ``github.com/multichannelsystems/McsUsbNet``: the type metadata
of ``x64/McsUsbNet.dll`` read with ``dnfile``, and the XML documentation
``x64/McsUsbNet.xml``):

* ``Mcs.Usb.StgStatusNet`` has the fields ``TiggerStatus`` (vendor spelling) of type
  ``Stg200xTriggerStatusEnumNet[]`` (one entry per trigger, "The STG maintains the status
  for each of the STG200x_NUM_TRIGGER triggers"), ``ListOfChangedTriggers`` (``UInt32[]``)
  and ``OvercurrentStatus`` of type ``Stg5OvercurrentStatusEnumNet``.
* ``Stg200xTriggerStatusEnumNet`` ("the STG download mode trigger status"): ``Idle = 0``,
  ``Running = 1``, ``Finished = 2``, ``Armed = 3`` (constants of the enum's fields).
* ``Stg5OvercurrentStatusEnumNet`` ("the STG Overcurrent Status"): ``Normal = 0``,
  ``Shutdown = 1``; ``CStg200xBasicNet.ResetOvercurrent()`` "Reset the Overcurrent Status".
* ``CStg200xDownloadBasicNet.EnableAutoReset``: "If autoreset is enabled, the STG status
  switches to FINISHED only for one poll cycle, after this, it switches to IDLE
  automatically" (the power-up default); ``DisableAutoReset``: the status stays FINISHED
  until ``ResetStatus(triggermap)``.
* ``CStg200xDownloadNet.QueryTriggerstatus()`` returns a ``StgStatusNet`` (signature in
  the metadata; not described in the XML); the poll-status event ``OnStgPollStatus`` is
  ``Invoke(status, stgStatusNet, index_list)``.
* ``CStg200xBasicNet.GetStgVersionInfo(out string SwVersion, out string HwVersion)``
  returns ``void``; pythonnet 3 returns "the result, if any, followed by the out
  parameters" (pythonnet's own comment, "by symmetry with MethodBinder.Invoke"), i.e.
  ``(SwVersion, HwVersion)``; pythonnet 2 put a ``None`` for the void result first
  (pythonnet issue #228). Both are accepted; the old ``info[1:]`` lost the software
  version under pythonnet 3.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class TriggerStatus(enum.IntEnum):
    """``Mcs.Usb.Stg200xTriggerStatusEnumNet`` (values from the DLL's metadata)."""

    IDLE = 0
    RUNNING = 1
    FINISHED = 2
    ARMED = 3


class OvercurrentStatus(enum.IntEnum):
    """``Mcs.Usb.Stg5OvercurrentStatusEnumNet`` (the type of ``StgStatusNet``'s field; an STG5
    family enum). Not an electrode-off detector on an STG4002: an open current output drives
    the output voltage to its maximum (STG4000 manual 12.5) and nothing reports it."""

    NORMAL = 0
    SHUTDOWN = 1


@dataclass(frozen=True)
class DeviceStatus:
    """One decoded ``StgStatusNet``."""

    triggers: tuple[TriggerStatus, ...]
    overcurrent: OvercurrentStatus

    def trigger(self, index: int) -> TriggerStatus:
        """Status of trigger ``index`` (0-based); IDLE if the device did not report it."""
        return self.triggers[index] if 0 <= index < len(self.triggers) else TriggerStatus.IDLE

    @property
    def any_active(self) -> bool:
        """True if any trigger is RUNNING or ARMED."""
        return any(t in (TriggerStatus.RUNNING, TriggerStatus.ARMED) for t in self.triggers)


class UnknownStatus(ValueError):
    """A status value outside the vendor's enum (named with the value)."""


_NAMES = {"IDLE": 0, "RUNNING": 1, "FINISHED": 2, "ARMED": 3, "NORMAL": 0, "SHUTDOWN": 1}


def _enum_value(value) -> int:
    """A .NET enum value as int: ``int()`` (pythonnet 3 enum objects, plain ints), else
    by its name (``str()`` of an enum is its member name)."""
    try:
        return int(value)
    except (TypeError, ValueError):
        name = str(value).rsplit(".", 1)[-1].upper()
        if name in _NAMES:
            return _NAMES[name]
        raise ValueError(value) from None


def decode_status(stg_status) -> DeviceStatus:
    """Decode a ``StgStatusNet`` (vendor field names).

    Raises
    ------
    UnknownStatus
        If a trigger or overcurrent status is not one of the vendor's enum values (a newer
        firmware or a corrupt reply): the caller treats that as a fault.
    """
    raw = getattr(stg_status, "TiggerStatus", None)  # vendor spelling
    triggers = []
    for i, v in enumerate(list(raw) if raw is not None else []):
        try:
            triggers.append(TriggerStatus(_enum_value(v)))
        except ValueError:
            raise UnknownStatus(f"STG trigger {i + 1} reported status {v!r}, not one of "
                                "Idle 0, Running 1, Finished 2, Armed 3") from None
    oc_raw = getattr(stg_status, "OvercurrentStatus", 0)
    try:
        oc = OvercurrentStatus(_enum_value(oc_raw if oc_raw is not None else 0))
    except ValueError:
        raise UnknownStatus(f"STG reported overcurrent status {oc_raw!r}, not one of "
                            "Normal 0, Shutdown 1") from None
    return DeviceStatus(tuple(triggers), oc)


def parse_version_info(info) -> tuple[str, str]:
    """``(software, hardware)`` from what pythonnet returns for ``GetStgVersionInfo``.

    ``(sw, hw)`` for the void method as pythonnet returns it; a 3-tuple
    ``(return value, sw, hw)`` is accepted too (a binding that reports the ``None``
    return value). Anything else gives ``("", "")``.
    """
    if isinstance(info, (tuple, list)):
        items = [str(x) for x in info if x is not None]
        if len(items) >= 2:
            return items[-2], items[-1]
    return "", ""


START_TIMEOUT_S = 1.0
"""Allowance for the start delay ("The startup delay is in the range of a few ms",
``SendStart``) and late poll events before a missing Running / end is judged."""
EARLY_END_TOLERANCE_S = 0.02


class TrialProgress(enum.Enum):
    RUNNING = "running"
    ENDED = "ended"
    ENDED_UNSEEN = "ended, Running never seen"
    EARLY_END = "ended before its duration"
    OVERDUE = "still active after its duration"


def judge_trial(trig: TriggerStatus, seen_running: bool, elapsed_s: float,
                duration_s: float, *, elapsed_sent_s: float | None = None) -> TrialProgress:
    """Where a started trial is, from trigger 1's status (vendor enum) and the host's time.

    Finished, or Idle after Running was seen, is the end (with auto-reset Finished shows
    for one poll cycle only); before ``duration_s`` that is an early end. Idle or Armed
    before Running is a start still under way until ``duration_s + START_TIMEOUT_S``.
    ``elapsed_s`` counts from just before ``SendStart`` (the device cannot have started
    earlier: used for the early end), ``elapsed_sent_s`` from its return (the device
    cannot have started later: used for the overdue end).
    """
    since_sent = elapsed_s if elapsed_sent_s is None else elapsed_sent_s
    ended = trig is TriggerStatus.FINISHED or (trig is TriggerStatus.IDLE and seen_running)
    if ended:
        return (TrialProgress.EARLY_END if elapsed_s < duration_s - EARLY_END_TOLERANCE_S
                else TrialProgress.ENDED)
    if since_sent > duration_s + START_TIMEOUT_S:
        return (TrialProgress.ENDED_UNSEEN if trig is TriggerStatus.IDLE
                else TrialProgress.OVERDUE)
    return TrialProgress.RUNNING
