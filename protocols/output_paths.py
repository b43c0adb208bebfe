"""Where commands write their results: never over what the user did not ask to replace.

Every command that writes a file or a folder goes through this module (one place, not one
copy per command):

* :func:`check_output` refuses, before any work (and before any device is touched), an
  ``--out`` that exists (unless ``force``), that is a session file (an HDF5 file whose
  ``format`` is ``nmsid-session``: never replaced, even with ``force``), a folder holding
  one, a dangling symbolic link, or a place that cannot be written;
* :func:`output_file` and :func:`output_dir` write into a temporary file / folder beside
  the target and rename it into place only when the command succeeded, so a kill never
  leaves half a result, and never mixes old and new results. With ``force`` an existing
  file is replaced by one ``os.replace`` (atomic); an existing folder is first renamed
  aside, the new one renamed in, then the old one deleted (two renames: atomic per rename,
  which is as far as POSIX goes for a non-empty folder).

Every folder :func:`output_dir` writes holds a manifest, :data:`MANIFEST_NAME`, listing
each file and folder nmsid put there (issue 39). ``--force`` replaces a folder only when
everything in it is listed there: a folder nmsid did not write (a source folder, a data
folder, ``~``) or one the user has added a file to is refused in one line and left
intact, with or without ``--force``.

Windows (issue 24): a file another program holds open (a CSV in Excel, a figure in a
viewer) cannot be replaced or deleted there (MoveFileExW / DeleteFileW fail with
ERROR_ACCESS_DENIED or ERROR_SHARING_VIOLATION). Then the fresh result is kept beside the
target under a free name (``twin-new.json``, ``twin-new-2.json``, ...) and the command ends
with one line naming both; it is never deleted. ``os.access`` says nothing about a folder
there (it checks only the read-only attribute), so writability is checked by creating and
removing a temporary file. :func:`default_sessions_dir` keeps sessions out of the Windows
folder (a shortcut's working directory is often ``C:\\Windows\\System32``).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import h5py

from nmsid.protocols import os_platform
from nmsid.protocols.errors import OutputPathError
from nmsid.protocols.session_file import FORMAT as SESSION_FORMAT
from nmsid.protocols.user_values import (  # noqa: F401 (re-exported: the name limits)
    DERIVED_SUFFIXES,
    LONGEST_SUFFIX_BYTES,
    MAX_SESSION_NAME_BYTES,
    name_length_problem,
    non_utf8_problem,
)

#: HDF5's format signature; it sits at byte 0, 512, 1024, 2048, ... of a file.
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: Temporary names start with this (beside the target, so a rename never crosses devices).
TMP_PREFIX = ".nmsid-tmp-"
#: The manifest :func:`output_dir` writes into every output folder: what nmsid wrote there.
MANIFEST_NAME = ".nmsid-output.json"
MANIFEST_FORMAT = "nmsid-output-manifest"


def is_session_file(path) -> bool:
    """True if ``path`` is (or might be) an nmsid session file.

    An HDF5 file whose root ``format`` attribute is ``nmsid-session``, or an HDF5 file
    that cannot be opened to tell (damaged, or locked by a live writer): those are treated
    as session files, since guessing wrong would destroy data.
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(8)
            if head != _HDF5_SIGNATURE:
                fh.seek(512)
                if fh.read(8) != _HDF5_SIGNATURE:
                    return False
    except OSError:
        return False
    try:
        with h5py.File(p, "r", locking=False) as f:
            fmt = f.attrs.get("format", b"")
    except Exception:
        return True
    if isinstance(fmt, bytes):
        fmt = fmt.decode("utf-8", "replace")
    return str(fmt) == SESSION_FORMAT


def _session_files_in(folder: Path, depth: int = 2) -> list[Path]:
    found: list[Path] = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return found
    for e in entries:
        if e.is_symlink():
            continue
        if e.is_dir() and depth > 1:
            found += _session_files_in(e, depth - 1)
        elif e.is_file() and is_session_file(e):
            found.append(e)
    return found


