"""Publishing a new version of a session file: temp file, fsync, atomic rename.

The writer never opens the published file for writing. It keeps the file's HDF5 image in
memory, changes it there (h5py on a ``BytesIO``), writes the whole new image to
``<file>.writing-<pid>`` with plain ``os.write`` calls, fsyncs it and renames it over the
file. So:

* a reader (``h5py.File(path)`` with HDF5's default locking, HDFView, another nmsid
  command) that has the file open keeps reading its consistent snapshot, and never blocks
  the writer: they no longer share an inode, nor HDF5's lock;
* a full disk or any other write error can only hit the temp file, which is removed; the
  published file stays as it was, and HDF5 never sees a failing write (h5py could crash on
  one);
* a kill leaves either the old or the new version, and perhaps a ``.writing-<pid>`` temp
  file that the next writer or ``nmsid recover`` removes (:func:`remove_stale_temps`).
"""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path

from nmsid.protocols.errors import DiskFullError, SessionExistsError, SessionWriteError

TEMP_TAG = ".writing-"
SPACE_MARGIN_BYTES = 1 << 20
"""Free space kept beyond each new version (metadata, the journal's next event lines)."""
_TEMP_NAME = re.compile(r"\.(writing|recovering)-\d+$")


def free_bytes(folder: str | os.PathLike) -> int:
    """Bytes an unprivileged process may still write in ``folder``."""
    st = os.statvfs(folder)
    return int(st.f_bavail) * int(st.f_frsize)


def fsync_dir(d: str | os.PathLike) -> None:
    """Make a rename inside ``d`` durable (fsync of the folder; best effort)."""
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


def publish_image(path: str | os.PathLike, image: bytes, *, exclusive: bool = False,
                  doing: str = "writing it") -> None:
    """Write ``image`` as the new content of ``path``, atomically.

    Parameters
    ----------
    path : path-like
        The session file.
    image : bytes
        The whole new file.
    exclusive : bool
        Refuse if ``path`` exists (a new session file: never overwrite).
    doing : str
        What the write is for, in :class:`DiskFullError`'s message.

    Raises
    ------
    DiskFullError
        If the folder lacks ``len(image)`` + :data:`SPACE_MARGIN_BYTES`, or the write hit
        ENOSPC; the file on disk is unchanged.
    SessionExistsError
        If ``exclusive`` and ``path`` exists.
    SessionWriteError
        For any other refused write.
    """
    path = Path(path)
    folder = path.parent
    need = len(image) + SPACE_MARGIN_BYTES
    free = free_bytes(folder)
    if free < need:
        raise DiskFullError(path, need, free, doing)
    if exclusive and os.path.lexists(path):
        raise SessionExistsError(path)
    tmp = path.with_name(f"{path.name}{TEMP_TAG}{os.getpid()}")
    fd = None
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        _write_all(fd, memoryview(image))
        os.fsync(fd)
        os.close(fd)
        fd = None
        if exclusive:
            os.link(tmp, path)  # fails if the path appeared meanwhile: never overwrite
            os.unlink(tmp)
        else:
            os.replace(tmp, path)
    except FileExistsError:
        _discard(fd, tmp)
        raise SessionExistsError(path) from None
    except OSError as exc:
        _discard(fd, tmp)
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise DiskFullError(path, need, free_bytes(folder), doing) from None
        raise SessionWriteError(path, f"cannot be written ({exc.strerror or exc})") from None
    except BaseException:
        _discard(fd, tmp)
        raise
    fsync_dir(folder)


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
        except IsADirectoryError:
            continue
        except OSError:
            continue
    return out
