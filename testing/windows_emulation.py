"""An emulation, on Linux, of the Windows behaviours that break POSIX-minded Python code.

No Windows machine is available to the project, so the Windows code paths are run here
against this stand-in. Each behaviour below follows Microsoft's or Python's documentation
(cited beside it); none was observed on a Windows machine. While installed:

1. **Files held open cannot be renamed, replaced or deleted.** ``os.rename``,
   ``os.replace``, ``os.remove``, ``os.unlink``, ``os.rmdir`` (and so ``shutil.rmtree``,
   ``shutil.move`` and ``pathlib``) raise ``PermissionError`` with ``winerror`` 32
   (ERROR_SHARING_VIOLATION) when the file they would move or delete is open in ANY process,
   and ``winerror`` 5 (ERROR_ACCESS_DENIED) when the target of a replace is open or a
   directory to be moved holds an open file. Open files are found by scanning
   ``/proc/*/fd`` (and ``/proc/*/cwd`` for directories). This models files opened WITHOUT
   ``FILE_SHARE_DELETE``, which is how CPython's ``open``/``os.open`` and HDF5 open them:
   CreateFileW, dwShareMode: "If this flag is not specified, but the file or device has
   been opened for delete access, the function fails" and DeleteFileW: "fails if an
   application attempts to delete a file that has other handles open for normal I/O"
   (learn.microsoft.com/windows/win32/api/fileapi/nf-fileapi-createfilew,
   .../nf-fileapi-deletefilew; system error codes 5 and 32:
   learn.microsoft.com/windows/win32/debug/system-error-codes--0-499-).
   ``os.rename`` onto an existing file raises ``FileExistsError`` (winerror 183): Python
   docs, os.rename: "On Windows, if dst exists a FileExistsError is always raised".
2. **Descriptors are text-mode unless ``O_BINARY`` is given.** ``os.O_BINARY`` (0x8000)
   and ``os.O_TEXT`` (0x4000) exist; ``os.open`` without ``O_BINARY`` gives a descriptor
   whose writes turn every ``\\n`` into ``\\r\\n`` and whose reads turn ``\\r\\n`` back
   into ``\\n`` (CRT ``_open``: "_O_TEXT ... the default"; ``_write``: "in text mode, each
   line feed character is replaced with a carriage return-line feed pair";
   learn.microsoft.com/cpp/c-runtime-library/reference/open-wopen and .../write). This is
   followed by ``os.write``/``os.read`` and by files built on the descriptor with
   ``open(fd)``/``os.fdopen(fd)``. ``os.open`` of a directory raises ``PermissionError``
   (the CRT cannot open a directory: CreateFileW needs FILE_FLAG_BACKUP_SEMANTICS for one),
   so "fsync the directory" code fails as it does there.
3. **POSIX-only functions and modules are absent.** ``os.statvfs``, ``os.fstatvfs``,
   ``os.pread``, ``os.pwrite``, ``os.fork``, ``os.forkpty``, ``os.openpty`` and
   ``signal.SIGHUP`` are removed, and ``import`` of ``pty``, ``tty``, ``fcntl``,
   ``resource``, ``termios``, ``pwd``, ``grp`` fails with ``ModuleNotFoundError`` (Python
   docs mark each "Availability: Unix"; signal: "On Windows, signal() can only be called
   with SIGABRT, SIGFPE, SIGILL, SIGINT, SIGSEGV, SIGTERM, or SIGBREAK").
   ``shutil.rmtree`` uses its non-descriptor walk, as on Windows.
4. **The default text encoding is cp1252.** ``locale.getpreferredencoding()`` and
   ``locale.getencoding()`` answer ``"cp1252"`` (the ANSI code page of Western-European
   Windows), and ``open``/``io.open``/``pathlib`` in text mode without ``encoding=`` use it
   and write ``\\r\\n`` line ends (Python docs, open: "the default encoding is platform
   dependent (whatever locale.getencoding() returns)"; newline: "translated to the system
   default line separator, os.linesep").
5. **``time.monotonic`` steps by 15.625 ms** (Python 3.11/3.12 on Windows read
   GetTickCount64, whose resolution is the 64 Hz system timer: Python docs,
   time.get_clock_info; learn.microsoft.com/windows/win32/api/sysinfoapi/
   nf-sysinfoapi-gettickcount64). Code that bound ``from time import monotonic`` before
   the emulation was installed keeps the fine clock.
6. **No C compiler on PATH.** ``shutil.which`` finds no ``cc``, ``gcc``, ``clang``,
   ``c99``, ``c89`` or ``cl`` (a stock Windows PC has none).

It also forces :mod:`nmsid.protocols.os_platform` to ``"windows"`` and answers its
``windows_api("msvcrt")`` / ``windows_api("kernel32")`` with the fakes of
:mod:`nmsid.testing.fake_windows_api` (mandatory byte-range locks, console control events;
``emulation.kernel32.deliver(CTRL_CLOSE_EVENT)`` sends one). ``os.name`` and
``sys.platform`` are left alone (the standard library depends on them).

Use it as a context manager (``with emulate_windows(): ...``), as the ``windows_emulation``
fixture, or for a whole run with pytest's ``--windows-emulation`` option (the hooks of
:mod:`nmsid.testing.platforms`, re-exported by ``tests/conftest.py``); tests that cannot
apply under it are marked ``@pytest.mark.posix_only("reason")`` and skipped with that reason.
On the Windows interpreter itself installing it changes nothing (:attr:`WindowsEmulation.real`):
the Windows tests meet Windows' own behaviour there.
"""

