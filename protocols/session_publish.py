"""Publishing a new version of a session file: temp file, fsync, atomic replace.

The writer never opens the published file for writing. It keeps the file's HDF5 image in
memory (:class:`nmsid.protocols.session_writer.SessionWriter`), writes a complete new
version to ``<file>.writing-<pid>`` with plain ``os.write`` calls, fsyncs it and replaces
the file with it. So:

* a reader (``h5py.File(path)``, HDFView, another nmsid command) that has the file open
  keeps reading its consistent snapshot on Linux;
* a full disk or any other write error can only hit the temp file, which is removed; the
  published file stays as it was;
* a kill leaves either the old or the new version, and perhaps a ``.writing-<pid>`` temp
  file that the next writer or ``nmsid recover`` removes (:func:`remove_stale_temps`).

When a session is recorded (:class:`nmsid.rig.session_log.SessionLog`) the file is
published when it is created (with the calibration) and once at the end; each trial end
only writes its journal entry (the durable copy) and appends the trial to the in-memory
image. The cost of a trial end is therefore independent of how many trials came before,
and the disk holds at most the journal (about the size of the file: entries are encoded
like the file's datasets) plus one new version of the file.

Windows (:func:`nmsid.protocols.os_platform.is_windows`): replacing a file that another
process holds open fails with a sharing violation (``ERROR_SHARING_VIOLATION`` 32, or
``ERROR_ACCESS_DENIED`` 5; Microsoft, "MoveFileExW" and "ReplaceFileW": the call fails if
the destination is open without ``FILE_SHARE_DELETE``, which neither HDF5 nor Python's
``open`` pass). Antivirus scanners, the search indexer and OneDrive open freshly written
files for a moment, so :func:`replace_retrying` retries such a failure with a bounded
backoff; a file still held after that raises :class:`FileHeldError`, which names the
file: the session's journal keeps everything, and the next publish (the end of the
session, ``nmsid recover``) tries again.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from nmsid.protocols import os_platform
from nmsid.protocols.errors import DiskFullError, SessionExistsError, SessionWriteError

TEMP_TAG = ".writing-"
SPACE_MARGIN_BYTES = 1 << 20
"""Free space kept beyond each new version (metadata, the journal's next event lines)."""
_TEMP_NAME = re.compile(r"\.(writing|recovering)-\d+$")

def o_binary() -> int:
    """``os.O_BINARY`` on Windows, 0 elsewhere (looked up at each call).

    Python's ``os.open`` documentation: on Windows, ``O_BINARY`` is needed to open a file
    in binary mode; without it the C runtime's ``_open`` gives a text-mode descriptor
    (Microsoft, "_open, _wopen": text mode is the default translation) whose ``_write``
    replaces every line feed with a carriage return-line feed pair, which would corrupt an
    HDF5 signature (0x0A bytes) and every float64 stream."""
    return getattr(os, "O_BINARY", 0)


RETRY_DELAYS_S: tuple[float, ...] = (0.01, 0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6)
"""Backoff between attempts of a rename / replace refused by a transient sharing
violation on Windows (about 3.2 s in all), then :class:`FileHeldError`."""

_SHARING_WINERRORS = (5, 32, 33)
"""ERROR_ACCESS_DENIED, ERROR_SHARING_VIOLATION, ERROR_LOCK_VIOLATION (Microsoft, "System
Error Codes (0-499)")."""


class FileHeldError(SessionWriteError):
    """On Windows, another program holds the file open, so it cannot be replaced or
    renamed (after retrying). Nothing is lost: the journal keeps the data."""

    def __init__(self, path: str | os.PathLike, detail: str = ""):
        self.detail = detail
        super().__init__(path, "is open in another program (HDFView, h5py, Excel, a backup "
                               "or sync tool), so Windows refuses to replace it"
                         + (f" ({detail})" if detail else "")
                         + "; close that program; nothing is lost: the journal keeps "
                           "every trial and the next publish (the session's end, or "
                           "`nmsid recover`) writes it")


def is_sharing_violation(exc: OSError) -> bool:
    """True for the Windows errors a held file gives on rename / replace / delete: a
    ``PermissionError`` whose ``winerror`` is 5, 32 or 33 (or with no ``winerror``, as
    Windows-emulating fakes on Linux raise it)."""
    if not isinstance(exc, PermissionError):
        return False
    winerror = getattr(exc, "winerror", None)
    return winerror is None or winerror in _SHARING_WINERRORS


def retrying(op: Callable[[], object], target: str | os.PathLike, *,
             delays_s: tuple[float, ...] | None = None) -> None:
    """Run ``op`` (a rename, replace or delete of ``target``); on Windows retry a sharing
    violation after each delay of ``delays_s`` (default :data:`RETRY_DELAYS_S`).

    Raises
    ------
    FileHeldError
        If Windows still refuses after the last retry (names ``target``).
    OSError
        Any other failure, unchanged (on POSIX a refused rename is not transient).
    """
    delays = RETRY_DELAYS_S if delays_s is None else delays_s
    for attempt in range(len(delays) + 1):
        try:
            op()
            return
        except OSError as exc:
            if not (os_platform.is_windows() and is_sharing_violation(exc)):
                raise
            if attempt == len(delays):
                raise FileHeldError(target, f"{type(exc).__name__}: "
                                            f"{exc.strerror or exc}") from None
            time.sleep(delays[attempt])


def replace_retrying(src: str | os.PathLike, dst: str | os.PathLike, *,
                     delays_s: tuple[float, ...] | None = None) -> None:
    """``os.replace(src, dst)`` with :func:`retrying` (``dst`` named in the error)."""
    retrying(lambda: os.replace(src, dst), dst, delays_s=delays_s)


def rename_retrying(src: str | os.PathLike, dst: str | os.PathLike, *,
                    delays_s: tuple[float, ...] | None = None) -> None:
    """``os.rename(src, dst)`` (a folder, or never over an existing name) with
    :func:`retrying` (``src`` named in the error: it is the one held)."""
    retrying(lambda: os.rename(src, dst), src, delays_s=delays_s)


def free_bytes(folder: str | os.PathLike) -> int:
    """Bytes an unprivileged process may still write in ``folder``.

    ``shutil.disk_usage`` (Python documentation: available on Unix and Windows; ``free``
    is what the caller's quota allows, ``f_bavail * f_frsize`` on Unix,
    ``GetDiskFreeSpaceExW``'s ``lpFreeBytesAvailableToCaller`` on Windows), not
    ``os.statvfs`` (Unix only).
    """
    return int(shutil.disk_usage(folder).free)


def fsync_dir(d: str | os.PathLike) -> None:
    """Make a rename inside ``d`` durable (fsync of the folder; best effort).

    Not on Windows: a folder cannot be opened with ``os.open`` there (``_open`` refuses
    directories with EACCES), and NTFS makes a completed ``MoveFileEx`` durable in its
    own log (Microsoft, "MoveFileExW": ``MOVEFILE_WRITE_THROUGH``)."""
    if os_platform.is_windows():
        return
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _write_all(fd: int, data: memoryview) -> None:
    while data:
        n = os.write(fd, data)
        data = data[n:]


def publish_image(path: str | os.PathLike, image: bytes | memoryview, *,
                  exclusive: bool = False, doing: str = "writing it",
                  delays_s: tuple[float, ...] | None = None) -> None:
    """Write ``image`` as the new content of ``path``, atomically.

    Parameters
    ----------
    path : path-like
        The session file.
    image : bytes or memoryview
        The whole new file.
    exclusive : bool
        Refuse if ``path`` exists (a new session file: never overwrite).
    doing : str
        What the write is for, in :class:`DiskFullError`'s message.
    delays_s : tuple of float, optional
        Backoff of the Windows retry (default :data:`RETRY_DELAYS_S`).

    Raises
    ------
    DiskFullError
        If the folder lacks ``len(image)`` + :data:`SPACE_MARGIN_BYTES`, or the write hit
        ENOSPC; the file on disk is unchanged.
    SessionExistsError
        If ``exclusive`` and ``path`` exists.
    FileHeldError
        On Windows, if another program holds ``path`` open past the retries (the file on
        disk is unchanged, the temp file removed).
    SessionWriteError
        For any other refused write.
    """
    path = Path(path)
    folder = path.parent
    data = memoryview(image).cast("B")
    need = data.nbytes + SPACE_MARGIN_BYTES
    free = free_bytes(folder)
    if free < need:
        raise DiskFullError(path, need, free, doing)
    if exclusive and os.path.lexists(path):
        raise SessionExistsError(path)
    tmp = path.with_name(f"{path.name}{TEMP_TAG}{os.getpid()}")
    fd = None
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | o_binary(), 0o644)
        _write_all(fd, data)
        os.fsync(fd)
        os.close(fd)
        fd = None
        if exclusive:
            _publish_new(tmp, path, delays_s)
        else:
            replace_retrying(tmp, path, delays_s=delays_s)
    except FileExistsError:
        _discard(fd, tmp)
        raise SessionExistsError(path) from None
    except FileHeldError:
        _discard(fd, tmp)
        raise
    except OSError as exc:
        _discard(fd, tmp)
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise DiskFullError(path, need, free_bytes(folder), doing) from None
        raise SessionWriteError(path, f"cannot be written ({exc.strerror or exc})") from None
    except BaseException:
        _discard(fd, tmp)
        raise
    fsync_dir(folder)


