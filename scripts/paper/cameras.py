#!/usr/bin/env python3
"""Camera TOML files of the paper experiments, derived from sample_configs/.

``cameras.py NAME OUT.toml`` writes one camera:

``rgbw``
    sample_configs/rgbw.toml as it is (the L3 RGBW camera: 1.4 µm, f/4, one
    R, G, B and W in each 2x2 repeat, ISETCam interleaved RGBW filters, no
    IR-cut filter).
``bayer``
    the same camera with its W pixel replaced by a G pixel: an RGGB Bayer
    mosaic with the same pixel, optics and R, G, B filters (the paper's
    comparison camera, and one that ``l3 baseline``, a Bayer-only
    conventional pipeline, can render).
``rgbw-ircut``
    the RGBW camera behind an IR-cut filter (ISETCam ``ircf_public``), so that
    W sees only the visible.
``rgbnir``
    sample_configs/rgbnir.toml as it is (R G / NIR B, IR-blocked R, G, B).
``rgbnir-black``
    the NIR pixel blacked out: its quantum efficiency is zero at every
    wavelength (a QE CSV written next to OUT.toml), so it records only
    dark current and noise.
``rgbnir-g``
    the NIR pixel replaced by G (an RGGB Bayer camera with the same filters).
``mtf-fF-pP``
    the RGBW camera with f-number F and pixel pitch P µm (e.g. ``mtf-f4-p1.4``);
    the electrical parameters (full well, noise) stay those of the 1.4 µm
    pixel so that only optics and sampling change over the grid.
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_configs"
SPECTRAL = ROOT / "l3cli" / "data" / "spectral"


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def dumps(cfg: dict) -> str:
    """TOML text of a two-level camera dict (top-level scalars, then tables)."""
    lines = [f"{k} = {_value(v)}" for k, v in cfg.items() if not isinstance(v, dict)]
    for k, v in cfg.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]"] + [f"{kk} = {_value(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


def _load(name: str) -> dict:
    with open(SAMPLES / f"{name}.toml", "rb") as f:
        return tomllib.load(f)


def camera(name: str, out: Path) -> dict:
    """The camera dict for ``name`` (may write a QE CSV next to ``out``)."""
    if name in ("rgbw", "rgbnir"):
        cfg = _load(name)
    elif name == "bayer":
        cfg = _load("rgbw")
        cfg["cfa"]["pattern"] = [["G" if c == "W" else c for c in row] for row in cfg["cfa"]["pattern"]]
        cfg["description"] = "L3 RGBW camera with W replaced by G (an RGGB Bayer)"
    elif name == "rgbw-ircut":
        cfg = _load("rgbw")
        cfg["cfa"]["ir_cut"] = "ircf-public"
        cfg["description"] = "L3 RGBW camera behind an IR-cut filter"
    elif name == "rgbnir-g":
        cfg = _load("rgbnir")
        cfg["cfa"]["pattern"] = [["R", "G"], ["G", "B"]]
        cfg["description"] = "RGB-NIR camera with the NIR pixel replaced by G"
    elif name == "rgbnir-black":
        cfg = _load("rgbnir")
        lines = (SPECTRAL / "qe_rgb_nir.csv").read_text().splitlines()
        body = [ln for ln in lines if ln and not ln.startswith("#")]
        head = body[0].split(",")
        nir = head.index("NIR")
        rows = []
        for ln in body[1:]:
            vals = ln.split(",")
            vals[nir] = "0"
            rows.append(",".join(vals))
        csv = out.parent / f"{out.stem}_qe.csv"
        csv.write_text("# ISETCam cfaRGBNearIR (l3 preset rgb-nir) with the NIR column set to 0\n"
                       + "\n".join([body[0]] + rows) + "\n")
        cfg["cfa"]["qe"] = csv.name
        cfg["description"] = "RGB-NIR camera with the NIR pixel blacked out (zero QE)"
    else:
        m = re.fullmatch(r"mtf-f([0-9.]+)-p([0-9.]+)", name)
        if not m:
            raise SystemExit(f"unknown camera {name!r}; see scripts/paper/cameras.py --help")
        cfg = _load("rgbw")
        cfg["optics"]["f_number"] = float(m.group(1))
        cfg["pixel"]["pitch_um"] = float(m.group(2))
        cfg["description"] = f"L3 RGBW camera at f/{m.group(1)} with {m.group(2)} um pixels"
    cfg["name"] = name
    return cfg


def main(argv: list[str]) -> None:
    if len(argv) != 2 or argv[0] in ("-h", "--help"):
        raise SystemExit(__doc__)
    out = Path(argv[1])
    out.parent.mkdir(parents=True, exist_ok=True)
    text = dumps(camera(argv[0], out))
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(out)


if __name__ == "__main__":
    main(sys.argv[1:])
