"""The exit status of a session that ran to its end (``nmsid run``), as the README says:
1 is only ever a bug."""

from __future__ import annotations

from nmsid.errors import EXIT_USER_ERROR, DeviceFault, SafetyError

#: ``nmsid recover`` found nothing to recover (a session that ended before calibration),
#: or a file still invalid after recovery: a bad file, the user's to act on.
EXIT_NOTHING_TO_RECOVER = EXIT_USER_ERROR


def run_exit_status(summary) -> int:
    """0 for a complete schedule or an operator's end (the summary line says how to
    continue); :attr:`SafetyError.exit_code` (4) when an interlock trip ended the session
    (a waveform refused by its charge-balance or ceiling check trips the interlock too);
    :attr:`DeviceFault.exit_code` (3) when a device glitch ended it for ``--resume``."""
    ended_by = str(summary.ended_by)
    if ended_by.startswith("interlock"):
        return SafetyError.exit_code
    if ended_by.endswith("session ended for --resume"):
        return DeviceFault.exit_code
    return 0