from __future__ import annotations

import builtins
import contextlib
import errno
import io
import locale
import math
import os
import shutil
import signal
import sys
import time
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from nmsid.protocols import os_platform
from nmsid.testing.fake_windows_api import FakeKernel32, FakeMsvcrt

#: Windows' values of the CRT's mode flags (fcntl.h of the Universal CRT).
O_BINARY = 0x8000
O_TEXT = 0x4000
#: Windows system error codes (learn.microsoft.com/windows/win32/debug/system-error-codes).
ERROR_ACCESS_DENIED = 5
ERROR_SHARING_VIOLATION = 32
ERROR_ALREADY_EXISTS = 183
#: The default Windows timer tick, 1/64 s.
TIMER_TICK_S = 0.015625
#: Modules Windows' Python does not have ("Availability: Unix").
POSIX_ONLY_MODULES = ("fcntl", "resource", "termios", "pty", "tty", "pwd", "grp")
#: Functions of ``os`` Windows' Python does not have.
POSIX_ONLY_OS_FUNCTIONS = ("statvfs", "fstatvfs", "pread", "pwrite", "fork", "forkpty",
                           "openpty")
#: Commands a stock Windows PC does not have on PATH.
HIDDEN_COMMANDS = ("cc", "gcc", "clang", "c99", "c89", "cl")

_MISSING = object()
_active: WindowsEmulation | None = None
"""The installed emulation (one at a time; a nested install reuses it)."""


def _sharing_error(winerror: int, path: Any, path2: Any = None) -> PermissionError:
    text = {ERROR_SHARING_VIOLATION: "The process cannot access the file because it is "
                                     "being used by another process",
            ERROR_ACCESS_DENIED: "Access is denied"}[winerror]
    exc = PermissionError(errno.EACCES, f"[WinError {winerror}] {text} (emulated)",
                          os.fsdecode(path) if path is not None else None, None,
                          os.fsdecode(path2) if path2 is not None else None)
    exc.winerror = winerror  # type: ignore[attr-defined]
    return exc


def _resolve(path: Any, dir_fd: int | None) -> str:
    """The absolute, symlink-free path of ``path`` (relative to ``dir_fd`` if given)."""
    p = os.fsdecode(path)
    if dir_fd is not None and not os.path.isabs(p):
        p = os.path.join(os.readlink(f"/proc/self/fd/{dir_fd}"), p)
    return os.path.realpath(p)


def held_open_paths() -> set[str]:
    """Paths that any process holds open now (``/proc/*/fd``), plus working directories.

    Returns
    -------
    set of str
        Absolute paths; processes whose tables cannot be read are skipped.
    """
    held: set[str] = set()
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            held.add(os.readlink(f"/proc/{pid}/cwd"))
        except OSError:
            pass
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith("/"):
                held.add(target)
    return held


