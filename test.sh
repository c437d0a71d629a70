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
# Set-up steps run side by side (scripts/bootstrap.sh setup_for_tests).
HLOD_SETUP_TEST_TOOLS=1 source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh" "$@"
if [ $# -gt 0 ] || [ "${HLOD_TEST_PROCESSES:-2}" = 1 ]; then
    exec "$PY" -m pytest -q --durations=10 "$@"
fi
log="$(mktemp "${TMPDIR:-/tmp}/hlod-tests-blender.XXXXXX")"
# the extension zips, built once for both processes by the first to need them (tests/blender_runs.py built_zips)
HLOD_TEST_ZIPS="$(mktemp -d "${TMPDIR:-/tmp}/hlod-test-zips.XXXXXX")"
export HLOD_TEST_ZIPS
trap 'rm -rf "$log" "$HLOD_TEST_ZIPS"' EXIT
"$PY" -m pytest -q --durations=5 -m blender >"$log" 2>&1 &
blender_pid=$!
status=0
"$PY" -m pytest -q --durations=10 -m "not blender" || status=$?
wait "$blender_pid" || { blender_status=$?; [ "$blender_status" -gt "$status" ] && status=$blender_status; }
echo "=== the Blender checks (-m blender), run beside the rest ==="
cat "$log"
exit "$status"
