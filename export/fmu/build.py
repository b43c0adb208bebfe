"""Write a twin as an FMI 2.0 FMU (model exchange + co-simulation): model description, C
sources, a binary for this platform compiled with the system's C compiler, zipped.

The FMU needs no Python at run time: the binary links only the C library and libm. Its
model is documented in ``docs/fmu.md`` and at the top of ``c/nmsid_model.c``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tempfile
import time
import uuid
import zipfile
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from xml.sax.saxutils import quoteattr

from nmsid.analysis.joint_twins import load_joint_twins
from nmsid.analysis.twin import Twin, file_sha256
from nmsid.export.errors import FmuExportError
from nmsid.export.fmu.description import c_header, model_description
from nmsid.export.fmu.variables import joint_variables, variables
from nmsid.protocols import os_platform
from nmsid.sim_backends.effects import effects_from_list
from nmsid.sim_backends.errors import SimConfigError

C_DIR = Path(__file__).resolve().parent / "c"
C_SOURCES = ("nmsid_model.c", "nmsid_twin.c")
C_HEADERS = ("nmsid_model.h", "fmi2Functions.h", "fmi2FunctionTypes.h",
             "fmi2TypesPlatform.h")
#: items of a version-1 twin file (docs/twin-file.md); any other item is a twin form the
#: FMU does not model (such as the muscle form), and the export refuses it
KNOWN_ITEMS = frozenset({"format", "format_version", "participant", "source", "calibration",
                         "sE_range", "parameters", "offset_N", "effects",
                         # a torque joint's twin: its units in N m (variables._in_joint_unit)
                         "joint", "measured_quantity", "measured_unit"})
#: the effects whose step c/nmsid_model.c implements (held to the Python reference step,
#: export/fmu/reference.py, by tests/export/test_fmu.py); any other effect is refused
SUPPORTED_EFFECTS = ("recruitment_nonlinearity", "activation_dynamics",
                     "flexor_extensor_asymmetry", "dead_time", "fatigue")
#: why an effect has no C step, where there is more to say than that it was not written
_REFUSED = {
    "baseline_drift": "the wander is a random signal seeded per simulated participant, not a "
                      "deterministic model",
}


@dataclass(frozen=True)
class FmuResult:
    """What :func:`export_fmu` wrote."""

    path: Path
    model_identifier: str
    guid: str
    platform: str | None
    seconds: float
    joints: tuple[str, ...] = ()
    """The joints of an FMU of several joints (a ``joints`` twin file); empty for one."""


def nmsid_version() -> str:
    """The installed nmsid's version ("unknown" when not installed)."""
    try:
        return metadata.version("nmsid")
    except metadata.PackageNotFoundError:
        return "unknown"


def unsupported_effects(effects) -> list[str]:
    """The names of the effects (parsed, or a twin file's entries) that the FMU's step (C
    and its Python reference) does not run; an additive term that is off (zero
    amplitude) changes nothing and is not listed.
    """
    out = []
    for e in effects:
        name = str(e.get("name")) if isinstance(e, dict) else e.name
        if name in SUPPORTED_EFFECTS:
            continue
        try:
            parsed = effects_from_list([e])[0]
        except SimConfigError:       # not even a valid entry: certainly not runnable
            out.append(name)
            continue
        if not (parsed.slots == {"additive"} and parsed.additive(0) is None):
            out.append(name)
    return out


