#!/usr/bin/env bash
# Main job: bake the embedded default scene and print its summary and checks.
# Usage: bash run.sh [OUTDIR]   (default: out/)
source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh"
OUT="${1:-out}"
mkdir -p "$OUT"
"$PY" -m hlod_core scene default -o "$OUT/default.hlod" --jobs 0 | tail -n 1
"$PY" -m hlod_core -q info "$OUT/default.hlod"
