# l3 — two commands: `make demo` and `make test` set everything up themselves.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
L3     := $(VENV)/bin/l3
STAMP  := $(VENV)/.l3-installed
SHARED ?= ../shared/data
DEMO   ?= demo_out

.PHONY: setup bytecode demo test test-fast test-portable fuzz bench bench-check lint clean

setup: $(STAMP) bytecode

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

# The package's bytecode, as `pip install` (not -e) writes it: an editable install
# leaves it to Python, which cannot keep it where PYTHONDONTWRITEBYTECODE is set, and
# then compiles every module on every start (~0.15 s of each `l3 render`, measured).
bytecode: $(STAMP)
	$(PY) -m compileall -q l3cli > /dev/null

test: $(STAMP) bytecode
	$(PY) -m pytest -n 2 -q

test-fast: $(STAMP) bytecode
	$(PY) -m pytest -n 2 -q -m "not slow"

# The suite three times, as three other machines would run it: as is; with numpy's
# AVX-512 code paths off (scripts/npy_simd_off.py: on a CPU without AVX-512, every
# SIMD path above numpy's baseline); with numba compiling for a generic x86-64 (or
# the architecture's generic) target. Each must pass (tests/README.md).
test-portable: $(STAMP) bytecode
	@echo "== 1/3: as is"
	$(PY) -m pytest -n 2 -q
	@echo "== 2/3: NPY_DISABLE_CPU_FEATURES=\"$$($(PY) scripts/npy_simd_off.py)\""
	NPY_DISABLE_CPU_FEATURES="$$($(PY) scripts/npy_simd_off.py)" $(PY) -m pytest -n 2 -q
	@echo "== 3/3: NUMBA_CPU_NAME=generic"
	NUMBA_CPU_NAME=generic $(PY) -m pytest -n 2 -q

# Property-based fuzzing of the file readers and output planning with a large
# budget (`make test` runs the same tests with a small one); prints the count.
FUZZ_COUNT := .fuzz-count.txt
fuzz: $(STAMP)
	rm -f $(FUZZ_COUNT)
	L3_FUZZ_PROFILE=fuzz L3_FUZZ_COUNT_FILE=$(FUZZ_COUNT) $(PY) -m pytest -n 0 -q -p no:cacheprovider tests/io/test_fuzz_readers.py
	@cat $(FUZZ_COUNT) && rm -f $(FUZZ_COUNT)

lint: $(STAMP)
	$(VENV)/bin/ruff check l3cli tests benchmarks

demo: $(STAMP) bytecode
	bash scripts/demo.sh $(L3) $(DEMO)

bench: $(STAMP) bytecode
	$(PY) benchmarks/run_all.py --out docs/performance.md
	$(PY) benchmarks/check_kernel_cost.py

# The default-trained table's render kernel within 30 % of the plain table's (a ratio
# measured in one process; exits non-zero when it is not).
bench-check: $(STAMP) bytecode
	$(PY) benchmarks/check_kernel_cost.py

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache .ruff_cache build *.egg-info

