"""The input layer: (raw, target) pairs from ``simulate`` folders and pairs folders.

Training (``l3 train``) and the conventional baseline (``l3 baseline``) read
their inputs through here; one :class:`Pair` describes one capture whatever
folder it comes from, and :func:`find_pairs` lists them:

* a ``simulate`` output folder (``manifest.json`` with ``"format":
  "l3-simulation"``): each capture's raw and its ideal, pixel-aligned target
  (CIE XYZ EXR);
* a *pairs directory*: raw files (any :data:`l3cli.io.raw.RAW_SUFFIXES`,
  including headerless ``NAME.raw`` with ``NAME.raw.toml``, and l3's TIFF/PNG
  mosaics with a ``.toml`` sidecar) each with one rendered image of the same
  stem (:data:`RENDER_SUFFIXES`): ``a.dng`` + ``a.jpg``, ``b.raw`` +
  ``b.raw.toml`` + ``b.png``. Training learns the mapping from the raw to the
  render (see ``docs/real-camera.md``). Images other than EXR are display
  sRGB; EXR carries its space in the ``l3:space`` attribute.

A :class:`Pair` holds paths and small per-capture facts only (cheap and
picklable, so distributed workers read the files themselves);
:func:`load_pair` reads one into a :class:`LoadedPair`. A simulated target is
pixel-aligned already. A rendered image is registered on its raw first: the
raw is cropped to the render's area (:mod:`l3cli.align` finds the offset and
flip and refuses renders that do not align), the render is put in the raw's
orientation, and a weight mask marks the pixels that may train:

Clipped pixels
    A pixel of the render with any channel at or above ``clip_high``
    (default 254.5/255) or at or below ``clip_low`` (default 0.5/255), in the
    file's encoded values, is excluded: its true colour was lost by the
    renderer's clipping and a regression would learn the clip, not the
    pipeline. (Floating-point EXR renders are not clipped; only non-finite
    values are excluded there.)
Border margin
    ``margin`` pixels (default 4) on every side of the render are excluded:
    ISPs treat edges specially (the Infinite-ISP sharpening zero-pads, so its
    outer rows and columns come out brighter), and near the crop edge the raw
    patch would reach outside the pixels the render covers.
Scaled renders (only with ``scaled=True``; ``l3 train --scaled-renders``)
    A render that does not align pixel for pixel is registered as a resized
    copy (:func:`l3cli.align.align_scaled`) and resampled onto the raw's
    pixels (:func:`l3cli.align.scaled_pair`): the pair then trains at the
    render's reduced resolution (the target holds no finer detail than the
    render), on the raw's own pixel grid, so the table still renders raws at
    full size. Clipped render pixels and the margin (in render pixels) are
    excluded wherever they contribute to a target pixel, and ``margin`` raw
    pixels at the crop's edges as well.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell and B. A. Wandell, "Automating the
   design of image processing pipelines for novel color filter arrays: Local,
   Linear, Learned (L3) method", Proc. SPIE 9023, Digital Photography X, 2014.
"""

from l3cli.pairs.find import (
    CLIP_HIGH,
    CLIP_LOW,
    DEFAULT_MARGIN,
    RENDER_SUFFIXES,
    Pair,
    find_pairs,
    is_pairs_dir,
    is_raw_file,
    is_simulation_dir,
    manifest_path,
    raw_files,
    read_simulation_manifest,
)
from l3cli.pairs.load import LoadedPair, iter_pairs, load_pair, weight_mask

__all__ = [
    "RENDER_SUFFIXES",
    "CLIP_LOW",
    "CLIP_HIGH",
    "DEFAULT_MARGIN",
    "Pair",
    "LoadedPair",
    "is_pairs_dir",
    "is_raw_file",
    "raw_files",
    "is_simulation_dir",
    "manifest_path",
    "read_simulation_manifest",
    "find_pairs",
    "load_pair",
    "iter_pairs",
    "weight_mask",
]
