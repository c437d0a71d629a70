# Sourced by run.sh and test.sh: make sure the Mesa EGL system packages and .venv/ exist (test.sh:
# with HLOD_SETUP_TEST_TOOLS=1 and its arguments, all the tests need, setup_for_tests).
# Creates or reuses .venv/ at the repository root; installs only what is missing.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
GL_PACKAGES="libegl1 libegl-mesa0 libgl1-mesa-dri"

say() { echo "hlod setup: $*" >&2; }

ensure_gl_packages() {
    if command -v dpkg-query >/dev/null 2>&1; then
        local missing=""
        for pkg in $GL_PACKAGES; do
            dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing="$missing $pkg"
        done
        [ -z "$missing" ] && return 0
        if [ "$(id -u)" = 0 ]; then
            say "installing system packages:$missing"
            DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2
            DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >&2
        else
            say "missing system packages:$missing"
            say "run as root:  apt-get install -y$missing   (Mesa's EGL/OpenGL, for headless rendering)"
            exit 1
        fi
    elif ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1'; then
        say "libEGL.so.1 not found: install your distribution's Mesa EGL and DRI packages"
        exit 1
    fi
}

# find_python X.Y: prints an interpreter of Python X.Y, or returns 1. Looks at $HLOD_PYTHON (3.11) or
# $HLOD_PYTHON313 (3.13), pythonX.Y, python3, then pyenv's installed versions (a pyenv shim answers
# only for the versions pyenv has selected, so the versions folder is searched too).
find_python() {
    local want="$1" candidate
    local override="HLOD_PYTHON"
    [ "$want" = 3.11 ] || override="HLOD_PYTHON${want/./}"
    local pyenv_versions=()
    if command -v pyenv >/dev/null 2>&1; then
        pyenv_versions=("$(pyenv root)"/versions/"$want".*/bin/python"$want")
    fi
    for candidate in "${!override:-}" "python$want" python3 "${pyenv_versions[@]}"; do
        [ -n "$candidate" ] || continue
        if command -v "$candidate" >/dev/null 2>&1 &&
           "$candidate" -c "import sys; sys.exit(sys.version_info[:2] != tuple(map(int, '$want'.split('.'))))" 2>/dev/null; then
            echo "$candidate"; return 0
        fi
    done
    return 1
}

# The installer of the Python environments: uv (Astral's, from PyPI, pinned here) in .venv. It installs
# a requirements file in a few seconds of CPU where pip takes about 15 s for each bpy, and links
# packages from its cache on later set-ups. Set-up tooling only: nothing of the product imports it.
UV_VERSION=0.13.9

ensure_venv_created() {
    # .venv with pip (scripts/build_extension.py downloads wheels with it) and uv
    if [ ! -x "$VENV/bin/python" ]; then
        local python
        python="$(find_python 3.11)" || {
            say "Python 3.11 is required (bpy 5.0.1 is published for 3.11 only); set HLOD_PYTHON to its path"
            exit 1
        }
        say "creating $VENV"
        "$python" -m venv "$VENV"
    fi
    if [ "$("$VENV/bin/uv" --version 2>/dev/null)" != "uv $UV_VERSION" ]; then
        "$VENV/bin/python" -m pip install --disable-pip-version-check -q "uv==$UV_VERSION" >&2 ||
            say "uv $UV_VERSION could not be installed: pip installs the environments instead"
    fi
}

install_requirements() {
    # install_requirements PYTHON REQUIREMENTS_FILE: with uv where .venv has it (pip's settings for a
    # wheel folder and a certificate passed on), else, or if uv fails, with pip
    local python="$1" req="$2" links=()
    if [ -x "$VENV/bin/uv" ]; then
        [ -n "${PIP_FIND_LINKS:-}" ] && links=(--find-links "$PIP_FIND_LINKS")
        if ( [ -n "${PIP_CERT:-}" ] && export SSL_CERT_FILE="$PIP_CERT"
             "$VENV/bin/uv" pip install -q --python "$python" "${links[@]}" -r "$req" >&2 ); then
            return 0
        fi
        say "uv could not install $req: trying pip"
    fi
    "$python" -m pip --version >/dev/null 2>&1 || "$python" -m ensurepip >&2  # made without pip (uv's)
    "$python" -m pip install --disable-pip-version-check -q -r "$req" >&2
}

ensure_venv() {
    ensure_venv_created
    local stamp="$VENV/.requirements.sha256"
    local want
    want="$(sha256sum "$ROOT/requirements.txt" | cut -d' ' -f1)"
    if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
        say "installing Python packages into $VENV (first run downloads about 400 MB)"
        install_requirements "$VENV/bin/python" "$ROOT/requirements.txt"
        echo "$want" > "$stamp"
    fi
}