def check_output(path, *, force: bool = False, kind: str = "file",
                 option: str = "--out") -> Path:
    """Refuse an output place before any work; return it as a ``Path``.

    Parameters
    ----------
    path : path-like
        The ``--out`` the user gave.
    force : bool
        The user asked to replace an existing output (``--force``).
    kind : {"file", "folder"}
        What the command writes there.
    option : str
        The option's name, for the message.

    Raises
    ------
    OutputPathError
        One line naming the path, what is wrong and what would be valid.
    """
    p = Path(path)
    if str(path) == "" or "\x00" in str(path):
        raise OutputPathError(f"{option} {str(path)!r}: not a usable path; give a {kind} name")
    if p.is_symlink() and not p.exists():
        raise OutputPathError(f"{option} {p}: a dangling symbolic link (to "
                              f"{os.readlink(p)}); give a real {kind} path")
    if p.exists():
        if p.is_file() and is_session_file(p):
            raise OutputPathError(f"{option} {p}: is a session file; nmsid never overwrites a "
                                  f"session file, even with --force; give another {kind}")
        if kind == "file" and p.is_dir():
            raise OutputPathError(f"{option} {p}: is a folder; give a file name")
        if kind == "folder" and not p.is_dir():
            raise OutputPathError(f"{option} {p}: is a file; give a folder name")
        if kind == "folder":
            inside = _session_files_in(p)
            if inside:
                raise OutputPathError(f"{option} {p}: holds the session file {inside[0]}; "
                                      f"nmsid never replaces a folder holding session "
                                      f"files, even with --force; give another folder")
            if any(p.iterdir()):
                if not force:
                    raise OutputPathError(f"{option} {p}: the folder exists and is not "
                                          "empty; give --force to replace it, or another "
                                          "folder")
                foreign = foreign_entry(p)
                if foreign is not None:
                    raise OutputPathError(f"{option} {p}: {foreign}; --force replaces only a "
                                          f"folder nmsid wrote (listed in its "
                                          f"{MANIFEST_NAME}); nothing was changed; give "
                                          f"another folder")
        elif not force:
            raise OutputPathError(f"{option} {p}: the file exists; give --force to replace "
                                  "it, or another file name")
    parent = _existing_ancestor(p.absolute().parent)
    if not parent.is_dir():
        raise OutputPathError(f"{option} {p}: {parent} is not a folder; give a path inside "
                              "a folder")
    if not _can_write_in(parent):
        raise OutputPathError(f"{option} {p}: cannot write in {parent} (permission denied); "
                              f"give a {kind} in a writable folder")
    return p


def _walk(folder: Path) -> list[str]:
    """Every file and folder under ``folder``, as POSIX paths relative to it (links are
    listed, never followed)."""
    found: list[str] = []
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        rel = Path(dirpath).relative_to(folder)
        for name in dirnames + filenames:
            found.append((rel / name).as_posix())
    return sorted(found)


def write_manifest(folder, command: str = "") -> Path:
    """Write :data:`MANIFEST_NAME` into ``folder``: everything in it now, as nmsid's."""
    folder = Path(folder)
    entries = [e for e in _walk(folder) if e != MANIFEST_NAME]
    path = folder / MANIFEST_NAME
    path.write_text(json.dumps({"format": MANIFEST_FORMAT, "format_version": 1,
                                "command": command, "entries": entries}, indent=1) + "\n",
                    encoding="utf-8")
    return path


def foreign_entry(folder) -> str | None:
    """Why ``folder`` is not entirely nmsid's output (one phrase), or None if it is.

    It is nmsid's when it holds a readable :data:`MANIFEST_NAME` and nothing that the
    manifest does not list.
    """
    folder = Path(folder)
    manifest = folder / MANIFEST_NAME
    try:
        data = json.loads(manifest.read_text(encoding="utf-8"))
        listed = set(data["entries"]) if data.get("format") == MANIFEST_FORMAT else None
    except (OSError, ValueError, KeyError, TypeError):
        listed = None
    if listed is None:
        first = next((e for e in _walk(folder)), "?")
        return f"nmsid did not write this folder (no {MANIFEST_NAME}; it holds {first})"
    for entry in _walk(folder):
        if entry != MANIFEST_NAME and entry not in listed:
            return f"holds {entry}, which nmsid did not write"
    return None


def _can_write_in(folder: Path) -> bool:
    """Whether a file can be created in ``folder``.

    POSIX: ``os.access``. Windows: ``os.access`` looks only at the read-only attribute and
    never refuses a folder (Python docs, os.access), so a temporary file is created and
    removed instead.
    """
    if not os_platform.is_windows():
        return os.access(folder, os.W_OK | os.X_OK)
    try:
        fd, name = tempfile.mkstemp(prefix=TMP_PREFIX, dir=folder)
    except OSError:
        return False
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(name)
    return True


def _free_name(p: Path, tag: str = "-new") -> Path:
    """``p`` with ``tag`` (then ``-2``, ``-3``, ...) before its suffix: a name not taken."""
    stem, suffix = (p.stem, p.suffix) if p.suffix and not p.is_dir() else (p.name, "")
    candidate = p.with_name(f"{stem}{tag}{suffix}")
    k = 2
    while candidate.exists() or candidate.is_symlink():
        candidate = p.with_name(f"{stem}{tag}-{k}{suffix}")
        k += 1
    return candidate


def _held_open(p: Path, fresh: Path, option: str, exc: OSError) -> OutputPathError:
    """Keep the fresh result ``fresh`` under a free name beside ``p``; the one-line error."""
    kept = _free_name(p)
    os.rename(fresh, kept)
    return OutputPathError(f"{option} {p}: cannot be replaced ({exc.strerror or exc}: "
                           f"is it open in another program, e.g. Excel?); the new result is "
                           f"kept in {kept}: close the program and move it, or give "
                           f"another {option}")


