"""A readable summary of a transform table (``l3 inspect``).

:func:`table_summary` gathers the facts (JSON-friendly dict): class layout,
level cut points, samples and ridge λ per class, empty classes and their
fallbacks, classes filled by smoothing, output space and provenance;
:func:`format_summary` turns them into text.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell, B. A. Wandell, "Automating the design
   of image processing pipelines for novel color filter arrays: Local, Linear,
   Learned (L3) method", Proc. SPIE 9023, Digital Photography X (2014).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from l3cli.errors import ConfigError
from l3cli.features import table_features
from l3cli.figures import group_name
from l3cli.table import TransformTable

__all__ = ["table_summary", "format_summary", "saturation_name", "class_rows", "compress_ranges",
           "filled_classes", "plain_value", "plain_lines", "CLASS_LISTS"]


def saturation_name(bits: int, channels: tuple[str, ...]) -> str:
    """``"-"`` for no saturated channel, else the channel names joined by ``+``."""
    names = [c for i, c in enumerate(channels) if bits >> i & 1]
    return "+".join(names) if names else "-"


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def plain_value(v: Any) -> str:
    """One line of plain text for a provenance value (no JSON brackets).

    Numbers to 4 significant digits; a long list of numbers as its count and
    range (``"41 values from 1e-09 to 10, log-spaced (x1.78 each)"``), a table
    of numbers as its shape and range, a long list of names as its first six
    and the count.

    Examples
    --------
    >>> plain_value([1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5])
    '9 values from 0.001 to 1e+05, log-spaced (x10 each)'
    >>> plain_value([[0.1, 0.2], [0.3, 1.0]])
    '2 x 2 numbers from 0.1 to 1'
    >>> plain_value({"used": True, "space": "srgb"})
    'used yes, space srgb'
    """
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return ", ".join(f"{k} {plain_value(x)}" for k, x in v.items()) or "none"
    if isinstance(v, (list, tuple)):
        if not v:
            return "none"
        if all(_is_number(x) for x in v):
            if len(v) <= 8:
                return ", ".join(plain_value(x) for x in v)
            a = np.asarray(v, dtype=np.float64)
            text = f"{a.size} values from {a[0]:.4g} to {a[-1]:.4g}"
            if np.all(a > 0):
                r = a[1:] / a[:-1]
                if np.allclose(r, r[0], rtol=1e-6) and r[0] != 1:
                    text += f", log-spaced (x{r[0]:.3g} each)"
            return text
        if all(isinstance(x, (list, tuple)) and x and all(_is_number(y) for y in x) for x in v) \
                and len({len(x) for x in v}) == 1:
            a = np.asarray(v, dtype=np.float64)
            return f"{a.shape[0]} x {a.shape[1]} numbers from {a.min():.4g} to {a.max():.4g}"
        parts = [plain_value(x) for x in v[:6]]
        sep = "; " if any(isinstance(x, (dict, list, tuple)) for x in v) else ", "
        return sep.join(parts) + (f"{sep}... ({len(v)} in all)" if len(v) > 6 else "")
    return str(v)


def plain_lines(key: str, v: Any, indent: int = 1) -> list[str]:
    """``key: value`` lines of :func:`plain_value`, a nested dict as an indented block."""
    pad = "  " * indent
    if isinstance(v, dict) and v and (len(v) > 3 or any(isinstance(x, (dict, list))
                                                         for x in v.values())):
        out = [f"{pad}{key}:"]
        for k, x in v.items():
            out += plain_lines(str(k), x, indent + 1)
        return out
    return [f"{pad}{key}: {plain_value(v)}"]


def compress_ranges(indices: Iterable[int]) -> str:
    """``[1, 2, 3, 7]`` -> ``"1-3, 7"``."""
    idx = sorted(int(i) for i in indices)
    if not idx:
        return "none"
    parts = []
    start = prev = idx[0]
    for i in idx[1:]:
        if i == prev + 1:
            prev = i
            continue
        parts.append(f"{start}-{prev}" if prev > start else f"{start}")
        start = prev = i
    parts.append(f"{start}-{prev}" if prev > start else f"{start}")
    return ", ".join(parts)


def filled_classes(table: TransformTable) -> dict[int, str]:
    """``{class index: prior}`` of the classes ``l3 smooth`` filled."""
    rec = table.provenance.get("smoothing") or {}
    out: dict[int, str] = {}
    for prior, idx in (rec.get("filled_by") or {}).items():
        for i in idx:
            out.setdefault(int(i), prior)
    return out


def class_rows(table: TransformTable) -> list[dict[str, Any]]:
    """One dict per class: index, group, positions, saturation, level, contrast,
    samples, λ per output, status (``trained``, ``filled:<prior>`` or ``empty``)
    and source class."""
    d = table.definition
    g, s, lev, tex = (np.asarray(a) for a in d.class_tuple(np.arange(d.n_classes)))
    con, ori, ctx, hl = (np.asarray(a) for a in d.texture_tuple(tex))
    filled = filled_classes(table)
    members = {gg: np.flatnonzero(d.position_group == gg).tolist() for gg in range(d.n_groups)}
    rows = []
    for i in range(d.n_classes):
        if table.empty[i]:
            status = "empty"
        elif i in filled:
            status = f"filled:{filled[i]}"
        else:
            status = "trained"
        lam = table.lambdas[i]
        rows.append({
            "class": i, "group": int(g[i]), "positions": members[int(g[i])],
            "saturation": saturation_name(int(s[i]), d.cfa.channels),
            "level": int(lev[i]), "contrast": int(con[i]),
            **({"orientation": int(ori[i]), "context": int(ctx[i]), "highlight": int(hl[i])}
               if d.has_extra_features else {}),
            "samples": int(table.counts[i]),
            "lambda": [None if not np.isfinite(v) else float(v) for v in lam],
            "status": status, "source": int(table.source_class[i]),
        })
    return rows


def table_summary(table: TransformTable, *, name: str = "table") -> dict[str, Any]:
    """Facts about a table, JSON-serialisable.

    Parameters
    ----------
    table
        The table.
    name
        Shown as the table's name (usually its file path).

    Returns
    -------
    dict
        Keys ``name``, ``format``, ``version``, ``output_space``, ``n_out``,
        ``cfa`` (spec, period, channels), ``patch``, ``layout`` (groups with
        their positions, saturation patterns, levels, contrast bins, classes),
        ``levels`` (per level bin: range, samples, trained classes, contrast
        cuts), ``classes`` (trained / empty / filled counts), ``empty`` (per
        saturation pattern: empty class indices), ``filled`` (by prior),
        ``samples`` (total), ``lambda`` (quantiles over trained classes),
        ``smoothing`` (record or None), ``provenance``.
    """
    d = table.definition
    cfa = d.cfa
    ng, ns, nl, nc = d.shape
    counts = table.counts.reshape(ng, ns, nl, nc)
    trained = (~table.empty).reshape(ng, ns, nl, nc)
    filled = filled_classes(table)
    cuts = d.level_cuts
    levels = []
    for lv in range(nl):
        lo = 0.0 if lv == 0 else float(cuts[lv - 1])
        hi = None if lv == nl - 1 else float(cuts[lv])
        levels.append({
            "level": lv, "from": lo, "to": hi,
            "samples": int(counts[:, :, lv].sum()),
            "samples_unsaturated": int(counts[:, 0, lv].sum()),
            "trained_classes": int(trained[:, :, lv].sum()),
            "contrast_cuts": [float(v) for v in d.contrast_cuts[lv]],
        })
    empty_by_sat: dict[str, list[int]] = {}
    for i in np.flatnonzero(table.empty):
        _, s, _, _ = d.class_tuple(int(i))
        empty_by_sat.setdefault(saturation_name(int(s), cfa.channels), []).append(int(i))
    fin = table.lambdas[np.isfinite(table.lambdas)]
    lam = ({"min": float(fin.min()), "median": float(np.median(fin)), "max": float(fin.max())}
           if fin.size else None)
    by_prior: dict[str, list[int]] = {}
    for i, prior in filled.items():
        by_prior.setdefault(prior, []).append(i)
    return {
        "name": name,
        "format": table.format,
        "version": table.file_version,
        "output_space": table.output_space,
        "n_out": table.n_out,
        "cfa": {"spec": cfa.spec, "period": list(cfa.period), "channels": list(cfa.channels)},
        "patch": d.patch,
        "layout": {
            "groups": [np.flatnonzero(d.position_group == gg).tolist() for gg in range(ng)],
            "group_names": [group_name(d, gg) for gg in range(ng)],
            "saturation_patterns": ns, "levels": nl, "contrast_bins": d.n_contrast,
            **({"orientation_bins": d.n_orientation, "context_bins": d.n_context,
                "highlight_bins": d.n_highlight, "texture_bins": nc}
               if d.has_extra_features else {}),
            "classes": d.n_classes, "coefficients": d.n_coeffs,
            "level_spacing": d.level_spacing, "saturation_threshold": d.saturation_threshold,
            "contrast_rule": d.contrast_rule, "saturation_rule": d.saturation_rule,
        },
        "levels": levels,
        "classes": {"trained": int((~table.empty).sum()) - len(filled),
                    "filled": len(filled), "empty": int(table.empty.sum())},
        "empty": {k: v for k, v in sorted(empty_by_sat.items())},
        "filled": {k: sorted(v) for k, v in sorted(by_prior.items())},
        "samples": int(table.counts.sum()),
        "lambda": lam,
        "smoothing": table.provenance.get("smoothing"),
        "features": [f.name for f in table_features(table)],  # l3cli.features: one list
        "white_balance": table.white_balance is not None,
        "tone_curve": None if table.tone_lut is None else int(table.tone_lut[0].shape[0]),
        "shading": None if table.shading is None else table.shading.summary(),
        "multiscale": None if table.multiscale is None else {
            "sigmas": table.multiscale.sigmas.tolist(), "classes": table.multiscale.n_classes,
            "levels": int(table.multiscale.level_cuts.size + 1),
            "transfer": table.multiscale.transfer},
        "conditions": None if table.conditions is None else {
            "by": table.conditions.by,
            "bins": [{"value": float(v), "samples": int(c.sum()),
                      "trained_classes": int((c > 0).sum()), "filled_classes": int(f.sum())}
                     for v, c, f in zip(table.conditions.values, table.conditions.counts,
                                        table.conditions.filled, strict=True)]},
        "provenance": table.provenance,
    }


def _fmt_level(v: float | None) -> str:
    return "inf" if v is None else f"{v:.4g}"


#: What the per-class list of :func:`format_summary` shows.
CLASS_LISTS = ("none", "trained", "all")


def format_summary(summary: dict[str, Any], *, table: TransformTable | None = None,
                   classes: str | bool = "none", provenance: bool = True) -> str:
    """Text form of :func:`table_summary`.

    Parameters
    ----------
    summary
        From :func:`table_summary`.
    table
        The table (needed for a class list).
    classes
        Per-class list (samples, λ per output, status, fallback source):
        ``"none"``, ``"trained"`` (classes with a kernel of their own: trained
        or filled by smoothing) or ``"all"`` (``True`` = ``"all"``).
    provenance
        Append the provenance.
    """
    if classes is True:
        classes = "all"
    elif classes is False:
        classes = "none"
    if classes not in CLASS_LISTS:
        raise ConfigError(f"class list {classes!r} is not known; use {', '.join(CLASS_LISTS)}")
    s = summary
    lay = s["layout"]
    out = [f"{s['name']}: {s['format']} v{s['version']}, output {s['output_space']} "
           f"({s['n_out']} channels)",
           f"CFA {s['cfa']['spec']} (period {s['cfa']['period'][0]}x{s['cfa']['period'][1]}, "
           f"channels {' '.join(s['cfa']['channels'])}), patch {s['patch']}x{s['patch']} "
           f"({lay['coefficients']} coefficients per output)",
           f"features: {', '.join(s.get('features') or []) or 'none beyond the classes'}",
           f"classes: {lay['classes']} = {len(lay['groups'])} position groups x "
           f"{lay['saturation_patterns']} saturation patterns x {lay['levels']} levels x "
           f"{lay['contrast_bins']} contrast bins"
           + (f" x {lay['orientation_bins']} orientation x {lay['context_bins']} context x "
              f"{lay['highlight_bins']} highlight bins" if "texture_bins" in lay else ""),
           "position groups (CFA colour at row, column of the repeat): "
           + "; ".join(f"{i}: {g}" for i, g in enumerate(lay.get("group_names", lay["groups"]))),
           f"saturation threshold {lay['saturation_threshold']:g} ({lay['saturation_rule']}), "
           f"contrast rule {lay['contrast_rule']}",
           f"classes trained {s['classes']['trained']}, filled by smoothing "
           f"{s['classes']['filled']}, empty {s['classes']['empty']}; "
           f"samples {s['samples']}",
           ]
    if s["lambda"]:
        lam = s["lambda"]
        out.append(f"ridge lambda: min {lam['min']:.3g}, median {lam['median']:.3g}, "
                   f"max {lam['max']:.3g}")
    if s.get("tone_curve"):
        out.append(f"output: the kernels render the renders' learned tone-curve space, mapped "
                   f"back by a {s['tone_curve']}-entry look-up table per channel")
    if s.get("multiscale"):
        ms = s["multiscale"]
        out.append(f"multiscale stage (--multiscale): bands of Gaussian low-passes sigma "
                   f"{', '.join(f'{v:g}' for v in ms['sigmas'])} px blended per "
                   f"{ms['classes']} coarse classes ({ms['levels']} levels x band energy), "
                   f"coding {ms['transfer']}")
    if s.get("shading"):
        sh = s["shading"]
        if "intervals" in sh:  # a spline grid (l3cli.lens.grid)
            out.append(f"input: lens shading corrected first (gain field learned on "
                       f"{sh['size'][1]}x{sh['size'][0]} raws, spline grid of "
                       f"{sh['intervals'][0]}x{sh['intervals'][1]} intervals; largest corner "
                       f"gain / centre per CFA position "
                       f"{', '.join(f'{g:.3f}' for g in sh['max_corner_gain'])})")
        else:
            out.append(f"input: lens shading corrected first (gain field learned on "
                       f"{sh['size'][1]}x{sh['size'][0]} raws, centre {sh['centre'][0]:+.3f}, "
                       f"{sh['centre'][1]:+.3f}; gain at r=1 / centre per CFA position "
                       f"{', '.join(f'{g:.3f}' for g in sh['gain_at_r1'])})")
    if s.get("white_balance"):
        out.append("input: white-balanced by each raw's as-shot white balance, output adapted "
                   "to its white")
    if s.get("conditions"):
        cond = s["conditions"]
        from l3cli.conditions import LABELS

        out.append(f"condition bins (--by {cond['by']}, {LABELS[cond['by']]}; render "
                   "interpolates between neighbours in log value, classes neither trained nor "
                   "filled use the pooled kernel):")
        for b in cond["bins"]:
            out.append(f"  {cond['by']} {b['value']:g}: {b['samples']} samples, "
                       f"{b['trained_classes']} classes trained, "
                       f"{b.get('filled_classes', 0)} filled from neighbouring bins")
    out.append("")
    out.append(f"levels ({lay['level_spacing']} spacing):")
    out.append(f"  {'bin':>3}  {'from':>9}  {'to':>9}  {'samples':>10}  {'unsat':>10}  "
               f"{'trained':>7}  contrast cuts")
    for lv in s["levels"]:
        cc = ", ".join(f"{v:.3g}" for v in lv["contrast_cuts"]) or "-"
        out.append(f"  {lv['level']:>3}  {_fmt_level(lv['from']):>9}  {_fmt_level(lv['to']):>9}  "
                   f"{lv['samples']:>10}  {lv['samples_unsaturated']:>10}  "
                   f"{lv['trained_classes']:>7}  {cc}")
    out.append("")
    out.append("empty classes (by saturated channels):" if s["empty"] else "empty classes: none")
    for sat, idx in s["empty"].items():
        out.append(f"  {'none saturated' if sat == '-' else sat}: {len(idx)} "
                   f"[{compress_ranges(idx)}]")
    if s["smoothing"]:
        sm = s["smoothing"]
        out.append("")
        out.append(f"smoothing: priors {', '.join(sm.get('priors', [])) or 'none'}")
        for prior in ("symmetry", "spline", "uniformity"):
            if prior in sm:
                out += plain_lines(prior, sm[prior])
        if s["filled"]:
            out.append("filled classes (by prior):")
            for prior, idx in s["filled"].items():
                out.append(f"  {prior}: {len(idx)} [{compress_ranges(idx)}]")
        else:
            out.append("filled classes: none")
    else:
        out.append("")
        out.append("smoothing: not smoothed")
    tuned = s["provenance"].get("tune")
    if tuned:
        from l3cli.train.tune import format_candidates

        ch = tuned["chosen"]
        out.append("")
        out.append(f"tuned by cross-validation ({len(tuned['folds'])} folds, "
                   f"{tuned['metric']}): chose {ch['target']}, patch {ch['patch']}, "
                   f"{ch['levels']} levels, {ch['contrast_bins']} contrast bins, threshold "
                   f"{ch.get('contrast_threshold') or 'quantile'}, shading "
                   f"{'on' if ch.get('shading') else 'off'}, multi-scale "
                   f"{'on' if ch.get('multiscale') else 'off'} (CV {ch['cv_mean']:.4f})")
        out.append(format_candidates(tuned))
    if classes != "none":
        if table is None:
            raise ConfigError("a class list needs the table")
        out.append("")
        out.append("classes with their own kernel:" if classes == "trained" else "all classes:")
        out.append(f"  {'class':>5} {'grp':>3} {'sat':>7} {'lev':>3} {'con':>3} {'samples':>9}  "
                   f"{'status':<16} {'src':>5}  lambda")
        for r in class_rows(table):
            if classes == "trained" and r["status"] == "empty":
                continue
            lam = " ".join("-" if v is None else f"{v:.3g}" for v in r["lambda"])
            out.append(f"  {r['class']:>5} {r['group']:>3} {r['saturation']:>7} {r['level']:>3} "
                       f"{r['contrast']:>3} {r['samples']:>9}  {r['status']:<16} "
                       f"{r['source']:>5}  {lam}")
    if provenance:
        prov = {k: v for k, v in s["provenance"].items() if k not in ("smoothing", "tune")}
        out.append("")
        out.append("provenance:")
        for k in sorted(prov):
            out += plain_lines(k, prov[k])
    return "\n".join(out)