ensure_blender_venvs() {
    # The extension checks run the built zip in each Blender we support, one environment each:
    # .venv-blender/bpy-X.Y from requirements-bpyXY.txt (its "# python-version:" line names the
    # Python of that Blender). They hold bpy and numpy only, as a Blender install does; the
    # extension's own dependencies come from its wheels. Each is created once and reused; the
    # missing ones install side by side (pip's downloads and unpacking overlap).
    local req pids=() pid
    for req in "$ROOT"/requirements-bpy*.txt; do
        ensure_blender_venv "$req" &
        pids+=("$!")
    done
    for pid in "${pids[@]}"; do
        wait "$pid"
    done
}

ensure_blender_venv() {
    # One .venv-blender/bpy-X.Y from requirements-bpyXY.txt ($1)
    local req="$1" version python interp dir stamp want
    version="$(sed -n 's/^bpy==\([0-9]*\.[0-9]*\).*/\1/p' "$req")"
    python="$(sed -n 's/^# python-version: *//p' "$req")"
    dir="$ROOT/.venv-blender/bpy-$version"
    if [ ! -x "$dir/bin/python" ]; then
        interp="$(find_python "$python")" || {
            say "Python $python not found (Blender $version runs it): install it (pyenv install $python, or your distribution's python$python package) or set HLOD_PYTHON${python/./} to its path"
            exit 1
        }
        say "creating $dir (Blender $version, Python $python)"
        # without pip where uv installs (pip's own install is 3 s of CPU each); install_requirements adds it
        # if uv fails
        if [ -x "$VENV/bin/uv" ]; then "$interp" -m venv --without-pip "$dir"; else "$interp" -m venv "$dir"; fi
    fi
    stamp="$dir/.requirements.sha256"
    want="$(sha256sum "$req" | cut -d' ' -f1)"
    if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
        say "installing bpy $version into $dir (first run downloads about 400 MB)"
        install_requirements "$dir/bin/python" "$req"
        echo "$want" > "$stamp"
    fi
}

