#!/usr/bin/env bash
# Runs the test suite (pytest). Extra arguments go to pytest, e.g. bash test.sh -k fileformat
# Without arguments the suite runs as two pytest processes side by side, one per core: the Blender
# checks (-m blender: each runs the bpy module in its own process) and everything else; the rest
# reports as it runs, the Blender checks' report follows, and the exit status is the worse of the two.
# With arguments (a marker expression, a file, -k ...) it is one pytest process, as given.
# HLOD_TEST_PROCESSES=1 runs the whole suite in one process.
# Set-up: .venv, the export's validators, CesiumJS, chromium and Xvfb always; the Blender environments
# (.venv-blender/bpy-4.2, bpy-5.0, bpy-5.2, about 1.2 GB, Python 3.13 for 5.2) and Mesa's Vulkan
# (lavapipe, for the checks under Blender's Vulkan backend) only when Blender
# checks may run: not when a marker expression leaves them out, i.e. -m EXPR where EXPR is
# `not blender` or has `not blender` as one of its terms joined by `and`, without `or`
# (bash test.sh -m "not slow and not blender", bash test.sh -m "gl and not blender").
HLOD_SETUP_TEST_TOOLS=1 source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh"  # .venv and ensure_test_tools
if blender_checks_may_run "$@"; then
    ensure_blender_venvs  # .venv-blender/bpy-4.2, bpy-5.0, bpy-5.2: the extension checks run in each
    ensure_vulkan  # lavapipe: the Blender checks also run under Blender's Vulkan backend
else
    say "a marker expression leaves out the Blender checks: the Blender environments are not set up"
fi
if [ $# -gt 0 ] || [ "${HLOD_TEST_PROCESSES:-2}" = 1 ]; then
    exec "$PY" -m pytest -q --durations=10 "$@"
fi
log="$(mktemp "${TMPDIR:-/tmp}/hlod-tests-blender.XXXXXX")"
trap 'rm -f "$log"' EXIT
"$PY" -m pytest -q --durations=5 -m blender >"$log" 2>&1 &
blender_pid=$!
status=0
"$PY" -m pytest -q --durations=10 -m "not blender" || status=$?
wait "$blender_pid" || { blender_status=$?; [ "$blender_status" -gt "$status" ] && status=$blender_status; }
echo "=== the Blender checks (-m blender), run beside the rest ==="
cat "$log"
exit "$status"
