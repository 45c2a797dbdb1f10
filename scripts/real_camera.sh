#!/usr/bin/env bash
# Approximating real pipelines (issue 7): regenerates the numbers of
# docs/results.md, section "Approximating a real pipeline".
#
#   scripts/real_camera.sh [L3_EXECUTABLE] [OUT_DIR] [SHARED_DATA_DIR]
#
# 1. Infinite-ISP: train on the three frames/ pairs, render the two holdout/
#    raws, evaluate against the ISP's PNGs (S-CIELAB at 96 dpi and 1 m, PSNR,
#    ColorChecker ΔE with the bundled chart corners), 4-pixel border excluded.
# 2. Blackmagic Pocket 4K DNG vs LibRaw's AHD rendering: train on the left
#    half, render and evaluate the right half.
# Extra `l3 train` options can be given in L3_TRAIN_OPTS (default: none, l3 train's defaults).
set -euo pipefail
L3=${1:-l3}
OUT=${2:-real_camera_out}
here=$(cd "$(dirname "$0")/.." && pwd)
DATA=${3:-$here/../shared/data}
PY=${PYTHON:-python3}
TRAIN_OPTS=${L3_TRAIN_OPTS:-}
IISP=$DATA/raw/infinite_isp
mkdir -p "$OUT"

echo "== Infinite-ISP: train on frames/ ($TRAIN_OPTS)"
# shellcheck disable=SC2086
"$L3" -v train "$IISP/frames" -o "$OUT/infinite_isp.npz" $TRAIN_OPTS --seed 1
echo "== Infinite-ISP: render and evaluate holdout/"
"$L3" render "$OUT/infinite_isp.npz" "$IISP"/holdout/*.raw -o "$OUT/infinite_isp_holdout" --format png
for raw in "$IISP"/holdout/*.raw; do
    stem=$(basename "$raw" .raw)
    chart=$("$PY" "$here/scripts/real_camera_data.py" chart "$stem")
    "$L3" evaluate "$OUT/infinite_isp_holdout/$stem.png" --reference "$IISP/holdout/$stem.png" \
        --dpi 96 --distance 1 --exclude-border 4 --chart "$chart" --json "$OUT/eval_$stem.json"
done

echo "== Blackmagic Pocket 4K vs LibRaw AHD: split, train on the left half"
"$PY" "$here/scripts/real_camera_data.py" blackmagic "$DATA/raw/misc/blackmagic_pocket4k_rggb.dng" "$OUT/bmpcc"
# shellcheck disable=SC2086
"$L3" -v train "$OUT/bmpcc/train" -o "$OUT/bmpcc.npz" $TRAIN_OPTS --seed 1
"$L3" render "$OUT/bmpcc.npz" "$OUT/bmpcc/test/bmpcc_right.raw" -o "$OUT/bmpcc_right.tif"
"$L3" evaluate "$OUT/bmpcc_right.tif" --reference "$OUT/bmpcc/ref/bmpcc_right.tif" \
    --dpi 96 --distance 1 --exclude-border 4 --json "$OUT/eval_bmpcc_right.json"

echo "== Summary (name | S-CIELAB mean ΔE*ab | PSNR dB | ColorChecker ΔE*ab)"
"$PY" "$here/scripts/real_camera_data.py" summary "$OUT"/eval_*.json