def _is_held(path: str, held: set[str]) -> bool:
    return path in held


def _holds_inside(directory: str, held: set[str]) -> bool:
    prefix = directory.rstrip("/") + "/"
    return directory in held or any(h.startswith(prefix) for h in held)


class _TextModeRaw(io.RawIOBase):
    """A raw file over a text-mode descriptor: writes ``\\n`` as ``\\r\\n`` (CRT _write)."""

    def __init__(self, fd: int, closefd: bool = True, readable: bool = True,
                 writable: bool = True) -> None:
        super().__init__()
        self._fd, self._closefd = fd, closefd
        self._readable, self._writable = readable, writable

    def fileno(self) -> int:
        return self._fd

    def readable(self) -> bool:
        return self._readable

    def writable(self) -> bool:
        return self._writable

    def seekable(self) -> bool:
        try:
            os.lseek(self._fd, 0, os.SEEK_CUR)
        except OSError:
            return False
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        return os.lseek(self._fd, offset, whence)

    def readinto(self, b: Any) -> int:
        data = os.read(self._fd, len(b))
        b[:len(data)] = data
        return len(data)

    def write(self, b: Any) -> int:
        os.write(self._fd, bytes(b))
        return len(b)

    def close(self) -> None:
        if not self.closed and self._closefd:
            os.close(self._fd)
        super().close()