# ---------------------------------------------------------------------------
# `make paper`: re-run the L3 paper's experiments (issue 9) and write
# docs/results.md + docs/figures/. Also an example batch pipeline: camera
# TOMLs -> simulation folders -> tables -> renders -> JSON reports -> Markdown.
# Everything but the committed docs lands in $(PAPER). One target per
# experiment: paper-real paper-rgbw paper-rgbnir paper-levels paper-patch
# paper-mtf paper-kernels.
PAPER          ?= paper_out
PAPER_SIZE     ?= 320x240
# Exposure: empty = each camera's own auto exposure (its TOML's [exposure]:
# brightest pixel at 95 % of white, at most 0.5 s, then auto ISO: analog gain
# up to 16x, so only scenes below a few lux are under-exposed); a number =
# that fixed time in seconds for every camera without its own
# PAPER_EXPOSURE_<camera>.
PAPER_EXPOSURE ?=
# the RGB-NIR experiment keeps a fixed exposure (2 um pixels, f/2.8: ~4x the
# light per pixel of the RGBW camera), so its light level sets the response level
PAPER_EXPOSURE_rgbnir       := 0.0125
PAPER_EXPOSURE_rgbnir-black := 0.0125
PAPER_EXPOSURE_rgbnir-g     := 0.0125
PAPER_TRAIN_LUX ?= 10 35 120 450 1600 5000
PAPER_TEST_LUX  ?= 20 70 250 900 3000
PAPER_TEST_SCENES_rgbw := macbeth slanted-edge
# The RGBW experiment's tables: 7x7 patches (24 levels, 2 contrast bins), the
# pick of a validation split of the TRAINING light levels (docs/results.md
# section 2); its "wide classes" variant: 12 response levels, one contrast
# bin. Extra `l3 train` options per camera: PAPER_TRAIN_OPTS_<camera> (tables
# are not rebuilt when only these change).
PAPER_RGBW_TRAIN_OPTS := --patch 7
PAPER_TRAIN_OPTS_rgbw := $(PAPER_RGBW_TRAIN_OPTS)
PAPER_TRAIN_OPTS_bayer := $(PAPER_RGBW_TRAIN_OPTS)
PAPER_TRAIN_OPTS_rgbw-ircut := $(PAPER_RGBW_TRAIN_OPTS)
PAPER_WIDE_TRAIN_OPTS := --levels 12 --contrast-bins 1
PAPER_PY       := L3=$(abspath $(L3)) $(PY) scripts/paper
PAPER_COMMON   := scripts/paper/common.py $(STAMP)
PAPER_SECTIONS := real rgbw rgbnir levels patch mtf kernels

.PHONY: paper paper-real paper-rgbw paper-rgbnir paper-levels paper-patch paper-mtf paper-kernels
# Build files are kept (.SECONDARY), and a deleted one is not rebuilt while
# docs/results.md is newer. After a change to l3 itself (which the rules do not
# track), re-run what depends on it by name, e.g. after an evaluate change:
#   rm -rf paper_out/eval paper_out/sections paper_out/real
#   make paper-real paper-rgbw paper-rgbnir paper-levels paper-patch paper-mtf paper-kernels paper
.SECONDARY:

paper: docs/results.md

docs/results.md: scripts/paper/results.py $(PAPER_SECTIONS:%=$(PAPER)/sections/%.md)
	$(PAPER_PY)/results.py $(PAPER) docs/results.md

paper-real paper-rgbw paper-rgbnir paper-levels paper-patch paper-mtf paper-kernels: paper-%: $(PAPER)/sections/%.md

# The simulation settings, rewritten only when they change (so changing e.g.
# PAPER_TEST_LUX on the command line re-runs what depends on it).
$(PAPER)/settings.txt: paper-settings-check
	@mkdir -p $(@D)
	@echo "$(PAPER_SIZE) $(PAPER_EXPOSURE) $(PAPER_EXPOSURE_rgbnir) $(PAPER_TRAIN_LUX) / $(PAPER_TEST_LUX) $(PAPER_TEST_SCENES_rgbw)" \
	    | cmp -s - $@ || echo "$(PAPER_SIZE) $(PAPER_EXPOSURE) $(PAPER_EXPOSURE_rgbnir) $(PAPER_TRAIN_LUX) / $(PAPER_TEST_LUX) $(PAPER_TEST_SCENES_rgbw)" > $@
.PHONY: paper-settings-check

# Camera variants (W -> G, NIR blacked out, ...) generated from sample_configs/.
$(PAPER)/cameras/%.toml: scripts/paper/cameras.py sample_configs/rgbw.toml sample_configs/rgbnir.toml
	$(PAPER_PY)/cameras.py $* $@

# The Esser chart's 113 measured reflectances (to 1068 nm), tiled into a
# spectral cube: training colours whose near infrared is measured, not modelled.
$(PAPER)/scenes/esser.npz: scripts/paper/esser.py l3cli/data/spectral/reflectance_esser.csv
	$(PY) scripts/paper/esser.py $@ $(PAPER_SIZE)