def check_exportable(data: dict, where: str) -> Twin:
    """The twin of a twin file's JSON object, or :class:`FmuExportError` naming the form or
    effect the FMU does not model."""
    extra = sorted(set(data) - KNOWN_ITEMS) if isinstance(data, dict) else []
    if extra:
        raise FmuExportError(f"{where}: the twin has item(s) {extra} (a twin form the FMU "
                             f"does not model yet, such as the muscle form); the FMU exports "
                             f"the second-order twin: {sorted(KNOWN_ITEMS)}")
    twin = Twin.from_dict(data, where)
    try:
        effects = effects_from_list(twin.effects)
    except SimConfigError as exc:
        raise FmuExportError(f"{where}: {exc}") from None
    for name in unsupported_effects(effects):
        why = _REFUSED.get(name, "its step is not written in C in export/fmu/c/nmsid_model.c")
        raise FmuExportError(f"{where}: effect {name} is not in the FMU ({why}); "
                             f"the FMU models {', '.join(SUPPORTED_EFFECTS)}; remove "
                             f"{name} from the twin's effects to export the rest")
    return twin


#: the top-level items of a twin file of several joints (analysis/joint_twins.py)
JOINTS_FILE_ITEMS = frozenset({"format", "format_version", "participant", "joints"})


def exportable_twins(data: dict, where: str) -> list[Twin]:
    """The twins an FMU is built from: the one twin of a one-joint file, or each joint's
    of a ``joints`` file (``docs/twin-file.md``), each checked by
    :func:`check_exportable`; :class:`FmuExportError` names the joint and the item."""
    if not (isinstance(data, dict) and "joints" in data):
        return [check_exportable(data, where)]
    extra = sorted(set(data) - JOINTS_FILE_ITEMS)
    if extra:
        raise FmuExportError(f"{where}: the twin file has item(s) {extra} beside 'joints'; "
                             f"a file of several joints has {sorted(JOINTS_FILE_ITEMS)}")
    twins = []
    for name, body in data["joints"].items():
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,39}", name):
            raise FmuExportError(f"{where}: joint name {name!r} cannot name FMU variables "
                                 "(rE_<joint>, ...): use letters, digits and _, starting "
                                 "with a letter, at most 40 characters")
        head = {k: data[k] for k in ("format", "format_version", "participant") if k in data}
        twins.append(check_exportable({**body, **head, "joint": name},
                                      f"{where}: joints.{name}"))
    return twins


def _identifier(participant: str) -> str:
    tail = re.sub(r"[^A-Za-z0-9_]", "_", participant)[:40]
    return "nmsid_twin" + (f"_{tail}" if tail else "")


def _sources_and_effects(twin: Twin) -> str:
    srcs = []
    for s in twin.source:
        if isinstance(s, dict):
            sha = f' sha256="{s["sha256"]}"' if "sha256" in s else ""
            srcs.append(f'<Source file={quoteattr(s["file"])}{sha}/>')
        else:
            srcs.append(f"<Source label={quoteattr(str(s))}/>")
    effects = "".join(f"<Effect name={quoteattr(e['name'])} params="
                      f"{quoteattr(json.dumps(e.get('params', {}), sort_keys=True))}/>"
                      for e in twin.effects)
    return "".join(srcs) + effects


def _annotation(twins: list[Twin], twin_sha256: str, version: str, *, joints: bool) -> str:
    """The ``Tool name="nmsid"`` annotation: a one-joint twin's sources and effects inside
    ``Twin``; a file of several joints', each inside a ``Joint`` element."""
    if joints:
        inner = "".join(f'<Joint name={quoteattr(t.joint)} quantity='
                        f'{quoteattr(t.measured_quantity)} unit={quoteattr(t.measured_unit)}>'
                        f'{_sources_and_effects(t)}</Joint>' for t in twins)
    else:
        inner = _sources_and_effects(twins[0])
    return (f'<Twin participant={quoteattr(twins[0].participant)} nmsidVersion="{version}" '
            f'twinFileSha256="{twin_sha256}">{inner}</Twin>')


