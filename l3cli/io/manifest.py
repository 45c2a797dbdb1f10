"""The simulation manifest: one versioned, validated reader and writer.

``l3 simulate`` writes ``SIM_DIR/manifest.json``; ``train``, ``evaluate`` and
``baseline`` read it. Every reader goes through :func:`read_manifest`, which
checks the format name, the version, and the types and ranges of the values
the readers use, and names the file and the key of the first problem.

Layout (version 1)::

    {"format": "l3-simulation", "version": 1,
     "camera": {...}, "target": {"space": "xyz", ...}, "options": {...},
     "captures": [{"stem": "...", "raw": "STEM.dng", "target": "STEM.target.exr",
                   "noise_free": "...", "lux": 100.0, "exposure_s": 0.01,
                   "width": 480, "height": 320, "chart": {...} | null,
                   "edge": {"roi": [x0, y0, x1, y1]} | null, ...}, ...]}

File names in a capture are plain names inside SIM_DIR (no folders, no ``..``).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from l3cli.errors import InputError, OutputError

__all__ = ["MANIFEST_NAME", "MANIFEST_FORMAT", "MANIFEST_VERSION", "manifest_path",
           "is_simulation_dir", "read_manifest", "write_manifest", "validate_manifest",
           "capture_files"]

MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = "l3-simulation"
MANIFEST_VERSION = 1
#: Target colour spaces a manifest may declare.
_SPACES = ("xyz", "linear-srgb", "srgb", "lab")
_FILE_KEYS = ("raw", "target", "noise_free", "raw_sidecar")


def manifest_path(folder: str | os.PathLike) -> Path:
    """``folder/manifest.json``."""
    return Path(folder) / MANIFEST_NAME


def is_simulation_dir(folder: str | os.PathLike) -> bool:
    """True when ``folder`` holds a ``manifest.json`` (a ``simulate`` output)."""
    return manifest_path(folder).exists()


class _Problem(Exception):
    """A validation problem, reported with the file name by the caller."""


def _finite(v: Any, key: str, *, positive: bool = False, allow_none: bool = False) -> None:
    if v is None and allow_none:
        return
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise _Problem(f"{key} must be a finite number, got {v!r}")
    if positive and not v > 0:
        raise _Problem(f"{key} must be > 0, got {v!r}")


def _numbers(v: Any, key: str, n: int | None = None) -> None:
    if not isinstance(v, list) or (n is not None and len(v) != n):
        raise _Problem(f"{key} must be a list of {n or 'some'} numbers, got {v!r:.80}")
    for i, x in enumerate(v):
        _finite(x, f"{key}[{i}]")


def _file_name(v: Any, key: str) -> None:
    if not isinstance(v, str) or not v or v in (".", "..") or "/" in v or "\\" in v or "\0" in v:
        raise _Problem(f"{key} must be a file name inside the simulation folder, got {v!r:.80}")


def _capture(cap: Any, i: int) -> None:
    where = f"captures[{i}]"
    if not isinstance(cap, dict):
        raise _Problem(f"{where} must be an object")
    for key in ("stem", "raw", "target"):
        if key not in cap:
            raise _Problem(f"{where} lacks {key!r}")
    if not isinstance(cap["stem"], str) or not cap["stem"]:
        raise _Problem(f"{where}.stem must be a non-empty string")
    for key in _FILE_KEYS:
        if key in cap:
            _file_name(cap[key], f"{where}.{key}")
    for key in ("lux", "exposure_s"):
        if key in cap:
            _finite(cap[key], f"{where}.{key}", positive=True, allow_none=True)
    for key in ("width", "height"):
        v = cap.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise _Problem(f"{where}.{key} must be an integer >= 1, got {v!r}")
    for key in ("black_level", "white_level", "photometric_exposure_white_lux_s"):
        if key in cap:
            _finite(cap[key], f"{where}.{key}", allow_none=True)
    if cap.get("illuminant") is not None and not isinstance(cap["illuminant"], str):
        raise _Problem(f"{where}.illuminant must be a string")
    if cap.get("white_xyz") is not None:
        _numbers(cap["white_xyz"], f"{where}.white_xyz", 3)
    chart = cap.get("chart")
    if chart is not None:
        if not isinstance(chart, dict) or not isinstance(chart.get("patches"), list):
            raise _Problem(f"{where}.chart must be an object with a 'patches' list")
        for j, box in enumerate(chart["patches"]):
            _numbers(box, f"{where}.chart.patches[{j}]", 4)
        ref = chart.get("reference_xyz")
        if ref is not None:
            if not isinstance(ref, list) or len(ref) != len(chart["patches"]):
                raise _Problem(f"{where}.chart.reference_xyz must hold one XYZ per patch")
            for j, xyz in enumerate(ref):
                _numbers(xyz, f"{where}.chart.reference_xyz[{j}]", 3)
        wi = chart.get("white_index")
        if wi is not None and (isinstance(wi, bool) or not isinstance(wi, int)
                               or not 0 <= wi < len(chart["patches"])):
            raise _Problem(f"{where}.chart.white_index must be a patch index, got {wi!r}")
    edge = cap.get("edge")
    if edge is not None:
        if not isinstance(edge, dict):
            raise _Problem(f"{where}.edge must be an object")
        if edge.get("roi") is not None:
            _numbers(edge["roi"], f"{where}.edge.roi", 4)


def validate_manifest(manifest: Any) -> None:
    """Check a manifest's structure; raise ``ValueError`` naming the key at fault."""
    try:
        _validate(manifest)
    except _Problem as exc:
        raise ValueError(str(exc)) from None


