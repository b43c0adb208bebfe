"""``nmsid`` in a forked child process, for the tests that kill, signal or starve it
(``test_kill``, ``test_store_processes``): one place for the fork, the redirection and
the wait."""

from __future__ import annotations

import os
import signal
import sys


def fork_main(argv, log_path, before=None) -> int:
    """Run ``nmsid argv`` in a forked child, stdout + stderr to ``log_path``; return its
    PID. ``before()`` runs in the child first (e.g. to plant a SIGKILL at a chosen
    moment). The child's SIGINT handler is Python's default, as in a terminal."""
    pid = os.fork()
    if pid == 0:
        code = 99
        try:
            fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            sys.stdout = open(1, "w", buffering=1, closefd=False)
            sys.stderr = open(2, "w", buffering=1, closefd=False)
            signal.signal(signal.SIGINT, signal.default_int_handler)
            if before is not None:
                before()
            from nmsid.cli import main
            code = main([str(a) for a in argv])
        except BaseException:
            import traceback
            traceback.print_exc()
        finally:
            os._exit(code)
    return pid


def wait_child(pid: int) -> tuple[int, bool]:
    """``(exit code, killed by a signal?)`` of the child ``pid``."""
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status), os.WIFSIGNALED(status)