def _description(twins: list[Twin], *, joints: bool) -> str:
    """The model description's one-line summary."""
    who = twins[0].participant or "an unnamed participant"
    if not joints:
        twin = twins[0]
        names = ", ".join(e["name"] for e in twin.effects) or "none"
        what = "force" if twin.measured_unit == "N" else f"{twin.joint} torque (N m)"
        return (f"nmsid digital twin of {who}: {what} from rE and sE, second-order dynamics "
                f"with parameter curves of sE; effects: {names}")
    each = "; ".join(f"{t.joint}: {t.measured_quantity} ({t.measured_unit}), effects "
                     f"{', '.join(e['name'] for e in t.effects) or 'none'}" for t in twins)
    return (f"nmsid digital twin of {who}, {len(twins)} joints: each joint's force or torque "
            f"from its own rE and sE (rE_<joint>, sE_<joint>), second-order dynamics with "
            f"parameter curves of sE; {each}")


@dataclass(frozen=True)
class Compiler:
    """A C compiler found for the FMU's binary.

    Attributes
    ----------
    kind : {"msvc", "gcc"}
        ``msvc``: Microsoft's ``cl``; ``gcc``: gcc, clang, cc or MinGW-w64's gcc (GCC's
        command line).
    path : str
        The executable.
    platform : str or None
        The FMI 2.0 binaries folder of the compiler's TARGET (``win64``, ``linux64``,
        ``darwin64``, ...), None when FMI 2.0 names none (e.g. ARM Linux).
    """

    kind: str
    path: str
    platform: str | None


#: Tried in this order when neither ``cc`` nor $CC names one: Windows has no ``cc``; MSVC's
#: ``cl`` is on PATH in a "Developer Command Prompt", MinGW-w64's ``gcc`` where installed.
CANDIDATES = {"windows": ("cl", "gcc", "clang"), "posix": ("cc", "gcc", "clang")}


def platform_of_target(target: str) -> str | None:
    """The FMI 2.0 folder for a compiler target: a GCC triple (``gcc -dumpmachine``:
    ``x86_64-w64-mingw32``, ``x86_64-linux-gnu``, ``arm64-apple-darwin23``) or MSVC's
    banner architecture (``x64``, ``x86``, ``ARM64``).

    Examples
    --------
    >>> platform_of_target("x86_64-w64-mingw32"), platform_of_target("x64")
    ('win64', 'win64')
    >>> platform_of_target("i686-linux-gnu"), platform_of_target("aarch64-linux-gnu")
    ('linux32', None)
    """
    t = target.strip().lower()
    if t in ("x64", "amd64"):
        return "win64"
    if t in ("x86", "80x86"):
        return "win32"
    if "darwin" in t or "apple" in t:
        return "darwin64"
    arch = t.split("-")[0]
    bits = "64" if arch in ("x86_64", "amd64") else "32" if re.fullmatch(r"i[3-6]86", arch) \
        else None
    if bits is None:
        return None
    if any(w in t for w in ("mingw", "windows", "cygwin", "msvc", "win32")):
        return "win" + bits
    if "linux" in t:
        return "linux" + bits
    return None


def _target(kind: str, path: str) -> str:
    """What the compiler builds for: ``-dumpmachine``, or ``for x64`` in cl's banner."""
    if kind == "msvc":
        run = subprocess.run([path], capture_output=True, text=True, check=False)
        m = re.search(r"\bfor\s+(\w+)", run.stderr + run.stdout)
        return m.group(1) if m else ""
    run = subprocess.run([path, "-dumpmachine"], capture_output=True, text=True, check=False)
    return run.stdout.strip()


def find_compiler(cc: str | None = None) -> Compiler:
    """The C compiler to build the binary with: ``cc``, else $CC, else the first of
    :data:`CANDIDATES` on PATH for this system (through the platform switch).

    Raises
    ------
    FmuExportError
        One line: none found (what was tried, what to install, ``--sources-only``).
    """
    wanted = cc or os.environ.get("CC")
    names = (wanted,) if wanted else CANDIDATES[os_platform.platform_name()]
    for name in names:
        path = shutil.which(name)
        if path is None:
            continue
        kind = "msvc" if Path(path).stem.lower() == "cl" else "gcc"
        return Compiler(kind, path, platform_of_target(_target(kind, path)))
    if os_platform.is_windows():
        how = ("install Visual Studio Build Tools (C++) and run nmsid from the 'x64 Native "
               "Tools Command Prompt', or MinGW-w64's gcc, or set CC")
    else:
        how = "install cc/gcc/clang, or set CC"
    raise FmuExportError(f"no C compiler found on PATH (tried {', '.join(names)}) to build "
                         f"the FMU's binary: {how}; or give --sources-only")


