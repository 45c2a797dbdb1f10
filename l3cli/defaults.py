"""The defaults of l3's options: the one place each is written.

The library's signatures and the command line's ``show_default`` both read
them from here. The module imports nothing, so the CLI can use it without
slowing ``l3 --help``.
"""

# l3 train (:class:`l3cli.train.TrainOptions`) and the class definition.
# The class layout and target space depend on what is trained from; each set was
# measured on its kind of input (docs/training.md, "Defaults"):
#: Pairs folders (a real camera's raws and renders): leave-one-image-out S-CIELAB
#: on the bundled Infinite-ISP frames/ (0.426 against 2.66 for the simulation set).
#: The target is the linear version of the renders' display sRGB (renders are still
#: written as display sRGB), linearised further by a per-channel tone curve learned from
#: the pairs (``tone_curve``, l3cli.tone.curve: 1.373 -> 0.453 at the layout chosen
#: without it, 36 levels and a 0.1 threshold; 0.426 with 24 levels and 0.2).
#: ``augment`` (:data:`l3cli.train.augment.AUGMENT_CHOICES`: train each pair mirrored and
#: rotated too) and ``sample_weight`` (``"luminance"``: weight each sample by its target's
#: luminance, :func:`l3cli.train.weights.sample_weights`) stay off: with the curve they gain
#: 6 % by leave-one-image-out on frames/ (0.426 -> 0.399) and nothing on the held-out frames,
#: but lose 30 % on a LibRaw render of a real sensor (Blackmagic DNG, left half -> right half
#: 0.078 -> 0.104) and the weights lose on a simulated converter; ``l3 train --tune`` tries
#: both on the user's own data (docs/training.md, "Augmentation and sample weights").
#: ``shading``: learn a lens-shading gain field (l3cli.lens.field; docs/training.md, "Lens
#: shading"); kept only where it predicts held-out images better than none.
PAIRS_LAYOUT = {"patch": 7, "levels": 24, "contrast_bins": 3, "contrast_threshold": 0.2,
                "target_space": "linear-srgb", "tone_curve": True,
                "augment": "none", "sample_weight": "none", "shading": True}
#: Simulate folders (ideal XYZ targets): the paper's layout, measured by make paper's
#: experiments 4 and 5 (the pairs layout leaves small simulations with untrained classes).
#: ``contrast_threshold`` None: thresholds at the per-level quantiles of the data.
SIMULATION_LAYOUT = {"patch": 5, "levels": 24, "contrast_bins": 2, "contrast_threshold": None,
                     "target_space": "xyz", "tone_curve": False,
                     "augment": "none", "sample_weight": "none", "shading": False}
#: Patch size (odd) of :class:`l3cli.train.TrainOptions`: the kernel sees PATCH x PATCH pixels.
PATCH = SIMULATION_LAYOUT["patch"]
#: Number of response-level bins (library default).
LEVELS = SIMULATION_LAYOUT["levels"]
#: Learn the renders' per-channel tone curve and train in its linear space (library
#: default; pairs folders use PAIRS_LAYOUT's). Only with the linear-srgb target.
TONE_CURVE = False
#: Learn a lens-shading gain field from rendered pairs (library default; pairs folders use
#: PAIRS_LAYOUT's).
SHADING = SIMULATION_LAYOUT["shading"]
#: Dihedral augmentation of the training pairs (library default; ``"none"``, ``"flips"``, ``"d4"``).
AUGMENT = SIMULATION_LAYOUT["augment"]
#: Per-sample weights of the fit (library default; ``"none"`` or ``"luminance"``).
SAMPLE_WEIGHT = SIMULATION_LAYOUT["sample_weight"]
#: Luminance (Y, white = 1) below which ``"luminance"`` weights stop falling.
WEIGHT_FLOOR = 0.01
#: ``"luminance"`` weights are Y to this power (leave-one-image-out: 1 -> 1.308, 1.25 -> 1.303,
#: 1.5 -> 1.302, 2 -> 1.311).
WEIGHT_EXPONENT = 1.5
#: Spacing of the level cut points (``"log"`` or ``"linear"``).
LEVEL_SPACING = "log"
#: Contrast bins per level (library default; 2 = flat / textured).
CONTRAST_BINS = SIMULATION_LAYOUT["contrast_bins"]
#: Edge-angle bins of the orientation class dimension (0 = off; even).
ORIENTATION_BINS = 0
#: Structure-tensor coherence at or below which a patch counts as isotropic.
COHERENCE = 0.5
#: Block size (pixels) of the context guide (0 = no context dimension).
CONTEXT_BLOCK = 0
#: Context bins (quantiles of the training data's context feature).
CONTEXT_BINS = 3
#: Context feature: ``"mean"`` (the guide) or ``"ratio"`` (patch level / guide).
CONTEXT_RULE = "ratio"
#: Highlight bins (0 = off, 2 = below / at least HIGHLIGHT_FRACTION of the patch saturated).
HIGHLIGHT_BINS = 0
#: Fraction of a patch's pixels saturated that makes it a strong highlight.
HIGHLIGHT_FRACTION = 0.25
#: Normalised raw value at or above which a pixel counts as saturated.
SATURATION = 0.95
#: Share classes between CFA positions whose patch layouts coincide.
MERGE_POSITIONS = True
#: Random fraction of each image's pixels used in training.
SAMPLE_FRACTION = 1.0
#: A class needs at least this many samples per coefficient to be trained.
MIN_SAMPLES_FACTOR = 3.0