# Training captures (Macbeth + the bundled natural photos) and held-out test
# captures (Macbeth, + slanted edge for RGBW, at light levels not used in training).
$(PAPER)/sim/%/train/manifest.json: $(PAPER)/cameras/%.toml $(PAPER)/settings.txt $(STAMP)
	rm -rf $(@D) && mkdir -p $(dir $(@D))
	$(L3) -q simulate $(abspath $<) -o $(@D) --scene macbeth --scene natural \
	    $(addprefix --lux ,$(PAPER_TRAIN_LUX)) $(addprefix --exposure ,$(or $(PAPER_EXPOSURE_$*),$(PAPER_EXPOSURE))) --size $(PAPER_SIZE) --seed 1

$(PAPER)/sim/%/test/manifest.json: $(PAPER)/cameras/%.toml $(PAPER)/settings.txt $(STAMP)
	rm -rf $(@D) && mkdir -p $(dir $(@D))
	$(L3) -q simulate $(abspath $<) -o $(@D) $(addprefix --scene ,$(or $(PAPER_TEST_SCENES_$*),macbeth)) \
	    $(addprefix --lux ,$(PAPER_TEST_LUX)) $(addprefix --exposure ,$(or $(PAPER_EXPOSURE_$*),$(PAPER_EXPOSURE))) --size $(PAPER_SIZE) --seed 2

# L3 tables: train (ridge + GCV per class), then smooth (the priors).
$(PAPER)/tables/%.raw.npz: $(PAPER)/sim/%/train/manifest.json
	mkdir -p $(@D)
	$(L3) -q train $(<D) -o $@ --seed 1 $(PAPER_TRAIN_OPTS_$*)

$(PAPER)/tables/%.npz: $(PAPER)/tables/%.raw.npz
	$(L3) -q smooth $< -o $@

