"""docs/camera-toml.md documents every key the camera loader accepts (and no other),
each with its unit or type, and every QE preset, IR filter and illuminant."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from l3cli import spectral
from l3cli.camera import camera_from_dict
from l3cli.errors import ConfigError
from tests.builders import MINIMAL

DOC = (Path(__file__).resolve().parents[1] / "docs" / "camera-toml.md").read_text()
SECTIONS = ["", "optics", "pixel", "readout", "cfa", "spectrum", "exposure"]


def allowed_keys(section: str) -> set[str]:
    """The keys the loader accepts in ``section``, from its own unknown-key message."""
    data = tomllib.loads(MINIMAL)
    (data.setdefault(section, {}) if section else data)["zz_not_a_key"] = 1
    with pytest.raises(ConfigError) as exc:
        camera_from_dict(data, file="cam.toml")
    msg = str(exc.value)
    assert "unknown key" in msg and "zz_not_a_key" in msg
    keys = set(msg.split("keys allowed in ", 1)[1].split(": ", 1)[1].split(", "))
    return keys - set(SECTIONS) if not section else keys


def documented_rows(section: str) -> dict[str, list[str]]:
    """Table rows ``| `key` | unit/type | default | allowed | meaning |`` under the section."""
    heading = "## Top level" if not section else f"## `[{section}]`"
    start = DOC.index(heading)
    nxt = DOC.find("\n## ", start + 1)
    body = DOC[start: nxt if nxt >= 0 else None]
    rows = {}
    for line in body.splitlines():
        m = re.match(r"\|\s*`([a-z_0-9]+)`\s*\|(.*)\|\s*$", line)
        if m:
            rows[m.group(1)] = [c.strip() for c in m.group(2).split("|")]
    return rows


@pytest.mark.parametrize("section", SECTIONS, ids=[s or "top" for s in SECTIONS])
def test_every_key_documented_with_unit(section: str) -> None:
    rows = documented_rows(section)
    assert set(rows) == allowed_keys(section)
    for key, cells in rows.items():
        assert len(cells) == 4, (key, cells)  # unit/type, default, allowed, meaning
        assert cells[0], f"{section}.{key}: no unit or type"
        assert cells[3], f"{section}.{key}: no meaning"


def test_units_of_physical_keys() -> None:
    units = {k: v[0] for s in SECTIONS for k, v in documented_rows(s).items()}
    expected = {"pitch_um": "µm", "conversion_gain_uv_per_e": "µV/e⁻", "voltage_swing_v": "V",
                "full_well_e": "e⁻", "read_noise_e": "e⁻ rms", "dark_current_e_per_s": "e⁻/s",
                "dsnu_e": "e⁻ rms", "prnu_percent": "% rms", "focal_length_mm": "mm",
                "bit_depth": "bits", "black_level_dn": "DN", "wavelength_nm": "nm",
                "time_s": "s", "max_time_s": "s", "light_levels_lux": "lux",
                "light_level_range_lux": "lux"}
    for key, unit in expected.items():
        assert units[key] == unit, (key, units[key])


def test_presets_filters_and_illuminants_documented() -> None:
    for name in spectral.QE_PRESETS:
        assert f"| `{name}` |" in DOC, name
    for name in spectral.IR_FILTERS:
        assert f"`{name}`" in DOC, name
    tail = DOC[DOC.index("Illuminants:"):]
    for name in spectral.ILLUMINANTS:
        assert re.search(rf"[`\s]{re.escape(name)}[`\s]", tail), name