def compile_command(compiler: Compiler, sources_dir: Path, out_file: Path) -> list[str]:
    """The command that builds the shared library ``out_file`` from the sources."""
    sources = [str(sources_dir / s) for s in C_SOURCES]
    if compiler.kind == "msvc":
        # /LD: a DLL; objects go to the working directory (a temporary one)
        return [compiler.path, "/nologo", "/LD", "/O2", "/I", str(sources_dir), *sources,
                f"/Fe:{out_file}"]
    windows_target = (compiler.platform or "").startswith("win")
    pic = [] if windows_target else ["-fPIC"]  # every Windows DLL is position independent
    return [compiler.path, "-shared", *pic, "-O2", "-std=c99", "-fvisibility=hidden",
            "-I", str(sources_dir), *sources, "-o", str(out_file), "-lm"]


def compile_binary(sources_dir: Path, out_file: Path, cc: str | None = None,
                   compiler: Compiler | None = None) -> None:
    """Compile the FMU's sources into a shared library with the system's C compiler.

    Raises
    ------
    FmuExportError
        No C compiler, or compilation failed (its message quoted).
    """
    compiler = compiler or find_compiler(cc)
    out_file.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="nmsid-cc-") as work:
        run = subprocess.run(compile_command(compiler, sources_dir, out_file),
                             capture_output=True, text=True, cwd=work, check=False)
    if run.returncode != 0:
        raise FmuExportError(f"{Path(compiler.path).name} failed to build the FMU binary: "
                             f"{(run.stderr or run.stdout).strip().splitlines()[:3]}")


