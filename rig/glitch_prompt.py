"""How headless ``nmsid run`` confirms resuming after a device glitch between trials.

:func:`glitch_confirmation` gives the engine's ``on_device_glitch``: with
``--resume-after-reconnect`` a successful reconnect is confirmed in advance (a failed one
ends the session); on an interactive terminal the operator is asked; otherwise the answer
is "no" and the session ends cleanly, to be continued with ``--resume``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable


def glitch_confirmation(resume_after_reconnect: bool, *, stdin=None,
                        stdout=None) -> Callable[[str, bool], bool]:
    """The ``on_device_glitch(description, reconnected) -> bool`` for ``nmsid run``."""
    stdin = stdin or sys.stdin
    stdout = stdout or sys.stdout
    if resume_after_reconnect:
        def confirm(what: str, reconnected: bool) -> bool:
            print(f"\n{what}; " + ("resuming (--resume-after-reconnect)" if reconnected
                                   else "ending the session"), file=stdout, flush=True)
            return reconnected
        return confirm
    if stdin.isatty():
        def ask(what: str, reconnected: bool) -> bool:
            question = ("Output is off. Check the participant and the devices; resume the "
                        "session?" if reconnected else
                        "Output is off. Check the cable; try to reconnect again?")
            print(f"\n{what}.\n{question} [y/N] ", end="", file=stdout, flush=True)
            line = stdin.readline()
            return line.strip().lower() in ("y", "yes")
        return ask

    def refuse(what: str, reconnected: bool) -> bool:
        print(f"\n{what}; no terminal to confirm on, ending the session (continue it with "
              "--resume, or pass --resume-after-reconnect)", file=stdout, flush=True)
        return False
    return refuse