# Render the held-out captures and score them against the ideal targets.
$(PAPER)/eval/%.json: $(PAPER)/tables/%.npz $(PAPER)/sim/%/test/manifest.json
	rm -rf $(PAPER)/render/$* && mkdir -p $(PAPER)/render/$* $(@D)
	$(L3) -q render $< $$(ls $(PAPER)/sim/$*/test/*.dng $(PAPER)/sim/$*/test/*.tif 2>/dev/null) -o $(PAPER)/render/$*
	$(L3) -q evaluate $(PAPER)/render/$* --reference $(PAPER)/sim/$*/test --json $@

# The same, trained in CIELAB (--target lab: the ridge loss then approximates a
# ΔE loss), scored on the Macbeth captures only.
$(PAPER)/tables/%-lab.raw.npz: $(PAPER)/sim/%/train/manifest.json
	mkdir -p $(@D)
	$(L3) -q train $(<D) -o $@ --seed 1 --target lab $(PAPER_TRAIN_OPTS_$*)

$(PAPER)/eval/%-lab.json: $(PAPER)/tables/%-lab.npz $(PAPER)/sim/%/test/manifest.json
	rm -rf $(PAPER)/render/$*-lab && mkdir -p $(PAPER)/render/$*-lab $(@D)
	$(L3) -q render $< $$(ls $(PAPER)/sim/$*/test/macbeth*.dng $(PAPER)/sim/$*/test/macbeth*.tif 2>/dev/null) -o $(PAPER)/render/$*-lab
	$(L3) -q evaluate $(PAPER)/render/$*-lab --reference $(PAPER)/sim/$*/test --json $@

# The same cameras trained without the chart (natural photos only), so the
# Macbeth test is out of sample in its colours too.
$(PAPER)/sim/%/train-natural/manifest.json: $(PAPER)/cameras/%.toml $(PAPER)/settings.txt $(STAMP)
	rm -rf $(@D) && mkdir -p $(dir $(@D))
	$(L3) -q simulate $(abspath $<) -o $(@D) --scene natural \
	    $(addprefix --lux ,$(PAPER_TRAIN_LUX)) $(addprefix --exposure ,$(or $(PAPER_EXPOSURE_$*),$(PAPER_EXPOSURE))) --size $(PAPER_SIZE) --seed 1

$(PAPER)/tables/%-nochart.raw.npz: $(PAPER)/sim/%/train-natural/manifest.json
	mkdir -p $(@D)
	$(L3) -q train $(<D) -o $@ --seed 1 $(PAPER_TRAIN_OPTS_$*)

$(PAPER)/eval/%-nochart.json: $(PAPER)/tables/%-nochart.npz $(PAPER)/sim/%/test/manifest.json
	rm -rf $(PAPER)/render/$*-nochart && mkdir -p $(PAPER)/render/$*-nochart $(@D)
	$(L3) -q render $< $$(ls $(PAPER)/sim/$*/test/macbeth*.dng $(PAPER)/sim/$*/test/macbeth*.tif 2>/dev/null) -o $(PAPER)/render/$*-nochart
	$(L3) -q evaluate $(PAPER)/render/$*-nochart --reference $(PAPER)/sim/$*/test --json $@

# The same cameras with the Esser chart added to training (measured
# near-infrared reflectances instead of the photos' modelled ones).
$(PAPER)/sim/%/train-esser/manifest.json: $(PAPER)/cameras/%.toml $(PAPER)/scenes/esser.npz $(PAPER)/settings.txt $(STAMP)
	rm -rf $(@D) && mkdir -p $(dir $(@D))
	$(L3) -q simulate $(abspath $<) -o $(@D) --scene $(abspath $(PAPER)/scenes/esser.npz) \
	    $(addprefix --lux ,$(PAPER_TRAIN_LUX)) $(addprefix --exposure ,$(or $(PAPER_EXPOSURE_$*),$(PAPER_EXPOSURE))) --size $(PAPER_SIZE) --seed 3

$(PAPER)/tables/%-esser.raw.npz: $(PAPER)/sim/%/train/manifest.json $(PAPER)/sim/%/train-esser/manifest.json
	mkdir -p $(@D)
	$(L3) -q train $(<D) $(PAPER)/sim/$*/train-esser -o $@ --seed 1 $(PAPER_TRAIN_OPTS_$*)

$(PAPER)/eval/%-esser.json: $(PAPER)/tables/%-esser.npz $(PAPER)/sim/%/test/manifest.json
	rm -rf $(PAPER)/render/$*-esser && mkdir -p $(PAPER)/render/$*-esser $(@D)
	$(L3) -q render $< $$(ls $(PAPER)/sim/$*/test/macbeth*.dng $(PAPER)/sim/$*/test/macbeth*.tif 2>/dev/null) -o $(PAPER)/render/$*-esser
	$(L3) -q evaluate $(PAPER)/render/$*-esser --reference $(PAPER)/sim/$*/test --json $@

# The same cameras with fewer, wider classes (PAPER_WIDE_TRAIN_OPTS).
$(PAPER)/tables/%-wide.raw.npz: $(PAPER)/sim/%/train/manifest.json
	mkdir -p $(@D)
	$(L3) -q train $(<D) -o $@ --seed 1 $(PAPER_WIDE_TRAIN_OPTS)

$(PAPER)/eval/%-wide.json: $(PAPER)/tables/%-wide.npz $(PAPER)/sim/%/test/manifest.json
	rm -rf $(PAPER)/render/$*-wide && mkdir -p $(PAPER)/render/$*-wide $(@D)
	$(L3) -q render $< $$(ls $(PAPER)/sim/$*/test/macbeth*.dng $(PAPER)/sim/$*/test/macbeth*.tif 2>/dev/null) -o $(PAPER)/render/$*-wide
	$(L3) -q evaluate $(PAPER)/render/$*-wide --reference $(PAPER)/sim/$*/test --json $@

# The conventional pipeline (demosaic + 3x3 matrix) on the Bayer camera.
$(PAPER)/eval/bayer-baseline.json: $(PAPER)/sim/bayer/train/manifest.json $(PAPER)/sim/bayer/test/manifest.json
	rm -rf $(PAPER)/render/bayer-baseline && mkdir -p $(@D)
	$(L3) -q baseline $(PAPER)/sim/bayer/test --train $(PAPER)/sim/bayer/train -o $(PAPER)/render/bayer-baseline
	$(L3) -q evaluate $(PAPER)/render/bayer-baseline --reference $(PAPER)/sim/bayer/test --json $@

# 1. Approximating a real pipeline: the real-camera script (issue 7).
$(PAPER)/real/summary.json: scripts/real_camera.sh scripts/real_camera_data.py $(STAMP)
	PYTHON=$(PY) bash scripts/real_camera.sh $(L3) $(PAPER)/real $(SHARED)
	$(PAPER_PY)/real.py $(PAPER) --collect

$(PAPER)/sections/real.md: scripts/paper/real.py $(PAPER_COMMON) $(PAPER)/real/summary.json
	$(PAPER_PY)/real.py $(PAPER)

# 2. RGBW vs the same camera with W -> G (an RGGB Bayer; also behind an IR-cut
#    filter), and vs the conventional pipeline on the Bayer camera.
$(PAPER)/sections/rgbw.md: scripts/paper/rgbw.py $(PAPER_COMMON) $(PAPER)/eval/rgbw.json \
        $(PAPER)/eval/rgbw-lab.json $(PAPER)/eval/bayer-lab.json $(PAPER)/eval/rgbw-nochart.json \
        $(PAPER)/eval/bayer-nochart.json $(PAPER)/eval/rgbw-ircut.json $(PAPER)/eval/bayer.json \
        $(PAPER)/eval/bayer-baseline.json $(PAPER)/eval/rgbw-esser.json $(PAPER)/eval/bayer-esser.json \
        $(PAPER)/eval/rgbw-wide.json $(PAPER)/eval/bayer-wide.json
	$(PAPER_PY)/rgbw.py $(PAPER)

# 3. RGB-NIR vs NIR blacked out vs NIR -> G; NIR weights over response levels.
$(PAPER)/sections/rgbnir.md: scripts/paper/rgbnir.py $(PAPER_COMMON) $(PAPER)/eval/rgbnir.json \
        $(PAPER)/eval/rgbnir-black.json $(PAPER)/eval/rgbnir-g.json $(PAPER)/tables/rgbnir.npz
	$(PAPER_PY)/rgbnir.py $(PAPER)

# 4. Number of response levels, log vs linear spacing (trains its own tables).
$(PAPER)/sections/levels.md: scripts/paper/levels.py $(PAPER_COMMON) \
        $(PAPER)/sim/bayer/train/manifest.json $(PAPER)/sim/bayer/test/manifest.json
	$(PAPER_PY)/levels.py $(PAPER)

# 5. Patch size 5/7/9: accuracy and cost (trains its own tables).
$(PAPER)/sections/patch.md: scripts/paper/patch.py $(PAPER_COMMON) \
        $(PAPER)/sim/rgbw/train/manifest.json $(PAPER)/sim/rgbw/test/manifest.json
	$(PAPER_PY)/patch.py $(PAPER)

# 6. Resolution: RGBW MTF50 vs the diffraction bound, over f-number x pixel size.
$(PAPER)/sections/mtf.md: scripts/paper/mtf.py scripts/paper/cameras.py $(PAPER_COMMON) \
        $(PAPER)/eval/rgbw.json
	$(PAPER_PY)/mtf.py $(PAPER)

# 7. The transforms: RGBW kernels at low / mid / high / saturated levels
#    (without and with an IR-cut filter).
$(PAPER)/sections/kernels.md: scripts/paper/kernels.py $(PAPER_COMMON) $(PAPER)/tables/rgbw.npz \
        $(PAPER)/tables/rgbw-ircut.npz
	$(PAPER_PY)/kernels.py $(PAPER)
