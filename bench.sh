#!/usr/bin/env bash
# Benchmarks (not part of the tests), one after the other:
#   1. bake throughput with 1 and 2 jobs, file open time (benchmarks/bake_throughput.py), and the
#      Blender bake (child process) with jobs 2 against jobs 1 (benchmarks/bench_blender_bake_jobs.py),
#      and a mixed scene's moved re-bake against its full bake (benchmarks/bench_blender_mixed_rebake.py);
#   2. the .hlod reader fuzz with 5000 mutated files (benchmarks/fuzz_hlod.py; the test suite runs
#      800 of the same), summary in OUT/fuzz_hlod.json; exits 1 if any file crashed the reader.
# Usage: bash bench.sh [--repeat R] [--out DIR] [--fuzz N] [--fuzz-seed S]   (--fuzz 0 skips it)
source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh"
FUZZ_CASES=5000
FUZZ_SEED=1
OUT=out/bench
PASS=()
while [ $# -gt 0 ]; do
    case "$1" in
        --fuzz) FUZZ_CASES="$2"; shift 2 ;;
        --fuzz-seed) FUZZ_SEED="$2"; shift 2 ;;
        --out) OUT="$2"; PASS+=("$1" "$2"); shift 2 ;;
        *) PASS+=("$1"); shift ;;
    esac
done
"$PY" -m benchmarks.bake_throughput ${PASS[@]+"${PASS[@]}"}
"$PY" -m pytest -q -s -p no:cacheprovider benchmarks/bench_blender_bake_jobs.py  # the Blender bake, jobs 2 vs 1
"$PY" -m pytest -q -s -p no:cacheprovider benchmarks/bench_blender_mixed_rebake.py  # a mixed scene's moved re-bake
if [ "$FUZZ_CASES" -gt 0 ]; then
    "$PY" -m benchmarks.fuzz_hlod --cases "$FUZZ_CASES" --seed "$FUZZ_SEED" --keep "$OUT/fuzz_failures" \
        --out "$OUT/fuzz_hlod.json"
fi
