#!/usr/bin/env bash
# The l3 demo on bundled data. Called by `make demo` (which sets up the venv first).
#   scripts/demo.sh L3_EXECUTABLE OUT_DIR
set -euo pipefail
L3=${1:-l3}
OUT=${2:-demo_out}
mkdir -p "$OUT"
here=$(cd "$(dirname "$0")/.." && pwd)

echo "== 1. Read the bundled real raw crops"
"$L3" info "$here/tests/data/DSC_1339_768x512_rggb_14bit.raw" "$here/tests/data/halide_bayer_small.png"
"$L3" info "$here/tests/data/DSC_1339_768x512_rggb_14bit.raw" \
    --preview "$OUT/rose_preview.png" --planes "$OUT/rose_planes"
echo "   wrote $OUT/rose_preview.png and the CFA planes in $OUT/rose_planes/"