def _publish_new(tmp: Path, path: Path, delays_s) -> None:
    """Give ``tmp`` the name ``path`` only if nothing has that name (never overwrite).

    POSIX: ``os.link`` fails with EEXIST if ``path`` exists (atomic), then the temp name
    is unlinked. Windows: ``os.rename`` "raises FileExistsError if dst exists" (Python
    documentation; ``MoveFileExW`` without ``MOVEFILE_REPLACE_EXISTING``), and hard links
    are not available on FAT / exFAT drives.
    """
    if os_platform.is_windows():
        rename_retrying(tmp, path, delays_s=delays_s)
    else:
        os.link(tmp, path)  # fails if the path appeared meanwhile: never overwrite
        os.unlink(tmp)


def _discard(fd: int | None, tmp: Path) -> None:
    if fd is not None:
        try:
            os.close(fd)
        except OSError:
            pass
    try:
        os.unlink(tmp)
    except OSError:
        pass


def stale_temps(path: str | os.PathLike) -> list[Path]:
    """Temp files of earlier writers of ``path`` (``<file>.writing-<pid>``,
    ``<file>.recovering-<pid>``). Only the session's lock holder may remove them."""
    path = Path(path)
    try:
        names = os.listdir(path.parent)
    except OSError:
        return []
    prefix = path.name
    return [path.with_name(n) for n in names
            if n.startswith(prefix) and _TEMP_NAME.fullmatch(n[len(prefix):])]


def remove_stale_temps(path: str | os.PathLike) -> list[Path]:
    """Remove :func:`stale_temps` (call only while holding the session's lock)."""
    out = []
    for p in stale_temps(path):
        try:
            os.unlink(p)
            out.append(p)
        except OSError:
            continue
    return out
