"""White balance on simulated data (issue 15, part 1): per-shot illuminants, a converter-like reference.

The experiment of ``scripts/wb_experiment.py`` at a small size: scenes under
several illuminants rendered by a reference converter that white-balances
each capture and adapts its colour matrix to the white (Bradford, via
colour-science); learned with and without the white-balance handling on some
captures and scored (S-CIELAB) on others, against a fixed-illuminant control.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _experiment():
    spec = importlib.util.spec_from_file_location("wb_experiment",
                                                  ROOT / "scripts" / "wb_experiment.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_white_balance_handling_reaches_the_fixed_illuminant_control(tmp_path):
    l3 = str(Path(sys.executable).parent / "l3")
    # The white-balance handling against its control under one fit: the data-side
    # options (--augment d4, --sample-weight luminance; off by default) move the two
    # sides of this tiny case (3 scenes at 160x120) apart by chance -- mixed-wb 2.37 vs
    # fixed 1.21 with them, 3.30 vs 3.23 without; at 320x240 1.54 vs 1.35 with them,
    # 1.91 vs 1.06 without -- so they are held off explicitly here. For the same reason the
    # fit is the fixed one (--no-tune): self-tuning, the pairs-folder default, may choose
    # another patch or target for each side of this tiny case (mixed-wb 1.64 vs fixed 0.63).
    res = _experiment().run(tmp_path, l3=l3, size="160x120",
                            only=("mixed-wb", "mixed-nowb", "fixed"),
                            train_opts=("--augment", "none", "--sample-weight", "none",
                                        "--no-tune"))
    assert res["fixed"] > 0  # the converter's demosaic is not learned exactly
    assert res["mixed-wb"] <= 1.25 * res["fixed"], res
    assert res["mixed-nowb"] > 3 * res["mixed-wb"], res  # without it the colours fail


def test_reference_converter_is_neutral_for_the_shot_white(tmp_path):
    """The reference maps the shot's own white to equal linear-sRGB channels (D65 white)."""
    import numpy as np

    from l3cli.io.raw import write_raw

    exp = _experiment()
    neutral = np.array([0.6, 1.0, 0.45])
    m = np.zeros((32, 32), np.uint16)
    m[0::2, 0::2] = 0.6 * 20000  # R, RGGB: a surface the camera sees as its neutral
    m[0::2, 1::2] = m[1::2, 0::2] = 20000
    m[1::2, 1::2] = 0.45 * 20000
    cm = np.array([[1.2, -0.1, -0.1], [-0.2, 1.1, 0.1], [0.0, -0.1, 1.0]])
    p = write_raw(tmp_path / "n.dng", m, "RGGB", color_matrix=cm, as_shot_neutral=neutral)
    out = exp.converter(p)[4:-4, 4:-4]
    np.testing.assert_allclose(out[..., 0], out[..., 1], rtol=1e-3)
    np.testing.assert_allclose(out[..., 2], out[..., 1], rtol=1e-3)
