#!/usr/bin/env bash
# Runs the test suite (pytest). Extra arguments go to pytest, e.g. bash test.sh -k fileformat
source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh"
ensure_validators
exec "$PY" -m pytest -q --durations=10 "$@"
