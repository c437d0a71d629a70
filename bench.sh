#!/usr/bin/env bash
# Benchmarks (not part of the tests): bake throughput with 1 and 2 jobs, file open time.
source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh"
exec "$PY" -m benchmarks.bake_throughput "$@"
