"""Priors on a trained transform table (``l3 smooth``; see ``docs/smoothing.md``).

Three independent priors, each on by default and each switchable, applied in
this order:

1. :mod:`l3cli.smooth.symmetry` -- kernels of CFA positions whose patch layouts
   are mirror images / rotations of each other are mirror images / rotations of
   each other (exactly, after the step);
2. :mod:`l3cli.smooth.spline` -- every coefficient is a smooth function of
   ``ln level`` (weighted smoothing spline); the same fit fills empty classes;
   in a condition-indexed table (``l3 train --by``) the per-bin kernels are
   also smooth functions of ``ln`` condition value, and a class a bin lacks is
   filled from the neighbouring bins (not the pooled kernel);
3. :mod:`l3cli.smooth.uniformity` -- a uniform scene renders uniform (the
   per-channel sums of the weights and the offsets agree across positions).

Symmetry is re-imposed exactly at the end (the later steps keep it up to
rounding). The output table records which priors ran, with what settings and
which classes were filled, under ``provenance["smoothing"]``.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell, B. A. Wandell, "Automating the design
   of image processing pipelines for novel color filter arrays: Local, Linear,
   Learned (L3) method", Proc. SPIE 9023, Digital Photography X (2014).
.. [2] H. Jiang, Q. Tian, J. Farrell, B. A. Wandell, "Learning the image
   processing pipeline", IEEE Trans. Image Processing 26(10), 5032-5042 (2017).
"""

from __future__ import annotations

import copy
import logging

import numpy as np

from l3cli import __version__
from l3cli.errors import ConfigError
from l3cli.smooth.spline import (
    DEFAULT_STRENGTH,
    DEFAULT_STRENGTH_GRID,
    smooth_conditions,
    smooth_levels,
)
from l3cli.smooth.symmetry import orbit_weights, symmetrize_kernels, symmetry_map
from l3cli.smooth.uniformity import fillable, make_uniform, missing_channels, uniformity_error
from l3cli.table import TransformTable

__all__ = ["smooth_table", "filled_classes", "DEFAULT_STRENGTH"]

log = logging.getLogger(__name__)


def _fallback_sources(definition, trained):
    from l3cli.train.fit import fallback_sources

    return fallback_sources(definition, trained)


