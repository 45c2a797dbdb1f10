#!/bin/bash
# Experiment 2's validation split (docs/results.md section 2, VALIDATION in
# scripts/paper/rgbw.py): camera and recipe choices scored on the TRAINING
# light levels only. Tables are trained at 10, 120, 1600 and 5000 lux and
# scored on new Macbeth captures at 35 and 450 lux (seed 7); prints the mean
# Macbeth ΔE*ab of the two levels per camera and recipe.
#
#   bash scripts/paper/rgbw_validation.sh [BUILD [OUT]]
#
# BUILD (default paper_out) holds the experiment's cameras/{rgbw,bayer}.toml
# (make paper-rgbw writes them); OUT (default BUILD/validation) the work files.
# The exposure-model rows derive their cameras from those by editing
# max_analog_gain and black_clamp. About 4 min of CPU on 2 cores.
set -euo pipefail
BUILD=${1:-paper_out}
OUT=${2:-$BUILD/validation}
L3=${L3:-.venv/bin/l3}
ESSER=$BUILD/scenes/esser.npz
mkdir -p "$OUT"

camera() {  # camera NAME VARIANT: BUILD/cameras/NAME.toml with the exposure model VARIANT
    local src=$BUILD/cameras/$1.toml dst=$OUT/$1-$2.toml
    case $2 in
        cap) sed -e 's/^max_analog_gain = .*/max_analog_gain = 1.0/' -e 's/^black_clamp = .*/black_clamp = false/' "$src" ;;
        gain) sed -e 's/^black_clamp = .*/black_clamp = false/' "$src" ;;
        clamp) cat "$src" ;;
    esac > "$dst"
    echo "$dst"
}

score() {  # score DIR NAME [train dirs and options...]: train, smooth, render, evaluate; print the mean
    local dir=$1 name=$2; shift 2
    "$L3" -q train "$@" -o "$dir/$name.raw.npz" --seed 1 > /dev/null
    "$L3" -q smooth "$dir/$name.raw.npz" -o "$dir/$name.npz" > /dev/null
    rm -rf "$dir/r-$name"
    "$L3" -q render "$dir/$name.npz" $(ls "$dir"/val/*.dng "$dir"/val/*.tif 2>/dev/null) -o "$dir/r-$name"
    "$L3" -q evaluate "$dir/r-$name" --reference "$dir/val" --json "$dir/$name.json" > /dev/null
    python3 - "$dir/$name.json" "$dir" "$name" <<'PY'
import json, sys
v = [i["macbeth_de_mean"] for i in json.load(open(sys.argv[1]))["images"]]
print(f"{sys.argv[2]:40s} {sys.argv[3]:10s} 35 / 450 lux: {v[0]:.2f} / {v[1]:.2f}  mean {sum(v) / len(v):.2f}")
PY
}

for cam in rgbw bayer; do
    for variant in cap gain clamp; do
        dir=$OUT/$cam-$variant
        mkdir -p "$dir"
        toml=$(camera $cam $variant)
        [ -f "$dir/vtrain/manifest.json" ] || "$L3" -q simulate "$toml" -o "$dir/vtrain" --scene macbeth \
            --scene natural --lux 10 --lux 120 --lux 1600 --lux 5000 --size 320x240 --seed 1
        [ -f "$dir/val/manifest.json" ] || "$L3" -q simulate "$toml" -o "$dir/val" --scene macbeth \
            --lux 35 --lux 450 --size 320x240 --seed 7
        score "$dir" p5 "$dir/vtrain"
    done
    dir=$OUT/$cam-clamp
    score "$dir" p7 "$dir/vtrain" --patch 7
    score "$dir" p9 "$dir/vtrain" --patch 9
    score "$dir" p7l36 "$dir/vtrain" --patch 7 --levels 36
    score "$dir" l12c1 "$dir/vtrain" --levels 12 --contrast-bins 1
    if [ -f "$ESSER" ]; then
        [ -f "$dir/vesser/manifest.json" ] || "$L3" -q simulate "$(camera $cam clamp)" -o "$dir/vesser" \
            --scene "$(realpath "$ESSER")" --lux 10 --lux 120 --lux 1600 --lux 5000 --size 320x240 --seed 3
        score "$dir" esser "$dir/vtrain" "$dir/vesser"
        score "$dir" p7esser "$dir/vtrain" "$dir/vesser" --patch 7
    fi
done
