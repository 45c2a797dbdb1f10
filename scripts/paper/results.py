#!/usr/bin/env python3
"""Assemble docs/results.md from the experiment sections (``make paper``).

``results.py BUILD OUT.md`` reads ``BUILD/sections/*.md`` and the numbers in
``BUILD/*.json`` written by the experiment modules of scripts/paper/, and
writes OUT.md: a summary table of every published number beside ours, then
one section per experiment.
"""

from __future__ import annotations

import datetime
import json
import os
import sys
from pathlib import Path

from common import ROOT

ORDER = ("real", "rgbw", "rgbnir", "levels", "patch", "mtf", "kernels")


def _j(build: Path, name: str) -> dict:
    p = build / f"{name}.json"
    return json.loads(p.read_text()) if p.exists() else {}


def _f(v, nd: int = 2) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def _levels(build: Path) -> str:
    """Training and test light levels and exposure, from the RGBW manifests."""
    out = []
    for part in ("train", "test"):
        p = build / "sim" / "rgbw" / part / "manifest.json"
        if not p.exists():
            return "see the Makefile's PAPER_TRAIN_LUX and PAPER_TEST_LUX"
        caps = json.loads(p.read_text())["captures"]
        lux = sorted({c["lux"] for c in caps})
        out.append(f"{part}: {', '.join(f'{x:g}' for x in lux)} lux")
    times = sorted({c["exposure_s"] for c in caps})
    gains = sorted({c.get("analog_gain", 1.0) for c in caps})
    if len(times) > 1:
        gain_txt = f", then analog gain up to {gains[-1]:.2g}x" if gains[-1] > 1 else ""
        txt = "; ".join(out) + (f"; each camera's own auto exposure ({times[0] * 1000:.0f}–{times[-1] * 1000:.0f} ms"
                                f"{gain_txt} for the RGBW camera's test captures)")
    else:
        txt = "; ".join(out) + f"; fixed {times[0] * 1000:g} ms exposure"
    p = build / "sim" / "rgbnir" / "test" / "manifest.json"
    if p.exists():
        e2 = sorted({c["exposure_s"] for c in json.loads(p.read_text())["captures"]})
        if len(e2) == 1 and e2 != times:
            txt += (f"; a fixed {e2[0] * 1000:g} ms for the RGB-NIR cameras, so that their light level"
                    " sets the response level")
    return txt


def _chart_note(build: Path) -> str:
    """How much the chart in training helps, from experiment 2's chart-held-out runs."""
    rgbw = _j(build, "rgbw")
    if not rgbw or "rgbw-nochart" not in rgbw.get("mean_lit_levels", {}):
        return " somewhat"
    ml = rgbw["mean_lit_levels"]
    return (f" (experiment 2, mean at the well-exposed levels: RGBW {ml['rgbw']:.2f} with the chart in "
            f"training, {ml['rgbw-nochart']:.2f} without; Bayer {ml['bayer']:.2f} vs {ml['bayer-nochart']:.2f})")