class WindowsEmulation:
    """Installs and removes the emulated Windows behaviours (module docstring).

    Parameters
    ----------
    hidden_commands : tuple of str
        Commands ``shutil.which`` does not find (default: the C compilers).
    timer_tick_s : float
        Step of ``time.monotonic``, s (default 1/64 s).
    """

    def __init__(self, hidden_commands: tuple[str, ...] = HIDDEN_COMMANDS,
                 timer_tick_s: float = TIMER_TICK_S) -> None:
        self.hidden_commands = frozenset(hidden_commands)
        self.timer_tick_s = timer_tick_s
        self.text_fds: dict[int, tuple[int, int]] = {}  # fd -> (st_dev, st_ino)
        self._saved: list[tuple[Any, str, Any]] = []
        self._modules: dict[str, Any] = {}
        self._platform: contextlib.AbstractContextManager[None] | None = None
        self._api: contextlib.AbstractContextManager[None] | None = None
        self.msvcrt: Any = None
        self.kernel32: Any = None
        self.installed = False
        self._nested = False
        #: True on the Windows interpreter, where nothing is emulated: ``msvcrt`` and
        #: ``kernel32`` stay None (tests of the fakes are marked ``emulation_only``)
        self.real = False

    def is_text(self, fd: int) -> bool:
        """True if ``fd`` is a text-mode descriptor opened under the emulation (a number
        closed elsewhere, e.g. by C code, and reused for another file is not)."""
        ident = self.text_fds.get(fd)
        if ident is None:
            return False
        try:
            st = os.fstat(fd)
        except OSError:
            st = None
        if st is None or (st.st_dev, st.st_ino) != ident:
            self.text_fds.pop(fd, None)
            return False
        return True

    # -- patching --------------------------------------------------------------------
    def _set(self, obj: Any, name: str, value: Any) -> None:
        self._saved.append((obj, name, getattr(obj, name, _MISSING)))
        setattr(obj, name, value)

    def _remove(self, obj: Any, name: str) -> None:
        if hasattr(obj, name):
            self._saved.append((obj, name, getattr(obj, name)))
            delattr(obj, name)

    def install(self) -> WindowsEmulation:
        """Switch the emulated behaviours on (idempotent per instance)."""
        if self.installed:
            return self
        if sys.platform == "win32":  # the Windows interpreter: its own behaviour applies
            self.installed = self.real = True
            return self
        global _active
        if _active is not None:  # nested inside another emulation: it already applies
            self.msvcrt, self.kernel32 = _active.msvcrt, _active.kernel32
            self.text_fds = _active.text_fds
            self.installed, self._nested = True, True
            return self
        fake_msvcrt = FakeMsvcrt()  # it uses fcntl: made before fcntl is hidden
        o = {n: getattr(os, n) for n in ("rename", "replace", "remove", "unlink", "rmdir",
                                          "open", "write", "read", "close", "fdopen")}
        real_open, real_which = builtins.open, shutil.which
        real_monotonic, real_monotonic_ns = time.monotonic, time.monotonic_ns
        real_clock_info = time.get_clock_info
        emu = self

        def _lexists(p: str) -> bool:
            # the file system's own answer (a test may patch os.path.lexists to stage a race)
            try:
                os.lstat(p)
            except OSError:
                return False
            return True

        # 1. files held open cannot be moved or deleted (CreateFileW share modes)
        def check_move(src: Any, dst: Any, src_dir_fd: int | None,
                       dst_dir_fd: int | None, replace: bool) -> None:
            s, d = _resolve(src, src_dir_fd), _resolve(dst, dst_dir_fd)
            if not replace and _lexists(d) and s != d:
                exc = FileExistsError(errno.EEXIST, "[WinError 183] Cannot create a file "
                                      "when that file already exists (emulated)",
                                      os.fsdecode(src), None, os.fsdecode(dst))
                exc.winerror = ERROR_ALREADY_EXISTS  # type: ignore[attr-defined]
                raise exc
            held = held_open_paths()
            if os.path.isdir(s) and not os.path.islink(s):
                if _holds_inside(s, held):
                    raise _sharing_error(ERROR_ACCESS_DENIED, src, dst)
            elif _is_held(s, held):
                raise _sharing_error(ERROR_SHARING_VIOLATION, src, dst)
            if s != d and _is_held(d, held):
                raise _sharing_error(ERROR_ACCESS_DENIED, src, dst)

        def rename(src: Any, dst: Any, *, src_dir_fd: int | None = None,
                   dst_dir_fd: int | None = None) -> None:
            check_move(src, dst, src_dir_fd, dst_dir_fd, replace=False)
            o["rename"](src, dst, src_dir_fd=src_dir_fd, dst_dir_fd=dst_dir_fd)

        def replace(src: Any, dst: Any, *, src_dir_fd: int | None = None,
                    dst_dir_fd: int | None = None) -> None:
            check_move(src, dst, src_dir_fd, dst_dir_fd, replace=True)
            o["replace"](src, dst, src_dir_fd=src_dir_fd, dst_dir_fd=dst_dir_fd)

        def make_delete(name: str) -> Callable[..., None]:
            def delete(path: Any, *, dir_fd: int | None = None) -> None:
                # Python's own tempfile.TemporaryFile: on Windows it IS NamedTemporaryFile,
                # opened with O_TEMPORARY and deleted by the system at close (tempfile.py);
                # on Linux it unlinks its open file at once. Its own call is let through,
                # as Windows' delete-on-close would be (pytest's capture uses it).
                caller = sys._getframe(1).f_globals.get("__name__")
                if caller != "tempfile" and _is_held(_resolve(path, dir_fd),
                                                     held_open_paths()):
                    raise _sharing_error(ERROR_SHARING_VIOLATION, path)
                o[name](path, dir_fd=dir_fd)
            delete.__name__ = name
            return delete

        def rmdir(path: Any, *, dir_fd: int | None = None) -> None:
            if _holds_inside(_resolve(path, dir_fd), held_open_paths()):
                raise _sharing_error(ERROR_SHARING_VIOLATION, path)
            o["rmdir"](path, dir_fd=dir_fd)

        # 2. text-mode descriptors (CRT _open / _write / _read)
        def os_open(path: Any, flags: int, mode: int = 0o777, *,
                    dir_fd: int | None = None) -> int:
            if os.path.isdir(_resolve(path, dir_fd)):
                raise PermissionError(errno.EACCES, "Permission denied (emulated: the "
                                      "CRT cannot open a directory)", os.fsdecode(path))
            fd = o["open"](path, flags & ~(O_BINARY | O_TEXT), mode, dir_fd=dir_fd)
            if not flags & O_BINARY:
                st = os.fstat(fd)
                emu.text_fds[fd] = (st.st_dev, st.st_ino)
            else:
                emu.text_fds.pop(fd, None)
            return fd

        def os_write(fd: int, data: Any) -> int:
            if emu.is_text(fd):
                data = bytes(data)
                o["write"](fd, data.replace(b"\n", b"\r\n"))
                return len(data)
            return o["write"](fd, data)

        def os_read(fd: int, n: int) -> bytes:
            data = o["read"](fd, n)
            return data.replace(b"\r\n", b"\n") if emu.is_text(fd) else data

        def os_close(fd: int) -> None:
            emu.text_fds.pop(fd, None)
            o["close"](fd)

        # 4. cp1252 and \r\n for text files opened without an encoding
        def emulated_open(file: Any, mode: str = "r", buffering: int = -1,
                          encoding: str | None = None, errors: str | None = None,
                          newline: str | None = None, closefd: bool = True,
                          opener: Any = None) -> Any:
            if isinstance(file, int) and emu.is_text(file):
                raw = _TextModeRaw(file, closefd, readable="r" in mode or "+" in mode,
                                   writable=any(c in mode for c in "wax+"))
                binary: Any
                if "+" in mode:
                    binary = io.BufferedRandom(raw)
                elif raw.writable():
                    binary = io.BufferedWriter(raw)
                else:
                    binary = io.BufferedReader(raw)
                if "b" in mode:
                    return raw if buffering == 0 else binary
                return io.TextIOWrapper(binary, encoding or "cp1252", errors, newline)
            if "b" not in mode:
                if encoding is None or encoding == "locale":
                    encoding = "cp1252"
                if newline is None and "+" not in mode and "r" not in mode:
                    newline = "\r\n"
            return real_open(file, mode, buffering, encoding, errors, newline, closefd,
                             opener)

        def fdopen(fd: int, mode: str = "r", buffering: int = -1, *args: Any,
                   **kwargs: Any) -> Any:
            return emulated_open(fd, mode, buffering, *args, **kwargs)

        # 5. the 64 Hz timer
        tick = self.timer_tick_s
        tick_ns = round(tick * 1e9)

        def monotonic() -> float:
            return math.floor(real_monotonic() / tick) * tick

        def monotonic_ns() -> int:
            return real_monotonic_ns() // tick_ns * tick_ns

        def get_clock_info(name: Any) -> Any:
            info = real_clock_info(name)
            if name == "monotonic":
                return types.SimpleNamespace(**{**vars(info), "resolution": tick,
                                                "implementation": "GetTickCount64()"})
            return info

        # 3. shutil.disk_usage exists on Windows (GetDiskFreeSpaceExW); on Linux it calls
        # the os.statvfs removed below, so it keeps a private reference
        real_statvfs = os.statvfs

        def disk_usage(path: Any) -> Any:
            st = real_statvfs(path)
            free, total = st.f_bavail * st.f_frsize, st.f_blocks * st.f_frsize
            return shutil._ntuple_diskusage(total, (st.f_blocks - st.f_bfree)  # type: ignore[attr-defined]
                                            * st.f_frsize, free)

        # 6. no C compiler
        def which(cmd: Any, mode: int = os.F_OK | os.X_OK, path: Any = None) -> Any:
            if Path(os.fsdecode(cmd)).stem.lower() in emu.hidden_commands:
                return None
            return real_which(cmd, mode, path)

        for name, fn in (("rename", rename), ("replace", replace),
                         ("remove", make_delete("remove")),
                         ("unlink", make_delete("unlink")), ("rmdir", rmdir),
                         ("open", os_open), ("write", os_write), ("read", os_read),
                         ("close", os_close), ("fdopen", fdopen)):
            self._set(os, name, fn)
        self._set(os, "O_BINARY", O_BINARY)
        self._set(os, "O_TEXT", O_TEXT)
        self._set(shutil, "_use_fd_functions", False)
        self._set(builtins, "open", emulated_open)
        self._set(io, "open", emulated_open)
        # 3. POSIX-only functions and modules
        for name in POSIX_ONLY_OS_FUNCTIONS:
            self._remove(os, name)
        self._remove(signal, "SIGHUP")
        # pyserial picks its backend by sys.platform when first imported (serialposix needs
        # termios; on Windows it is serialwin32, which needs none of the blocked modules):
        # import it before the block, as a Windows process would have its own backend
        with contextlib.suppress(ImportError):
            import serial  # noqa: F401, PLC0415
        for name in POSIX_ONLY_MODULES:
            self._modules[name] = sys.modules.get(name, _MISSING)
            sys.modules[name] = None  # type: ignore[assignment]  # import -> ImportError
        self._set(locale, "getpreferredencoding", lambda do_setlocale=True: "cp1252")
        if hasattr(locale, "getencoding"):
            self._set(locale, "getencoding", lambda: "cp1252")
        self._set(time, "monotonic", monotonic)
        self._set(time, "monotonic_ns", monotonic_ns)
        self._set(time, "get_clock_info", get_clock_info)
        self._set(shutil, "which", which)
        self._set(shutil, "disk_usage", disk_usage)
        self._platform = os_platform.forced("windows")
        self._platform.__enter__()
        self.msvcrt, self.kernel32 = fake_msvcrt.enforce(), FakeKernel32()
        self._api = os_platform.fake_windows_api(msvcrt=self.msvcrt, kernel32=self.kernel32)
        self._api.__enter__()
        self.installed, _active = True, self
        return self

    def uninstall(self) -> None:
        """Restore everything :meth:`install` changed, in reverse order."""
        if not self.installed:
            return
        if self.real or self._nested:
            self.installed = self.real = False
            self.installed = self._nested = False
            return
        global _active
        _active = None
        if self._api is not None:
            self._api.__exit__(None, None, None)
            self._api = None
        if self.msvcrt is not None:
            self.msvcrt.unenforce()  # before the patches below are restored
        for obj, name, value in reversed(self._saved):
            if value is _MISSING:
                if hasattr(obj, name):
                    delattr(obj, name)
            else:
                setattr(obj, name, value)
        self._saved.clear()
        for name, module in self._modules.items():
            if module is _MISSING:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module
        self._modules.clear()
        self.text_fds.clear()
        if self._platform is not None:
            self._platform.__exit__(None, None, None)
            self._platform = None
        self.installed = False

    def __enter__(self) -> WindowsEmulation:  # noqa: PYI034
        return self.install()

    def __exit__(self, *exc: object) -> None:
        self.uninstall()