blender_checks_may_run() {
    # The test arguments "$@" may select Blender checks (marker `blender`) unless the marker
    # expression leaves them out: the last -m EXPR (or -mEXPR, -m=EXPR; pytest takes the last one)
    # whose terms joined by `and` include `not blender`, with no `or` (test.sh's header). Returns 1
    # when they cannot run.
    local args=("$@") i k expr="" words
    for ((i = 0; i < ${#args[@]}; i++)); do
        case "${args[i]}" in
            -m) expr="${args[i + 1]:-}" ;;
            -m*) expr="${args[i]#-m}"; expr="${expr#=}" ;;
        esac
    done
    read -r -a words <<< "$expr"
    [[ " ${words[*]} " == *" or "* ]] && return 0
    for ((k = 0; k + 1 < ${#words[@]}; k++)); do
        if [ "${words[k]}" = not ] && [ "${words[k + 1]}" = blender ] &&
           { [ "$k" = 0 ] || [ "${words[k - 1]}" = and ]; } &&
           { [ $((k + 2)) = ${#words[@]} ] || [ "${words[k + 2]}" = and ]; }; then
            return 1
        fi
    done
    return 0
}

ensure_npm() {
    # $1: what needs it (for the messages)
    command -v npm >/dev/null 2>&1 && return 0
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        say "installing nodejs and npm (for $1)"
        DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nodejs npm >&2
    else
        say "npm not found: install Node.js 18+ and npm (for $1)"
        exit 1
    fi
}

npm_ci() {
    # npm ci in folder $1 when its package-lock.json changed since the last install; $2 says what.
    # Without the packages' install scripts: the only ones (tools/validators) compile better-sqlite3 from
    # source (about 1.5 min of CPU; its prebuilt binaries are on GitHub, not on the registry), which
    # 3d-tiles-tools loads only to read .3dtiles packages, and check sharp's prebuilt binary, which npm
    # installs as a package of its own. check_tileset.mjs uses neither.
    local folder="$1" stamp="$1/node_modules/.lock.sha256" want
    want="$(sha256sum "$folder/package-lock.json" | cut -d' ' -f1)"
    if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
        say "installing $2 into $folder/node_modules"
        (cd "$folder" && npm ci --silent --no-audit --no-fund --ignore-scripts >&2)
        echo "$want" > "$stamp"
    fi
}

ensure_validators() {
    # The tests' independent readers of the 3D Tiles export (npm: Khronos glTF validator, CesiumGS
    # 3d-tiles-tools, loaders.gl's Tiles3DLoader with the draco3d decoder), pinned in
    # tools/validators/package-lock.json; installed once.
    ensure_npm "the export validators"
    npm_ci "$ROOT/tools/validators" "the export validators (npm ci, about 290 MB)"
}

ensure_viewer() {
    # The 3D Tiles viewer (python -m hlod_core view): CesiumJS from npm, pinned in
    # tools/viewer/package-lock.json, served from there (never a CDN); and, for its browser test,
    # Debian's chromium (Playwright drives it; Playwright's own browser download is not used).
    ensure_npm "the 3D Tiles viewer's CesiumJS"
    npm_ci "$ROOT/tools/viewer" "CesiumJS for the 3D Tiles viewer (npm ci, about 130 MB)"
    if ! command -v chromium >/dev/null 2>&1; then
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
            say "installing chromium (the viewer page's browser test)"
            DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2
            DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >&2
        else
            say "chromium not found: run as root:  apt-get install -y chromium   (the viewer page's browser test)"
            exit 1
        fi
    fi
}

ensure_x_server() {
    # The GLX branch of the standalone GL context (hlod_core/render/gl_platform.py: EGL first, then
    # GLX) is tested on a virtual X server: Debian's xvfb, and Mesa's GLX (libglx-mesa0).
    local missing=""
    command -v Xvfb >/dev/null 2>&1 || missing="xvfb"
    if command -v dpkg-query >/dev/null 2>&1; then
        dpkg-query -W -f='${Status}' libglx-mesa0 2>/dev/null | grep -q "install ok installed" || missing="$missing libglx-mesa0"
    fi
    [ -z "$missing" ] && return 0
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        say "installing$missing (a virtual X server for the GLX test)"
        DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >&2
    else
        say "missing:$missing; run as root:  apt-get install -y$missing   (a virtual X server for the GLX test)"
        exit 1
    fi
}

ensure_test_tools() {
    # What the tests need besides .venv (test.sh): the validators, CesiumJS, chromium and a virtual X server
    # (system packages with apt in this one job, never beside another apt run; the two npm installs
    # side by side).
    ensure_npm "the export validators and CesiumJS"
    ensure_validators &
    local validators=$!
    ensure_viewer  # CesiumJS (npm) and chromium: the viewer page and its browser test
    wait "$validators"
    ensure_x_server  # Xvfb and Mesa's GLX: the GLX branch of the GL context is tested on it
}

ensure_test_system_packages() {
    # test.sh, as root with apt: every Debian package the tests need that is missing, in one apt run
    # ($1 = blender: with lavapipe for the Blender checks); the ensure_* functions then find them.
    [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && command -v dpkg-query >/dev/null 2>&1 || return 0
    local want="$GL_PACKAGES libglx-mesa0" missing="" pkg
    command -v npm >/dev/null 2>&1 || want="$want nodejs npm"
    command -v chromium >/dev/null 2>&1 || want="$want chromium"
    command -v Xvfb >/dev/null 2>&1 || want="$want xvfb"
    [ "${1:-}" = blender ] && want="$want mesa-vulkan-drivers"
    for pkg in $want; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing="$missing $pkg"
    done
    [ -z "$missing" ] && return 0
    say "installing system packages:$missing"
    DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >&2
}

setup_for_tests() {
    # test.sh's set-up for its arguments "$@": the system packages first (one apt run), then side by
    # side the npm installs, .venv, the Blender environments and the extension's wheels (downloads
    # and unpacking overlap); a failure of any stops the set-up.
    local blender=no pids=() pid
    blender_checks_may_run "$@" && blender=blender
    ensure_test_system_packages "$blender"
    ensure_gl_packages
    [ "$blender" = blender ] && ensure_vulkan  # lavapipe: the Blender checks also run under Vulkan
    ensure_venv_created  # uv first: it installs every environment below
    ensure_test_tools &  # the last that may run apt (where the one run above could not)
    pids+=("$!")
    if [ "$blender" = blender ]; then
        ensure_blender_venvs &  # .venv-blender/bpy-4.2, bpy-5.0, bpy-5.2: the extension checks run in each
        pids+=("$!")
    else
        say "a marker expression leaves out the Blender checks: the Blender environments are not set up"
    fi
    ensure_venv
    if [ "$blender" = blender ]; then
        # the wheels the extension zips carry (tests/blender_runs.py builds the zips)
        nice -n 5 "$VENV/bin/python" "$ROOT/scripts/build_extension.py" --download-only >&2 &
        pids+=("$!")
    fi
    for pid in "${pids[@]}"; do
        wait "$pid"
    done
}

ensure_vulkan() {
    # The Blender checks also run under Blender's Vulkan backend (tests/blender_runs.py VULKAN_BLENDERS):
    # Mesa's lavapipe, a Vulkan on the CPU (Debian's mesa-vulkan-drivers).
    if command -v dpkg-query >/dev/null 2>&1; then
        dpkg-query -W -f='${Status}' mesa-vulkan-drivers 2>/dev/null | grep -q "install ok installed" && return 0
    elif [ -f /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ]; then
        return 0
    fi
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        say "installing mesa-vulkan-drivers (lavapipe: the Blender checks under Vulkan)"
        DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers >&2
    else
        say "missing: mesa-vulkan-drivers; run as root:  apt-get install -y mesa-vulkan-drivers   (lavapipe, a CPU Vulkan for the Blender checks under Vulkan)"
        exit 1
    fi
}

if [ "${HLOD_SETUP_TEST_TOOLS:-}" = 1 ]; then
    setup_for_tests "$@"  # test.sh sources this with its arguments
else
    ensure_gl_packages
    ensure_venv
fi
PY="$VENV/bin/python"
export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"
cd "$ROOT"