def summary(build: Path) -> str:
    real, rgbw, nir, mtf = (_j(build, n) for n in ("real", "rgbw", "rgbnir", "mtf"))
    lev, pat, ker = (_j(build, n) for n in ("levels", "patch", "kernels"))
    rows = []
    if real:
        rows += [("1", "real pipeline, S-CIELAB ΔE (held out)", "1.74 (Nikon D200)",
                  f"{_f(real.get('infinite_isp_scielab'))} (Infinite-ISP)",
                  "another camera and ISP (Infinite-ISP, 8-bit raws, 3 training frames) than the paper's Nikon D200"),
                 ("1", "real pipeline, PSNR dB", "40.4 (Nikon D200)", f"{_f(real.get('infinite_isp_psnr'))} (Infinite-ISP)",
                  "8-bit raws; the ISP's spatially varying steps (denoising, sharpening), which one kernel per class only averages"),
                 ("1", "raw converter, S-CIELAB ΔE", "1.46 (DxO)", f"{_f(real.get('blackmagic_scielab'))} (LibRaw AHD)",
                  'one Blackmagic frame through LibRaw AHD (close to linear) vs DxO on many Nikon images')]
    if rgbw:
        m, ml = rgbw["mean"], rgbw["mean_lit_levels"]
        lit = f"{rgbw['lit_levels'][0]:g}–{rgbw['lit_levels'][-1]:g} lux"
        fl, fl3 = rgbw["linear_colour_floor"], rgbw["linear_colour_floor_3_pieces"]
        gain = rgbw.get("analog_gain", {}).get("bayer", {})
        g_txt = f"gain {max(gain.values()):.2g}x" if gain else "under-exposed"
        rows += [("2", "2x2 RGBW, Macbeth mean ΔE (auto exposure, then auto gain)", "1.70",
                  f"{_f(m['rgbw'])} all levels; {_f(ml['rgbw'])} at {lit}",
                  '5 training scenes, 4 of them RGB photos with synthetic spectra (their NIR a linear function of RGB); '
                  'the chart in training at other levels; W and R see the NIR'),
                 ("2", "RGBW with W→G (Bayer), Macbeth mean ΔE", "1.65",
                  f"{_f(m['bayer'])} all levels; {_f(ml['bayer'])} at {lit}",
                  f"same scenes; sensor far from the Luther condition (one-map floor {fl['bayer']:.2f}); "
                  f"noise at 20 lux ({g_txt})"),
                 ("2", "RGBW / Bayer ratio of the means", "1.03", f"{rgbw['bar']['ratio']:.2f}",
                  'RGBW better at every level: four channels fit XYZ better than three, and W gathers more light'
                  if all(rgbw["macbeth_de"]["rgbw"][k] < rgbw["macbeth_de"]["bayer"][k] for k in rgbw["macbeth_de"]["rgbw"])
                  else 'RGBW better where auto exposure reaches its target'),
                 ("2", "same, trained in CIELAB (`--target lab`), RGBW / Bayer", "–",
                  f"{_f(m['rgbw-lab'])} / {_f(m['bayer-lab'])}"),
                 ("2", "same, chart not in training, RGBW / Bayer", "–",
                  f"{_f(m['rgbw-nochart'])} / {_f(m['bayer-nochart'])} all levels; "
                  f"{_f(ml['rgbw-nochart'])} / {_f(ml['bayer-nochart'])} at {lit}"),
                 ("2", "one linear map, noise-free (not a bound on L3), RGBW / Bayer", "–",
                  f"{_f(fl['rgbw'])} / {_f(fl['bayer'])} (3 maps by level, in sample: "
                  f"{_f(fl3['rgbw'])} / {_f(fl3['bayer'])})"),
                 ("2", "RGBW behind an IR-cut filter, Macbeth mean ΔE", "–",
                  f"{_f(m['rgbw-ircut'])} all levels; {_f(ml['rgbw-ircut'])} at {lit}"),
                 ("2", "Bayer: L3 vs demosaic + matrix, Macbeth mean ΔE", "L3 better",
                  f"{_f(m['bayer'])} vs {_f(m['bayer-baseline'])}",
                  "agrees" if m["bayer"] < m["bayer-baseline"] else "our L3 is not better on average (exp. 2)")]
    if nir:
        med = nir["median_pooled"]
        rows += [("3", "median ΔE RGB-NIR / NIR black / NIR→G", "2.87 / 3.08 / 2.69",
                  f"{_f(med['rgbnir'])} / {_f(med['rgbnir-black'])} / {_f(med['rgbnir-g'])}",
                  'paper: one light level; ours pooled over 5 levels including 20 lux; our NIR filter has no visible response')]
    if lev:
        n0, n1 = str(lev["levels"][0]), str(lev["levels"][-1])
        rows += [("4", f"ΔE log vs linear levels, {n0} and {n1} levels", "log better with few; same beyond 12–15",
                  f"{n0}: {_f(lev['mean']['log'][n0])} vs {_f(lev['mean']['linear'][n0])}; "
                  f"{n1}: {_f(lev['mean']['log'][n1])} vs {_f(lev['mean']['linear'][n1])}",
                  'our 6 sparse training levels: the dark test level decides (exp. 4)'
                  if lev.get('dark_level_decides', True) else
                  'linear spacing puts more bins where auto exposure keeps the chart (exp. 4)')]
    if pat:
        rows += [("5", "Macbeth ΔE, patch 5 / 7 / 9", "little gain beyond 5x5",
                  " / ".join(_f(pat[p]["de_mean"]) for p in ("5", "7", "9")),
                  'agrees' if max(pat[p]["de_mean"] for p in ("5", "7", "9")) - min(pat[p]["de_mean"] for p in ("5", "7", "9")) < 0.3
                  else 'our Macbeth ΔE depends on the patch size more than published (exp. 5)')]
    if mtf:
        lux = mtf["l3_per_lux"]
        rows += [("6", "RGBW MTF50 f/4 1.4 µm, cy/mm", "154.8",
                  f"{min(lux.values()):.1f}–{max(lux.values()):.1f} over light levels",
                  'agrees; auto exposure leaves most test edges at the same response'),
                 ("6", "diffraction bound, cy/mm", "186.7", _f(mtf["diffraction_f4"], 1),
                  'Airy OTF averaged over the visible vs one wavelength (~541 nm)')]
    if ker:
        sh = {k: v["channel_share"]["W"] for k, v in ker["classes"].items()}
        rows += [("7", "W share of RGBW kernel weights (Y)", "moves from W to RGB as W saturates",
                  ", ".join(f"{k} {v:.2f}" for k, v in sh.items()),
                  'our W has no IR-cut filter: its NIR signal predicts XYZ poorly')]
        if "classes_ircut" in ker:
            sh2 = {k: v["channel_share"]["W"] for k, v in ker["classes_ircut"].items()}
            rows += [("7", "same, RGBW behind an IR-cut filter", "",
                      ", ".join(f"{k} {v:.2f}" for k, v in sh2.items()))]
    lines = ["| exp. | quantity | published | l3 | why they differ |", "|---|---|---|---|---|"]
    lines += [f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4] if len(r) > 4 else ''} |" for r in rows]
    return "\n".join(lines)


