#!/usr/bin/env bash
# Approximating real pipelines (issues 7 and 15): the tutorial of
# docs/real-camera.md; with the full shared data it regenerates the numbers of
# docs/results.md, section "Approximating a real pipeline".
#
#   scripts/real_camera.sh [L3_EXECUTABLE] [OUT_DIR] [SHARED_DATA_DIR]
#
# Without SHARED_DATA_DIR (a fresh clone) it uses the compact set bundled in
# the repository, examples/infinite_isp/ (1024x768 crops around each chart,
# made by scripts/make_examples.py). With SHARED_DATA_DIR it uses the full
# frames of SHARED_DATA_DIR/raw/infinite_isp and adds the Blackmagic example.
#
# 1. Infinite-ISP: train on the three frames/ pairs, render the two holdout/
#    raws, evaluate against the ISP's PNGs (S-CIELAB at 96 dpi and 1 m, PSNR,
#    ColorChecker ΔE with the chart corners), 4-pixel border excluded.
# 2. (full data only) Blackmagic Pocket 4K DNG vs LibRaw's AHD rendering:
#    train on the left half, render and evaluate the right half; and five
#    crops of it as DNGs whose white balance differs per shot (train on 3,
#    evaluate 2; the as-shot white balance is an input, issue 15).
# Extra `l3 train` options can be given in L3_TRAIN_OPTS (default: none, l3 train's defaults).
set -euo pipefail
L3=${1:-l3}
OUT=${2:-real_camera_out}
here=$(cd "$(dirname "$0")/.." && pwd)
DATA=${3:-}
PY=${PYTHON:-python3}
TRAIN_OPTS=${L3_TRAIN_OPTS:-}
if [ -n "$DATA" ]; then
    IISP=$DATA/raw/infinite_isp
    RAW_EXT=raw
    CHARTS=$here/l3cli/data/charts/infinite_isp_charts.json
    echo "== full frames from $IISP"
else
    IISP=$here/examples/infinite_isp
    RAW_EXT=tif
    CHARTS=$IISP/charts.json
    echo "== compact set $IISP (pass SHARED_DATA_DIR for the full frames)"
fi
mkdir -p "$OUT"
rm -f "$OUT"/eval_*.json

echo "== Infinite-ISP: train on frames/ ($TRAIN_OPTS)"
# shellcheck disable=SC2086
"$L3" -v train "$IISP/frames" -o "$OUT/infinite_isp.npz" $TRAIN_OPTS --seed 1
echo "== Infinite-ISP: render and evaluate holdout/"
"$L3" render "$OUT/infinite_isp.npz" "$IISP"/holdout/*."$RAW_EXT" -o "$OUT/infinite_isp_holdout" --format png
for raw in "$IISP"/holdout/*."$RAW_EXT"; do
    stem=$(basename "$raw" ."$RAW_EXT")
    chart=$("$PY" "$here/scripts/real_camera_data.py" chart "$stem" "$CHARTS")
    "$L3" evaluate "$OUT/infinite_isp_holdout/$stem.png" --reference "$IISP/holdout/$stem.png" \
        --dpi 96 --distance 1 --exclude-border 4 --chart "$chart" --json "$OUT/eval_$stem.json"
done

if [ -n "$DATA" ]; then
    echo "== Blackmagic Pocket 4K vs LibRaw AHD: split, train on the left half"
    "$PY" "$here/scripts/real_camera_data.py" blackmagic "$DATA/raw/misc/blackmagic_pocket4k_rggb.dng" "$OUT/bmpcc"
    # shellcheck disable=SC2086
    "$L3" -v train "$OUT/bmpcc/train" -o "$OUT/bmpcc.npz" $TRAIN_OPTS --seed 1
    "$L3" render "$OUT/bmpcc.npz" "$OUT/bmpcc/test/bmpcc_right.raw" -o "$OUT/bmpcc_right.tif"
    "$L3" evaluate "$OUT/bmpcc_right.tif" --reference "$OUT/bmpcc/ref/bmpcc_right.tif" \
        --dpi 96 --distance 1 --exclude-border 4 --json "$OUT/eval_bmpcc_right.json"

    echo "== Blackmagic, white balance per shot: train on 3 DNG crops, evaluate 2 (issue 15)"
    "$PY" "$here/scripts/real_camera_data.py" bmpcc-wb "$DATA/raw/misc/blackmagic_pocket4k_rggb.dng" "$OUT/bmpcc_wb"
    # shellcheck disable=SC2086
    "$L3" -v train "$OUT/bmpcc_wb/train" -o "$OUT/bmpcc_wb.npz" $TRAIN_OPTS --seed 1
    "$L3" render "$OUT/bmpcc_wb.npz" "$OUT"/bmpcc_wb/test/*.dng -o "$OUT/bmpcc_wb_test" --format tiff
    for stem in shot3 shot4; do
        "$L3" evaluate "$OUT/bmpcc_wb_test/$stem.tif" --reference "$OUT/bmpcc_wb/test/$stem.tif" \
            --dpi 96 --distance 1 --exclude-border 4 --json "$OUT/eval_bmpcc_wb_$stem.json"
    done
fi

echo "== Summary (name | S-CIELAB mean ΔE*ab | PSNR dB | ColorChecker ΔE*ab)"
"$PY" "$here/scripts/real_camera_data.py" summary "$OUT"/eval_*.json