# l3 train --multiscale (l3cli.multiscale.stage: noise reduction beyond the patch)
#: Fit the multi-scale stage after the table (off: docs/training.md, "Noise reduction
#: beyond the patch").
MULTISCALE = False
#: Increasing Gaussian low-pass standard deviations of the stage's bands, pixels. Measured on
#: simulated ISO 3200 captures (scripts/measure_multiscale.py; S-CIELAB, flat-patch noise):
#: (1, 3, 9) 1.651, 0.45x; (2, 6) 1.687, 0.34x; (3,) 1.786, 0.39x (no stage 1.817).
MULTISCALE_SIGMAS = (1.0, 3.0, 9.0)
#: Coarse-level bins of the stage's classes (quantiles of the training renders).
MULTISCALE_LEVELS = 12
#: Band-energy bins per level of the stage's classes (12 x 8 classes: 1.687 against 8 x 6's
#: 1.706 and 4 x 4's 1.773 with sigmas (2, 6)).
MULTISCALE_ENERGY_BINS = 8
#: Ridge shrinkage of each class's blend towards the identity (relative to its band power).
MULTISCALE_RIDGE = 1e-3

# l3 train's self-tuning (l3cli.train.tune; docs/training.md, "Self-tuning")
#: Tune by cross-validation by default: on for pairs folders (a camera's own look, which
#: no fixed layout fits every camera), off for simulate folders (the paper's layout).
#: ``--tune`` / ``--no-tune`` override it.
TUNE_PAIRS = True
TUNE_SIMULATE = False
#: The searched values (``[train.tune]`` overrides them): ``spaces`` None = the inputs'
#: default target space and ``srgb``; an empty tuple = not searched (the fixed default).
#: Patch 7/9, lens shading on/off and the multi-scale stage on/off: 3 to 8 candidates,
#: within 3 minutes on the bundled frames on 2 cores (docs/training.md).
TUNE_GRID = {"spaces": None, "patches": (7, 9), "levels": (), "contrast_bins": (),
             "contrast_thresholds": (), "augments": (), "sample_weights": (),
             "shading": (True, False), "multiscale": (False, True), "folds": 5}
#: The one-standard-error rule's cap: a cheaper candidate is chosen over the best only
#: when its CV score is within one paired standard error and within this fraction of it.
TUNE_TOLERANCE = 0.05

# l3 smooth
#: Spline smoothing strength over response levels (λ of the Whittaker smoother).
SPLINE_STRENGTH = 0.02

# l3 evaluate (S-CIELAB viewing conditions and colour path)
#: Display resolution, dots per inch.
DPI = 96.0
#: Viewing distance, metres.
VIEWING_DISTANCE_M = 1.0
#: S-CIELAB filter set (``"distribution"``: ISETCam's; ``"original"``: the 1997 paper's).
SCIELAB_FILTERS = "distribution"
#: S-CIELAB XYZ -> opponent matrix (ISETCam's xyz2opp for the 10° observer).
SCIELAB_OPPONENT = "xyz10"

# every command with --seed
#: Random seed.
SEED = 0