def main(build: Path, out: Path) -> None:
    from l3cli import __version__
    from l3cli.io.atomic import atomic_path

    parts = [f"""# Results: the L3 paper's experiments, re-run with l3

Generated by `make paper` (scripts/paper/, one module per experiment; each
experiment is also its own target: `make paper-real paper-rgbw paper-rgbnir
paper-levels paper-patch paper-mtf paper-kernels`). Do not edit by hand:
change the scripts and re-run. Build files land in `{build.name}/`.
l3 {__version__}, {datetime.date.today().isoformat()}, {os.cpu_count()} CPU cores.

Published values are from Jiang, Tian, Farrell & Wandell, "Learning the
image processing pipeline", IEEE Trans. Image Processing 26(10), 2017. Our
numbers come from l3's own simulator (`l3 simulate`, ISETCam-like but not
ISETCam), the small bundled scene set (the Macbeth chart and four natural
photos at 320x240 pixels) and the bundled real data, so they agree with the
paper in trend more than in value; each section says why they differ and
where l3 falls short.

All simulated tests use captures at light levels not used in training
({_levels(build)}). The Macbeth chart is in both the training
and the test scenes (different light levels and noise), as in the train/render
issue's end-to-end test; this favours Macbeth ΔE{_chart_note(build)}.

## Summary

{summary(build)}
"""]
    for name in ORDER:
        p = build / "sections" / f"{name}.md"
        if p.exists():
            parts.append(p.read_text(encoding="utf-8"))
        else:
            parts.append(f"## {name}\n\nNot run (`make paper-{name}`).\n")
    text = "\n".join(parts)
    with atomic_path(out) as tmp:
        tmp.write_text(text, encoding="utf-8")
    print(f"wrote {out.relative_to(ROOT) if out.is_absolute() and ROOT in out.parents else out}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]))