@contextlib.contextmanager
def emulate_windows(**options: Any) -> Iterator[WindowsEmulation]:
    """Run the ``with`` block under the emulated Windows behaviours.

    Parameters
    ----------
    **options
        Passed to :class:`WindowsEmulation`.

    Examples
    --------
    >>> import os
    >>> from nmsid.testing.windows_emulation import emulate_windows
    >>> with emulate_windows():
    ...     hasattr(os, "statvfs")
    False
    """
    emulation = WindowsEmulation(**options).install()
    try:
        yield emulation
    finally:
        emulation.uninstall()


#: Uses that make a test module unable to run under the emulation (it has no fork, ...).
_POSIX_ATTRIBUTES = {("os", n) for n in POSIX_ONLY_OS_FUNCTIONS} | {("signal", "SIGHUP")}


def posix_only_uses(path: Any) -> list[str]:
    """What in a test module needs POSIX (``os.fork``, ``signal.SIGHUP``, ``import pty``,
    the forked-CLI helper), found in its syntax tree (strings and comments do not count).

    Returns
    -------
    list of str
        Sorted names; empty if the module can run under the emulation.
    """
    import ast

    try:
        tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    except (OSError, SyntaxError, UnicodeDecodeError):
        return []
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and (node.value.id, node.attr) in _POSIX_ATTRIBUTES:
            found.add(f"{node.value.id}.{node.attr}")
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name in POSIX_ONLY_MODULES)
        elif isinstance(node, ast.ImportFrom) and node.module:
            if node.module.split(".")[0] in POSIX_ONLY_MODULES and not node.level:
                found.add(node.module)
            if node.module.split(".")[-1] == "forked_cli":
                found.add("forked_cli (os.fork)")
    return sorted(found)
