"""Point Windows extension modules at the complex-math shim (cmath_shim.c), for Wine 8.0.

Wine 8.0's ucrtbase has the C99 complex functions (``cexp``, ``cabs``, ``crealf``, ...) only
as stubs that abort the process; numpy >= 2 calls ``crealf`` at import, scipy.special and
scipy.signal call the rest. The shim ``apx-ms-win-crt-math-l1-1-0.dll`` implements them and
forwards every other math name to ucrtbase. A module is pointed at it by renaming, in its
import table, ``api-ms-win-crt-math-l1-1-0.dll`` to the same-length shim name (an
``api-ms-*`` name is an API set that Wine resolves itself: no DLL override reaches it).

    python3 ucrt_math.py def PYTHON_DIR OUT.def     the shim's export list
    python3 ucrt_math.py patch PYTHON_DIR           rename the import in modules that need it

Reads the import tables itself (:func:`pe_imports`).
"""

from __future__ import annotations

import re
import struct
import sys
from pathlib import Path

API_SET = "api-ms-win-crt-math-l1-1-0.dll"
SHIM = "apx-ms-win-crt-math-l1-1-0.dll"
#: The functions the shim implements (cmath_shim.c), each in double, float, long double.
COMPLEX = {base + suffix
           for base in ("cexp clog csqrt csin ccos ctan csinh ccosh ctanh catan casin cacos "
                        "casinh cacosh catanh conj cproj cabs carg creal cimag cpow").split()
           for suffix in ("", "f", "l")}


def modules(python_dir: Path) -> list[Path]:
    """Every .pyd and .dll under the Windows Python (Tcl/Tk's own left alone)."""
    return sorted(p for p in python_dir.rglob("*")
                  if p.suffix.lower() in (".pyd", ".dll")
                  and not re.search(r"tcl|tk86", p.name, re.I))


def pe_imports(data: bytes) -> dict[str, set[str]]:
    """The import table of a PE32+ file: ``{dll name (lower case): {function names}}``.

    Microsoft's PE format (learn.microsoft.com/windows/win32/debug/pe-format): the import
    directory is data directory 1 of the optional header; each 20-byte descriptor names a
    DLL (``Name``) and its lookup table (``OriginalFirstThunk``, else ``FirstThunk``) of
    8-byte entries, the high bit for an ordinal, else the RVA of a 2-byte hint + name.
    """
    u16 = lambda o: struct.unpack_from("<H", data, o)[0]  # noqa: E731
    u32 = lambda o: struct.unpack_from("<I", data, o)[0]  # noqa: E731
    pe = u32(0x3C)
    if data[pe:pe + 4] != b"PE\0\0" or u16(pe + 24) != 0x20B:
        return {}
    n_sections, opt_size = u16(pe + 6), u16(pe + 20)
    sections = [(u32(o + 12), max(u32(o + 8), u32(o + 16)), u32(o + 20))
                for o in range(pe + 24 + opt_size, pe + 24 + opt_size + 40 * n_sections, 40)]

    def offset(rva: int) -> int:
        for start, size, raw in sections:
            if start <= rva < start + size:
                return rva - start + raw
        raise ValueError(f"RVA {rva:#x} outside the sections")

    def cstr(o: int) -> str:
        return data[o:data.index(b"\0", o)].decode("ascii", "replace")

    out: dict[str, set[str]] = {}
    directory = u32(pe + 24 + 112 + 8)
    if not directory:
        return out
    d = offset(directory)
    while any(data[d:d + 20]):
        lookup = u32(d) or u32(d + 16)
        names = out.setdefault(cstr(offset(u32(d + 12))).lower(), set())
        t = offset(lookup)
        while (entry := struct.unpack_from("<Q", data, t)[0]):
            if not entry >> 63:
                names.add(cstr(offset(entry & 0x7FFFFFFF) + 2))
            t += 8
        d += 20
    return out


def math_imports(path: Path, dlls: tuple[str, ...] = (API_SET,)) -> set[str]:
    """The names ``path`` imports from ``dlls`` (default: the UCRT math API set)."""
    try:
        table = pe_imports(path.read_bytes())
    except (ValueError, struct.error):  # not a PE32+ image: nothing to patch
        return set()
    return set().union(*(names for dll, names in table.items() if dll in dlls))


def write_def(python_dir: Path, out: Path) -> None:
    names = set(COMPLEX)
    for path in modules(python_dir):
        names |= math_imports(path, (API_SET, SHIM))  # a module patched before too
    lines = [f"LIBRARY {SHIM}", "EXPORTS"]
    lines += [f"  {n} = w_{n}" if n in COMPLEX else f"  {n} = ucrtbase.{n}"
              for n in sorted(names)]
    out.write_text("\n".join(lines) + "\n")


def patch(python_dir: Path) -> int:
    count = 0
    for path in modules(python_dir):
        if not math_imports(path) & COMPLEX:
            continue
        data = path.read_bytes()
        new = re.sub(re.escape(API_SET).encode(), SHIM.encode(), data, flags=re.I)
        if new != data:
            path.write_bytes(new)
            count += 1
    return count


if __name__ == "__main__":
    command, python_dir = sys.argv[1], Path(sys.argv[2])
    if command == "def":
        write_def(python_dir, Path(sys.argv[3]))
    elif command == "patch":
        print(f"{patch(python_dir)} modules pointed at {SHIM}")
    else:
        sys.exit(f"unknown command {command!r}: def or patch")
