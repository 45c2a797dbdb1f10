#!/usr/bin/env bash
# The l3 demo on bundled data. Called by `make demo` (which sets up the venv first).
#   scripts/demo.sh L3_EXECUTABLE OUT_DIR
# Simulates a Bayer camera, learns its L3 table, smooths it, renders held-out
# captures and scores them; every file it makes lands in OUT_DIR.
set -euo pipefail
L3=${1:-l3}
OUT=${2:-demo_out}
here=$(cd "$(dirname "$0")/.." && pwd)
CAM="$here/sample_configs/bayer.toml"
mkdir -p "$OUT"
rm -rf "$OUT/train_sim" "$OUT/test_sim" "$OUT/renders"

echo "== 1. Read a bundled real raw crop (14-bit RGGB, headerless + sidecar)"
"$L3" info "$here/tests/data/DSC_1339_768x512_rggb_14bit.raw" \
    --preview "$OUT/rose_preview.png" --planes "$OUT/rose_planes"

echo "== 2. Simulate training captures: Macbeth chart + natural scenes at 4 light levels"
"$L3" simulate "$CAM" -o "$OUT/train_sim" --scene macbeth --scene natural \
    --lux 15 --lux 60 --lux 250 --lux 1000 --size 320x240 --seed 1

echo "== 3. Simulate held-out test captures at a light level not used in training"
"$L3" simulate "$CAM" -o "$OUT/test_sim" --scene macbeth --scene slanted-edge \
    --lux 120 --size 320x240 --seed 2

echo "== 4. Train the L3 table (ridge regression per class, lambda by GCV)"
"$L3" train "$OUT/train_sim" -o "$OUT/table.npz" --seed 1

echo "== 5. Look inside the table; smooth it with the priors (symmetry, smoothness over levels,"
echo "      uniformity), which fills the classes training left empty"
"$L3" inspect "$OUT/table.npz" --plots "$OUT/kernels" | head -n 25
"$L3" smooth "$OUT/table.npz" -o "$OUT/table_smooth.npz"

echo "== 6. Render the held-out raws (linear XYZ EXR, and display sRGB PNG) with the trained"
echo "      table (here it scores better than the smoothed one: README, 'When l3 smooth helps')"
mkdir -p "$OUT/renders" "$OUT/renders_png"
"$L3" render "$OUT/table.npz" "$OUT/test_sim" -o "$OUT/renders"
"$L3" render "$OUT/table.npz" "$OUT/test_sim" -o "$OUT/renders_png" --format png

echo "== 7. Evaluate against the ideal targets (S-CIELAB at 96 dpi / 1 m, Macbeth dE, MTF50)"
"$L3" evaluate "$OUT/renders" --reference "$OUT/test_sim" --json "$OUT/report.json" \
    --plots "$OUT/plots"
echo "   the PNG renders score the same, within 8-bit quantisation:"
"$L3" evaluate "$OUT/renders_png" --reference "$OUT/test_sim"

echo
echo "Done. Look at $OUT/renders_png/*.png, $OUT/plots/ and $OUT/report.json."