def smooth_table(table: TransformTable, *, symmetry: bool = True, spline: bool = True,
                 uniformity: bool = True, spline_strength: float | str | None = DEFAULT_STRENGTH,
                 symmetry_elements: tuple[str, ...] | None = None,
                 uniformity_target: str = "period-mean") -> TransformTable:
    """Apply the priors to a table and return a new table.

    Parameters
    ----------
    table
        A trained table (not changed).
    symmetry, spline, uniformity
        Which priors run.
    spline_strength
        λ of the smoothing spline (data weights = samples per coefficient,
        abscissa ``ln level``; :data:`DEFAULT_STRENGTH`), or ``"auto"`` (or
        ``None``): one λ per series by generalised cross-validation.
    symmetry_elements
        D4 element names to use (default: all; the set is closed into a group).
    uniformity_target
        ``"period-mean"`` (common channel sums = mean over the CFA positions, so
        flat-area colours keep their period average) or ``"least-squares"``
        (sample-count weighted least-squares targets); see
        :func:`l3cli.smooth.uniformity.make_uniform`.

    Returns
    -------
    TransformTable
        Same class definition, counts and λ; new kernels; classes filled by
        symmetry or by the spline are no longer empty (their ``source_class``
        is themselves); ``provenance["smoothing"]`` records the run.
    """
    if isinstance(spline_strength, str):
        if spline_strength != "auto":
            try:
                spline_strength = float(spline_strength)
            except ValueError:
                raise ConfigError(f"spline strength {spline_strength!r} is not allowed; "
                                  "use 'auto' or a number >= 0") from None
        else:
            spline_strength = None
    if spline_strength is not None and (not np.isfinite(spline_strength) or spline_strength < 0):
        raise ConfigError(f"spline strength {spline_strength} is not allowed; use 'auto' or >= 0")
    d = table.definition
    kernels = table.kernels.astype(np.float64)
    empty = table.empty.copy()
    weights = np.where(empty, 0.0, table.counts.astype(np.float64))
    record: dict = {"l3_version": __version__, "priors": [], "order":
                    ["symmetry", "spline", "uniformity"]}
    filled_by: dict[str, list[int]] = {}
    smap = None
    if symmetry:
        smap = symmetry_map(d, elements=symmetry_elements)
        kernels = symmetrize_kernels(kernels, weights, d, smap)
        w_orb = orbit_weights(weights, d, smap)
        newly = empty & (w_orb > 0)
        filled_by["symmetry"] = np.flatnonzero(newly).tolist()
        empty = empty & ~newly
        weights = w_orb
        record["priors"].append("symmetry")
        record["symmetry"] = {
            "elements": list(symmetry_elements) if symmetry_elements else "all of D4",
            **smap.describe(),
            "weights": "sample counts (empty classes 0)",
        }
    if spline:
        kernels, filled, lam_med = smooth_levels(
            kernels, weights, d, strength=spline_strength)
        newly = empty & filled
        filled_by["spline"] = np.flatnonzero(newly).tolist()
        empty = empty & ~newly
        record["priors"].append("spline")
        finite = lam_med[np.isfinite(lam_med)]
        record["spline"] = {
            "strength": "auto (GCV per series, coefficients pooled)" if spline_strength is None
            else float(spline_strength),
            "grid": [float(DEFAULT_STRENGTH_GRID[0]), float(DEFAULT_STRENGTH_GRID[-1]),
                     int(DEFAULT_STRENGTH_GRID.size)] if spline_strength is None else None,
            "abscissa": "ln(level bin centre)",
            "penalty": "second divided differences (Whittaker smoother)",
            "weights": "samples per coefficient" + (" summed over symmetry orbits" if symmetry else ""),
            "extrapolation": "constant beyond the first/last trained level",
            "lambda_median": float(np.median(finite)) if finite.size else None,
        }
    conditions = table.conditions
    if spline and conditions is not None:
        from l3cli.conditions import Conditioned

        ck, cfilled = smooth_conditions(conditions.values, conditions.kernels, conditions.counts,
                                        d.n_coeffs, strength=spline_strength)
        conditions = Conditioned(conditions.by, conditions.values, ck.astype(np.float32),
                                 conditions.counts, conditions.filled | cfilled)
        record["spline"]["conditions"] = {
            "by": conditions.by, "abscissa": "ln(condition value)",
            "filled_per_bin": [int(f.sum()) for f in cfilled]}
    if uniformity:
        before = uniformity_error(kernels, d, mask=~empty)
        trained = ~empty
        # an empty class whose slot is trained at other positions starts from its
        # fallback kernel and follows the common values
        newly = fillable(trained, d)
        kernels = np.where(newly[:, None, None], kernels[_fallback_sources(d, trained)], kernels)
        kernels = make_uniform(kernels, weights, d, active=trained, target=uniformity_target,
                               fill=newly)
        filled_by["uniformity"] = np.flatnonzero(newly).tolist()
        empty = empty & ~newly
        record["priors"].append("uniformity")
        record["uniformity"] = {
            "method": "per-channel weight sums and offsets made equal across position groups, "
                      "minimum-norm change spread over each channel's taps",
            "target": uniformity_target,
            "weights": "positions per group" if uniformity_target == "period-mean"
            else "sample counts / taps per channel",
            "spread_before": before,
            "channels_left_alone": missing_channels(d),
        }
        if record["uniformity"]["channels_left_alone"]:
            log.warning("uniformity: channels %s are missing from some %dx%d patch layouts and "
                        "cannot be made uniform; use a larger patch",
                        ", ".join(record["uniformity"]["channels_left_alone"]), d.patch, d.patch)
    if symmetry and smap is not None:
        # the later steps keep symmetry up to rounding: make it exact again
        kernels = symmetrize_kernels(kernels, np.ones_like(weights), d, smap)
    # empty classes keep the kernel of a trained class
    trained = ~empty
    src = _fallback_sources(d, trained)
    kernels = kernels[src]
    if uniformity:
        record["uniformity"]["spread_after"] = uniformity_error(kernels, d, mask=trained)
    all_filled = sorted(set().union(*filled_by.values())) if filled_by else []
    record["filled_classes"] = all_filled
    record["filled_by"] = filled_by
    record["still_empty"] = int(empty.sum())
    prov = copy.deepcopy(table.provenance)
    history = prov.get("smoothing_history", [])
    if "smoothing" in prov:
        history.append(prov["smoothing"])
        prov["smoothing_history"] = history
    prov["smoothing"] = record
    log.info("smoothing: priors %s; filled %d classes, %d still empty",
             ", ".join(record["priors"]) or "none", len(all_filled), int(empty.sum()))
    return TransformTable(definition=d, kernels=kernels.astype(np.float32), counts=table.counts,
                          lambdas=table.lambdas, empty=empty, source_class=src,
                          output_space=table.output_space, provenance=prov,
                          white_balance=table.white_balance, conditions=conditions,
                          tone_lut=table.tone_lut,
                          multiscale=table.multiscale)  # kept: it follows any kernels


def filled_classes(table: TransformTable) -> dict[str, list[int]]:
    """Classes that smoothing filled, by prior (``{}`` when never smoothed)."""
    rec = table.provenance.get("smoothing") or {}
    return {k: list(v) for k, v in (rec.get("filled_by") or {}).items()}