def default_sessions_dir(cwd: str | os.PathLike | None = None,
                         environ: dict | None = None) -> Path:
    """Where ``nmsid run`` puts sessions when no ``--out`` / ``--outdir`` is given.

    ``sessions`` in the working directory, except on Windows when the working directory
    is inside the Windows folder (``%SystemRoot%``, e.g. ``C:\\Windows\\System32``, the
    working directory of many shortcuts and of a console started as administrator):
    then ``Documents\\nmsid\\sessions`` in the user's profile, so sessions are not
    written among system files (or refused there) and are found again.

    Parameters
    ----------
    cwd : path-like, optional
        The working directory (default: the process's).
    environ : dict, optional
        The environment (default: ``os.environ``): ``SystemRoot`` / ``windir`` and
        ``USERPROFILE``.
    """
    env = os.environ if environ is None else environ
    here = Path(os.getcwd() if cwd is None else cwd)
    if os_platform.is_windows():
        system = env.get("SystemRoot") or env.get("windir") or "C:\\Windows"
        norm = str(here).replace("/", "\\").rstrip("\\").lower()
        root = system.replace("/", "\\").rstrip("\\").lower()
        if norm == root or norm.startswith(root + "\\"):
            profile = env.get("USERPROFILE") or str(Path.home())
            return Path(profile) / "Documents" / "nmsid" / "sessions"
    return Path("sessions")


def check_session_name(path, *, option: str = "--out") -> Path:
    """Refuse, before any device is connected, a session file name that the journal and
    recovery could not derive their names from: longer than
    :data:`MAX_SESSION_NAME_BYTES` (UTF-8 bytes; the longest derived name adds
    :data:`LONGEST_SUFFIX_BYTES`, see :data:`DERIVED_SUFFIXES`), or holding bytes that
    are not UTF-8.

    Raises
    ------
    OutputPathError
        One line naming the option, the name and the limit.
    """
    text = os.fspath(path)
    problem = non_utf8_problem(text) or name_length_problem(text)
    if problem:
        raise OutputPathError(f"{option}: {problem}")
    return Path(text)


def _existing_ancestor(folder: Path) -> Path:
    while not folder.exists() and folder != folder.parent:
        if folder.is_symlink():  # a dangling link among the parents
            raise OutputPathError(f"{folder}: a dangling symbolic link (to "
                                  f"{os.readlink(folder)}); give a real folder")
        folder = folder.parent
    return folder


def _tmp_beside(p: Path) -> Path:
    return p.with_name(f"{TMP_PREFIX}{p.name}-{os.getpid()}")


@contextlib.contextmanager
def output_file(path, *, force: bool = False, option: str = "--out"):
    """Yield a temporary path beside ``path``; on success it replaces ``path`` (checked
    by :func:`check_output` first). On any error the temporary file is removed and
    ``path`` is untouched."""
    p = check_output(path, force=force, kind="file", option=option)
    p.absolute().parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_beside(p)
    try:
        yield tmp
        if p.exists() and is_session_file(p):  # appeared while we worked
            raise OutputPathError(f"{option} {p}: became a session file meanwhile; not "
                                  f"replaced; the result is in {tmp}")
        if p.exists() and not force:
            raise OutputPathError(f"{option} {p}: appeared while the command ran; not "
                                  f"replaced (give --force)")
        try:
            os.replace(tmp, p)
        except PermissionError as exc:  # Windows: p is open in another program
            raise _held_open(p, tmp, option, exc) from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            if tmp.exists() and not (p.exists() and p.samefile(tmp)):
                tmp.unlink()


@contextlib.contextmanager
def output_dir(path, *, force: bool = False, option: str = "--out", command: str = ""):
    """Yield a temporary folder beside ``path``; on success its manifest
    (:func:`write_manifest`) is written and it is renamed to ``path`` (an existing one,
    allowed by ``force`` only when nmsid wrote all of it, is renamed aside first and then
    deleted). On any error the temporary folder is deleted and ``path`` is untouched.
    ``command`` is recorded in the manifest."""
    p = check_output(path, force=force, kind="folder", option=option)
    p.absolute().parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_beside(p)
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        yield tmp
        write_manifest(tmp, command)
        old = None
        if p.exists():
            check_output(p, force=force, kind="folder", option=option)  # still allowed?
            old = p.with_name(f"{TMP_PREFIX}{p.name}-old-{os.getpid()}")
            try:
                os.rename(p, old)
            except PermissionError as exc:  # Windows: a file in p is open elsewhere
                raise _held_open(p, tmp, option, exc) from None
        try:
            os.rename(tmp, p)
        except OSError as exc:
            if old is not None:  # put the old results back where they were
                os.rename(old, p)
            if not isinstance(exc, PermissionError):
                raise
            try:  # Windows: a fresh file held open (a virus scanner): keep the results
                error = _held_open(p, tmp, option, exc)
            except OSError:
                raise exc from None
            raise error from None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
