#!/usr/bin/env bash
# Runs the test suite (pytest). Extra arguments go to pytest, e.g. bash test.sh -k fileformat
source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh"
ensure_validators
ensure_viewer  # CesiumJS (npm) and chromium: the viewer page and its browser test
ensure_blender_venvs  # .venv-blender/bpy-4.2, bpy-5.0, bpy-5.2: the extension checks run in each
exec "$PY" -m pytest -q --durations=10 "$@"
