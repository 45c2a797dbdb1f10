"""The defaults of l3's options: the one place each is written.

The library's signatures and the command line's ``show_default`` both read
them from here. The module imports nothing, so the CLI can use it without
slowing ``l3 --help``.
"""

# l3 train (:class:`l3cli.train.TrainOptions`) and the class definition
#: Patch size (odd): the kernel sees PATCH x PATCH raw pixels.
PATCH = 5
#: Number of response-level bins.
LEVELS = 24
#: Spacing of the level cut points (``"log"`` or ``"linear"``).
LEVEL_SPACING = "log"
#: Contrast bins per level (2 = flat / textured).
CONTRAST_BINS = 2
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

# l3 smooth
#: Spline smoothing strength over response levels (λ of the Whittaker smoother).
SPLINE_STRENGTH = 0.02

# every command with --seed
#: Random seed.
SEED = 0
