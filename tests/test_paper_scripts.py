"""Tests of the `make paper` helpers in scripts/paper/ (issue 9): the derived
camera files load with l3's own camera reader and say what they claim, and the
diffraction bound matches the Airy MTF of a single wavelength in the middle of
the visible."""

from __future__ import annotations

import importlib.util
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scripts" / "paper"


def _module(name: str):
    sys.path.insert(0, str(PAPER))
    try:
        spec = importlib.util.spec_from_file_location(f"paper_{name}", PAPER / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(str(PAPER))


@pytest.mark.parametrize("name", ["rgbw", "rgbw-ircut", "bayer", "rgbnir", "rgbnir-black",
                                  "rgbnir-g", "mtf-f8-p2.4"])
def test_cameras_load(tmp_path, name):
    from l3cli.camera import load_camera

    cams = _module("cameras")
    out = tmp_path / f"{name}.toml"
    cams.main([name, str(out)])
    cfg = tomllib.loads(out.read_text())
    assert cfg["name"] == name
    cam = load_camera(out.resolve())
    assert cam.name == name


def test_camera_variants_say_what_they_claim(tmp_path):
    from l3cli.camera import load_camera

    cams = _module("cameras")
    for name in ("rgbw", "bayer", "rgbnir-black", "mtf-f8-p2.4"):
        cams.main([name, str(tmp_path / f"{name}.toml")])
    # the paper's comparison: the RGBW camera with W -> G is an RGGB Bayer,
    # everything else (pixel, optics, filters, exposure) unchanged
    rgbw = tomllib.loads((tmp_path / "rgbw.toml").read_text())
    g = tomllib.loads((tmp_path / "bayer.toml").read_text())
    assert load_camera((tmp_path / "bayer.toml").resolve()).cfa.cfa.spec == "RG/GB"
    for sec in ("optics", "pixel", "readout", "exposure"):
        assert g[sec] == rgbw[sec]
    assert {k: v for k, v in g["cfa"].items() if k != "pattern"} == \
        {k: v for k, v in rgbw["cfa"].items() if k != "pattern"}
    black = load_camera((tmp_path / "rgbnir-black.toml").resolve())
    qe = np.asarray(black.qe_curves())
    nir = black.cfa.cfa.channels.index("NIR")
    others = [i for i in range(qe.shape[1]) if i != nir]
    assert np.all(qe[:, nir] == 0) and np.all(qe[:, others].max(axis=0) > 0.1)
    m = tomllib.loads((tmp_path / "mtf-f8-p2.4.toml").read_text())
    assert m["optics"]["f_number"] == 8.0 and m["pixel"]["pitch_um"] == 2.4


def test_diffraction_bound_between_monochrome_values():
    mtf = _module("mtf")
    # Airy MTF = 0.5 at nu / nu_c = 0.4040 (Goodman 2005), nu_c = 1 / (lambda N)
    mono = {lam: 0.40397 / (lam * 1e-6 * 4.0) for lam in (520.0, 580.0)}
    poly = mtf.diffraction_mtf50(4.0)
    assert mono[580.0] < poly < mono[520.0]
    # a pixel aperture can only lower it
    assert mtf.diffraction_mtf50(4.0, pitch_um=1.4) < poly