def _validate(m: Any) -> None:
    if not isinstance(m, dict):
        raise _Problem("not a JSON object")
    if m.get("format") != MANIFEST_FORMAT:
        raise _Problem(f"format must be {MANIFEST_FORMAT!r}, got {m.get('format')!r:.60}")
    version = m.get("version")
    if isinstance(version, bool) or not isinstance(version, int):
        raise _Problem(f"version must be an integer, got {version!r:.60}")
    if version != MANIFEST_VERSION:
        raise _Problem(f"version {version} is not supported; this l3 reads version "
                       f"{MANIFEST_VERSION} (re-run `l3 simulate` with this l3)")
    for key in ("camera", "target", "options"):
        if m.get(key) is not None and not isinstance(m[key], dict):
            raise _Problem(f"{key} must be an object")
    space = (m.get("target") or {}).get("space", "xyz")
    if space not in _SPACES:
        raise _Problem(f"target.space must be one of {', '.join(_SPACES)}, got {space!r:.60}")
    pitch = (m.get("camera") or {}).get("pixel_pitch_um")
    if pitch is not None:
        _finite(pitch, "camera.pixel_pitch_um", positive=True)
    caps = m.get("captures")
    if not isinstance(caps, list):
        raise _Problem("'captures' must be a list")
    stems: set[str] = set()
    for i, cap in enumerate(caps):
        _capture(cap, i)
        if cap["stem"] in stems:
            raise _Problem(f"captures[{i}].stem {cap['stem']!r} appears twice")
        stems.add(cap["stem"])


def read_manifest(folder: str | os.PathLike) -> dict[str, Any]:
    """Read and validate ``folder/manifest.json`` (``folder`` may name the file itself).

    Returns
    -------
    dict
        The manifest; ``target.space`` is filled in (``xyz``) where absent.

    Raises
    ------
    InputError
        Missing, unreadable, not JSON, another format or version, or values of
        the wrong type or range (the message names the key).
    """
    path = Path(folder)
    if path.is_dir() or path.name != MANIFEST_NAME:
        path = manifest_path(path)
    if not path.exists():
        raise InputError(f"{path.parent}: not a `l3 simulate` output (no {MANIFEST_NAME})")
    try:
        text = path.read_bytes().decode("utf-8")
        manifest = json.loads(text)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        detail = getattr(exc, "strerror", None) or getattr(exc, "msg", None) or type(exc).__name__
        raise InputError(f"{path}: cannot read the simulation manifest ({detail})") from exc
    try:
        _validate(manifest)
    except _Problem as exc:
        raise InputError(f"{path}: not a valid l3 simulation manifest: {exc}") from None
    manifest.setdefault("target", {})
    manifest["target"] = {**(manifest["target"] or {}), "space": (manifest["target"] or {})
                          .get("space", "xyz")}
    return manifest


def write_manifest(folder: str | os.PathLike, manifest: dict[str, Any]) -> Path:
    """Validate ``manifest`` and write it atomically as ``folder/manifest.json``."""
    from l3cli.io.atomic import atomic_path

    try:
        _validate(manifest)
    except _Problem as exc:
        raise OutputError(f"{manifest_path(folder)}: refusing to write a bad manifest: {exc}") \
            from None
    path = manifest_path(folder)
    try:
        text = json.dumps(manifest, indent=1, allow_nan=False) + "\n"
    except (ValueError, TypeError) as exc:
        raise OutputError(f"{path}: refusing to write a bad manifest: {exc}") from None
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path


def capture_files(folder: str | os.PathLike, manifest: dict[str, Any]) -> list[Path]:
    """Every file of ``folder`` the manifest lists (raws, sidecars, targets), and itself."""
    folder = Path(folder)
    out = [manifest_path(folder)]
    for cap in manifest["captures"]:
        out.extend(folder / cap[k] for k in _FILE_KEYS if cap.get(k))
    return out
