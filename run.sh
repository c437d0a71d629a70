#!/usr/bin/env bash
# Main job: bake the embedded default scene, check it, evaluate every traversal method on a short
# seeded inspection path (report in OUTDIR/report/), and draw the preview with the modulation
# overlay through the Blender add-on's own draw path (OUTDIR/preview.png).
# Usage: bash run.sh [OUTDIR]   (default: out/)
source "$(dirname "${BASH_SOURCE[0]}")/scripts/bootstrap.sh"
OUT="${1:-out}"
mkdir -p "$OUT"
"$PY" -m hlod_core scene default -o "$OUT/default.hlod" --jobs 0 | tail -n 1
"$PY" -m hlod_core -q info "$OUT/default.hlod"
"$PY" scripts/blender_preview.py "$OUT/default.hlod" "$OUT/preview.png" 2> >(grep -v EGL_BAD_MATCH >&2) | tail -n 1
echo "hlod: evaluating 11 method variants on an 80-frame path (about a minute)..." >&2
"$PY" -m hlod_core -q evaluate "$OUT/default.hlod" --out "$OUT/report" --seed 1 --frames 80 --size 640x480 --repeat 2 \
    | tail -n 1 > "$OUT/summary.json"
echo "hlod: report: $OUT/report/report.md (figures beside it), preview picture: $OUT/preview.png" >&2
cat "$OUT/summary.json"