def export_fmu(twin_path: str | os.PathLike, out: str | os.PathLike, *, force: bool = False,
               extrapolate: bool = False, binary: bool = True) -> FmuResult:
    """Write ``twin_path`` as an FMI 2.0 FMU at ``out``.

    Parameters
    ----------
    twin_path : path
        A twin file (``docs/twin-file.md``): one twin (the FMU's variables ``rE``, ``sE``,
        ``force_N``, ...), or several joints' (``joints``): one FMU with each joint's
        variables named ``rE_<joint>``, ``sE_<joint>``, ``force_N_<joint>`` or
        ``torque_Nm_<joint>``, ... (:func:`nmsid.export.fmu.variables.joint_variable_name`).
    out : path
        The ``.fmu`` to write; an existing file is refused unless ``force``.
    force : bool
        Replace an existing ``out``.
    extrapolate : bool
        Start value of the FMU's ``extrapolate`` parameter (default clamp sE to the tested
        range, as ``nmsid twin simulate`` does).
    binary : bool
        Compile a binary for this platform (False: sources only).

    Returns
    -------
    FmuResult

    Raises
    ------
    FmuExportError
        Existing ``out`` without ``force``, a form or effect the FMU does not model, no C
        compiler.
    """
    t0 = time.perf_counter()
    src, out = Path(twin_path), Path(out)
    if out.exists() and not force:
        raise FmuExportError(f"{out}: already exists; choose another --out or add --force")
    if out.suffix.lower() != ".fmu":
        raise FmuExportError(f"{out}: an FMU's file name ends in .fmu")
    load_joint_twins(src)       # errors name the file and item (a joint's: joints.knee...)
    data = json.loads(src.read_text(encoding="utf-8"))
    joints = isinstance(data, dict) and "joints" in data
    twins = exportable_twins(data, str(src))
    twin_sha = file_sha256(src)
    version = nmsid_version()
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"nmsid-twin:{twin_sha}:{version}:"
                                                   f"{extrapolate}")) + "}"
    ident = _identifier(twins[0].participant)
    # a one-joint file: the names of every earlier FMU (rE, sE, force_N, ...); a file of
    # several joints: each joint's with _<joint> after it (variables.joint_variable_name)
    vs = (joint_variables(twins, extrapolate=extrapolate) if joints
          else variables(twins[0], extrapolate=extrapolate))
    desc = _description(twins, joints=joints)
    compiler = find_compiler() if binary else None
    plat = compiler.platform if compiler is not None else None
    with tempfile.TemporaryDirectory(prefix="nmsid-fmu-") as tmp:
        root = Path(tmp)
        (root / "sources").mkdir()
        for f in C_SOURCES + C_HEADERS:
            shutil.copyfile(C_DIR / f, root / "sources" / f)
        (root / "sources" / "twin_data.h").write_text(
            c_header(vs, guid, [t.joint for t in twins]), encoding="utf-8")
        (root / "modelDescription.xml").write_text(model_description(
            vs, model_name=f"nmsid_twin {twins[0].participant}".strip(), model_identifier=ident,
            guid=guid, description=desc, version=f"twin sha256 {twin_sha[:12]}",
            generation_tool=f"nmsid {version}",
            annotation_xml=_annotation(twins, twin_sha, version, joints=joints),
            source_files=list(C_SOURCES)), encoding="utf-8")
        (root / "resources").mkdir()
        shutil.copyfile(src, root / "resources" / "twin.json")
        (root / "documentation").mkdir()
        (root / "documentation" / "index.html").write_text(_doc_html(ident), encoding="utf-8")
        if plat:
            ext = {"linux": ".so", "darwin": ".dylib", "win": ".dll"}[plat.rstrip("0123456789")]
            compile_binary(root / "sources", root / "binaries" / plat / (ident + ext),
                           compiler=compiler)
        fd, tmp_name = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".part")
        os.close(fd)
        tmp_out = Path(tmp_name)
        with zipfile.ZipFile(tmp_out, "w", zipfile.ZIP_DEFLATED) as z:
            for p in sorted(root.rglob("*")):
                if p.is_file():
                    z.write(p, p.relative_to(root).as_posix())
        # mkstemp creates the file 0600; the FMU gets a new file's usual mode (0666 less
        # the umask: 0644 typically), like every other output (issue 39)
        os.chmod(tmp_out, 0o666 & ~_umask())
        os.replace(tmp_out, out)
    return FmuResult(out, ident, guid, plat, time.perf_counter() - t0,
                     tuple(t.joint for t in twins) if joints else ())


def _umask() -> int:
    """The process's umask (read by setting it and putting it back at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _doc_html(ident: str) -> str:
    return f"""<html><body><h1>{ident}</h1>
<p>An nmsid digital twin (force from the EAA ratio rE and sum sE). The model and its
variables are in modelDescription.xml; the twin file it came from is resources/twin.json.</p>
<p>Build the binary for another platform from sources/ (C99, needs only libm), e.g.
<code>cc -shared -fPIC -O2 -std=c99 -fvisibility=hidden -Isources sources/nmsid_model.c
sources/nmsid_twin.c -o binaries/linux64/{ident}.so -lm</code>; on macOS
<code>binaries/darwin64/{ident}.dylib</code>;
on Windows <code>cl /LD /O2 /Isources sources\\nmsid_model.c sources\\nmsid_twin.c
/Fe:binaries\\win64\\{ident}.dll</code>.
Or let the importer build it (FMPy: <code>fmpy.build.build_platform_binary</code>, needs CMake).</p>
<p>Co-simulation is exact for inputs that move in straight lines over each step: set their
first derivatives (fmi2SetRealInputDerivatives), otherwise they are held over the step.</p>
</body></html>
"""

