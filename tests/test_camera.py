"""Camera TOML loader: sample configs, validation errors naming file, key and what is allowed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from l3cli.camera import load_camera
from l3cli.errors import ConfigError, InputError
from tests.builders import MINIMAL

REPO = Path(__file__).resolve().parents[1]
SAMPLES = sorted((REPO / "sample_configs").glob("*.toml"))



def write(tmp_path: Path, text: str, name: str = "cam.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("path", SAMPLES, ids=[p.stem for p in SAMPLES])
def test_sample_configs_load(path: Path) -> None:
    cam = load_camera(path)
    d = cam.to_dict()
    json.dumps(d)  # JSON-able for the manifest
    assert d["file"] == path.name
    qe = cam.qe_curves()
    assert qe.shape == (cam.wavelengths.size, cam.cfa.cfa.n_channels)
    assert np.all(qe >= 0) and np.all(qe.max(axis=0) > 0)


def test_required_samples_exist() -> None:
    names = {p.stem for p in SAMPLES}
    assert {"bayer", "rgbw", "rgbnir", "nikon-d200-like"} <= names


def test_rgbw_is_the_l3_camera() -> None:
    cam = load_camera(REPO / "sample_configs" / "rgbw.toml")
    assert cam.pixel.pitch_um == 1.4 and cam.optics.f_number == 4.0
    assert set(cam.cfa.cfa.channels) == {"R", "G", "B", "W"}
    # Jiang et al. 2017: "exactly one R, G, B and W in each CFA repeating
    # pattern"; replacing W with G gives a Bayer pattern.
    cfa = cam.cfa.cfa
    assert cfa.period == (2, 2)
    names = sorted(cfa.channels[i] for i in np.asarray(cfa.index_pattern).ravel())
    assert names == ["B", "G", "R", "W"]
    bayer = [[("G" if cfa.channels[i] == "W" else cfa.channels[i]) for i in row]
             for row in np.asarray(cfa.index_pattern)]
    assert "".join(bayer[0] + bayer[1]) in ("RGGB", "BGGR", "GRBG", "GBRG")


def test_rgbw_4x4_keeps_the_interleaved_layout() -> None:
    cam = load_camera(REPO / "sample_configs" / "rgbw-4x4.toml")
    ref = load_camera(REPO / "sample_configs" / "rgbw.toml")
    cfa = cam.cfa.cfa
    assert cfa.period == (4, 4)
    counts = {c: int((np.asarray(cfa.index_pattern) == i).sum()) for i, c in enumerate(cfa.channels)}
    assert counts == {"W": 8, "G": 4, "R": 2, "B": 2}
    assert cam.pixel == ref.pixel and cam.optics == ref.optics


def test_rgbnir_reaches_nir() -> None:
    cam = load_camera(REPO / "sample_configs" / "rgbnir.toml")
    assert cam.wavelengths[-1] >= 1000
    qe = cam.qe_curves()
    ch = cam.cfa.cfa.channels
    nir = qe[:, ch.index("NIR")]
    wl = cam.wavelengths
    # NIR pixel: mostly beyond 700 nm; R, G, B: IR-blocked.
    assert nir[wl > 750].sum() > 5 * nir[wl < 650].sum()
    for c in ("R", "G", "B"):
        q = qe[:, ch.index(c)]
        assert q[wl > 800].sum() < 0.02 * q.sum()
    assert cam.cfa.cfa.period == (2, 2)


def test_minimal_defaults(tmp_path: Path) -> None:
    cam = load_camera(write(tmp_path, MINIMAL))
    assert cam.pixel.full_well_e == pytest.approx(10000.0)
    assert cam.optics.f_number == 4.0
    assert cam.exposure.mode == "auto" and cam.exposure.illuminant == "D65"
    assert cam.wavelengths[0] == 380 and cam.wavelengths[-1] == 730  # the QE's visible range
    assert cam.readout.white_level_dn == 1023
    import dataclasses

    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.pixel.pitch_um = 3.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "patch, key, allowed",
    [
        ("[optics]\nf_numbr = 2.0\n", "optics.f_numbr", "f_number"),
        ("[optics]\nf_number = 0.1\n", "optics.f_number", "[0.5, 64]"),
        ("[optics]\nf_number = \"4\"\n", "optics.f_number", "must be a number"),
        ("[optics]\ncos4 = 1\n", "optics.cos4", "true or false"),
        ("[readout]\nbit_depth = 20\n", "readout.bit_depth", "[8, 16]"),
        ("[readout]\nbit_depth = 10.5\n", "readout.bit_depth", "integer"),
        ("[exposure]\nmode = \"manual\"\n", "exposure.mode", "auto, fixed"),
        ("[exposure]\nilluminant = \"D66\"\n", "exposure.illuminant", "D65"),
        ("[exposure]\nlight_levels_lux = [100, 0]\n", "exposure.light_levels_lux", "(0, 1e6]"),
        ("[spectrum]\nwavelength_nm = [400, 700, 7]\n", "spectrum.wavelength_nm", "divide"),
        ("colour = 1\n", "colour", "keys allowed"),
    ],
)
def test_bad_values_name_file_key_and_allowed(tmp_path: Path, patch: str, key: str, allowed: str) -> None:
    # Put the top-level key before the first table.
    text = patch + MINIMAL if not patch.startswith("[") else MINIMAL + patch
    p = write(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load_camera(p)
    msg = str(e.value)
    assert str(p) in msg and key in msg and allowed in msg
    assert "\n" not in msg


def test_pixel_needs_two_of_three(tmp_path: Path) -> None:
    text = MINIMAL.replace("voltage_swing_v = 1.0\n", "")
    with pytest.raises(ConfigError, match="give two of"):
        load_camera(write(tmp_path, text))
    text = MINIMAL.replace("voltage_swing_v = 1.0\n", "voltage_swing_v = 1.0\nfull_well_e = 5000\n")
    with pytest.raises(ConfigError, match="pixel.full_well_e.*inconsistent"):
        load_camera(write(tmp_path, text))


def test_toml_syntax_error_names_line(tmp_path: Path) -> None:
    p = write(tmp_path, MINIMAL + "[optics\nf_number = 2\n")
    with pytest.raises(ConfigError) as e:
        load_camera(p)
    assert str(p) in str(e.value) and "line 10" in str(e.value)


def test_missing_file() -> None:
    with pytest.raises(InputError, match="no such camera file"):
        load_camera("/nonexistent/cam.toml")


def test_unknown_qe_preset_lists_valid(tmp_path: Path) -> None:
    p = write(tmp_path, MINIMAL.replace('"bayer-rgb"', '"bayr"'))
    with pytest.raises(ConfigError) as e:
        load_camera(p)
    msg = str(e.value)
    assert "cfa.qe" in msg and "bayer-rgb" in msg and "interleaved-rgbw" in msg


def test_unknown_ir_filter_lists_valid(tmp_path: Path) -> None:
    p = write(tmp_path, MINIMAL + 'ir_cut = "hotmirror"\n')
    with pytest.raises(ConfigError, match="cfa.ir_cut.*ircf-public"):
        load_camera(p)


def test_channel_without_qe_column(tmp_path: Path) -> None:
    p = write(tmp_path, MINIMAL.replace('"RGGB"', '[["R", "G"], ["NIR", "B"]]'))
    with pytest.raises(ConfigError, match="no QE column 'NIR'.*R, G, B"):
        load_camera(p)


def _qe_csv(tmp_path: Path, rows: list[tuple[float, float, float, float]]) -> Path:
    lines = ["# test QE", "wavelength_nm,R,G,B"] + [",".join(f"{v:g}" for v in r) for r in rows]
    p = tmp_path / "qe.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_user_qe_csv(tmp_path: Path) -> None:
    wl = np.arange(380, 731, 10)
    _qe_csv(tmp_path, [(w, 0.3, 0.4, 0.5) for w in wl])
    cam = load_camera(write(tmp_path, MINIMAL.replace('"bayer-rgb"', '"qe.csv"')))
    np.testing.assert_allclose(cam.qe_curves()[:, 2], 0.5)


@pytest.mark.parametrize(
    "rows, match",
    [
        ([(400, 0.1, 0.1, 0.1), (420, 0.1, 0.1, 0.1), (410, 0.1, 0.1, 0.1)], "strictly increasing"),
        ([(w, 0.1, -0.2 if w == 500 else 0.1, 0.1) for w in range(380, 731, 10)], "non-negative"),
        ([(w, 0.1, 0.1, 0.1) for w in range(450, 651, 10)], "covers 450-650 nm.*400-700 nm"),
    ],
    ids=["non-monotonic", "negative", "range-not-covered"],
)
def test_bad_qe_csv(tmp_path: Path, rows, match: str) -> None:
    _qe_csv(tmp_path, rows)
    p = write(tmp_path, MINIMAL.replace('"bayer-rgb"', '"qe.csv"') + "[spectrum]\nwavelength_nm = [400, 700, 10]\n")
    with pytest.raises(ConfigError, match=match) as e:
        load_camera(p)
    assert "qe.csv" in str(e.value)


def test_qe_csv_non_numeric(tmp_path: Path) -> None:
    (tmp_path / "qe.csv").write_text("wavelength_nm,R,G,B\n400,0.1,x,0.1\n500,0.1,0.1,0.1\n")
    with pytest.raises(ConfigError, match="non-numeric"):
        load_camera(write(tmp_path, MINIMAL.replace('"bayer-rgb"', '"qe.csv"')))


def test_light_level_range(tmp_path: Path) -> None:
    cam = load_camera(write(tmp_path, MINIMAL + "[exposure]\nlight_level_range_lux = [1, 1000]\nlight_level_count = 4\n"))
    np.testing.assert_allclose(cam.exposure.light_levels_lux, [1, 10, 100, 1000])
    with pytest.raises(ConfigError, match="exposure.light_level_count.*missing"):
        load_camera(write(tmp_path, MINIMAL + "[exposure]\nlight_level_range_lux = [1, 1000]\n"))
    with pytest.raises(ConfigError, match="exposure.light_levels_lux.*cannot be combined"):
        load_camera(write(tmp_path, MINIMAL + "[exposure]\nlight_level_range_lux = [1, 10]\n"
                          "light_level_count = 2\nlight_levels_lux = [5]\n"))


def test_channel_mapping(tmp_path: Path) -> None:
    text = MINIMAL.replace('pattern = "RGGB"\nqe = "bayer-rgb"',
                           'pattern = [["R", "C"], ["C", "B"]]\nqe = "mt9v024-rgbw"\nchannels = { C = "W" }')
    cam = load_camera(write(tmp_path, text + "[spectrum]\nwavelength_nm = [400, 1000, 10]\n"))
    assert dict(cam.cfa.channel_columns) == {"R": "R", "C": "W", "B": "B"}
    qe = cam.qe_curves()
    assert qe.shape == (61, 3)
    bad = text.replace('{ C = "W" }', '{ G = "W" }')
    with pytest.raises(ConfigError, match="cfa.channels.G.*not a channel"):
        load_camera(write(tmp_path, bad))


@pytest.mark.parametrize("qe, ir_cut, reaches_nir", [
    ("interleaved-rgbw", "none", True),     # W responds far into the NIR
    ("nikon-d200-ir", "none", True),        # no IR-cut: R, G, B leak beyond 700 nm
    ("nikon-d200-ir", "ircf-public", False),  # behind the IR-cut filter: visible only
    ("bayer-rgb", "none", False),           # data end at 730 nm
])
def test_default_grid_reaches_1000nm_when_a_channel_responds(tmp_path: Path, qe, ir_cut,
                                                              reaches_nir) -> None:
    pattern = '[["R", "G"], ["W", "B"]]' if qe == "interleaved-rgbw" else '"RGGB"'
    text = MINIMAL.replace('"bayer-rgb"', f'"{qe}"').replace('"RGGB"', pattern)
    cam = load_camera(write(tmp_path, text + f'ir_cut = "{ir_cut}"\n'))
    wl = cam.wavelengths
    assert (wl[-1] >= 1000) == reaches_nir
    if not reaches_nir:
        assert wl[-1] <= 780
