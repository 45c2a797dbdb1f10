"""The transform table: an NPZ file of per-class affine kernels.

A table holds everything :mod:`l3cli.render` needs: the class definition
(:class:`l3cli.classify.ClassDefinition`), one affine kernel per class and
output channel, the training counts and ridge parameters, the output colour
space and the training provenance. It is a plain ``numpy.savez`` archive
(no pickled objects), loadable with ``numpy.load(allow_pickle=False)``.

Keys (format ``l3-table``, version 1; strings are 0-d unicode arrays)
--------------------------------------------------------------------
================== ============ ===============================================
key                dtype        shape / meaning
================== ============ ===============================================
format             str          ``"l3-table"``
version            int64        ``1``
cfa                str          CFA spec (:attr:`l3cli.cfa.CFA.spec`)
patch              int64        odd patch size S
level_cuts         float64      (n_levels - 1,) increasing level cut points
level_spacing      str          ``"log"`` or ``"linear"``
contrast_rule      str          ``"relative-std-v1"``
contrast_cuts      float64      (n_levels, n_contrast - 1) thresholds per level
contrast_eps       float64      () eps of the contrast rule
saturation_rule    str          ``"any-pixel-per-channel-v1"``
saturation_threshold float64    () normalised saturation threshold
position_group     int64        (n_positions,) group of each CFA position
kernels            float32      (n_classes, S*S + 1, n_out): rows 0..S*S-1 weight
                                the patch in raster order (dy, dx), the last row
                                is the constant term; empty classes hold the
                                kernel of ``source_class``
counts             int64        (n_classes,) training samples per class
lambdas            float64      (n_classes, n_out) ridge λ chosen by GCV
                                (NaN for empty classes)
empty              bool         (n_classes,) too few samples to train
source_class       int64        (n_classes,) class whose kernel is used
output_space       str          ``xyz``, ``linear-srgb``, ``srgb`` or ``lab``
provenance         str          JSON: inputs, options, seed, l3 version, date
white_balance      str          optional JSON: the table expects white-balanced
                                input and holds its adaptation model
                                (:class:`l3cli.whitebalance.model.WhiteBalanceModel`);
                                absent in tables trained without it
cond_*             (optional)   per-ISO-bin kernels (:mod:`l3cli.conditions`)
tone_lut           float32      optional (n_lut, n_out): the kernels render a learned
                                curve space; the output is this look-up table
                                (linear interpolation) of the kernels' values on the
                                uniform grid ``tone_range[0] .. tone_range[1]`` of each
                                channel (:mod:`l3cli.tone.curve`); absent in tables
                                without a tone curve (their kernels render directly)
tone_range         float32      optional (2, n_out): the grid's ends (with tone_lut)
shading_rule       str          optional (version 2): ``"radial-poly-r2-v1"``, a lens
                                shading gain field applied to the normalised mosaic
                                before classification (:mod:`l3cli.lens.field`)
shading_centre     float64      (2,) optical centre (cy, cx), normalised coordinates
shading_coeffs     float64      (n_positions, k) gain = sum_j coeffs[p, j] r^(2j)
shading_size       int64        (2,) height, width of the training raws
shading_grid       float64      (n_positions, ny + 3, nx + 3) with ``shading_rule``
                                ``"spline-grid-v1"`` (instead of centre and coeffs): the
                                control values of a cubic B-spline surface per position
                                (:mod:`l3cli.lens.grid`)
================== ============ ===============================================

A table with a shading gain field is written as version 2 (so that an l3
that cannot apply it refuses the table; version 3 when it also holds a
multi-scale stage); every other table as version 1.

A table with a multi-scale stage (``l3 train --multiscale``, :mod:`l3cli.multiscale.stage`)
holds the optional keys ``multiscale_rule`` (str, ``"gauss-bands-v2"``),
``multiscale_sigmas`` (float64 (n_scales,)), ``multiscale_level_cuts`` (float64
(n_levels - 1,)), ``multiscale_energy_cuts`` (float64 (n_levels, n_energy - 1)),
``multiscale_blend`` (float32 (n_levels * n_energy, n_scales * n_out, n_out)) and
``multiscale_counts`` (int64), ``multiscale_transfer`` (str, ``"none"`` or ``"srgb"``:
the coding it blends in) and is written as version 3, so that an l3 that cannot apply
the stage refuses the table.

Class index ``= ((group * 2**n_channels + sat) * n_levels + level) * n_contrast
+ contrast``.
"""

from __future__ import annotations

import json
import os
import stat
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition
from l3cli.colourspace import SPACES
from l3cli.conditions import MAX_KERNEL_GAIN, kernel_gain  # the limit kernels share
from l3cli.errors import ConfigError, L3Error, TableError
from l3cli.io.atomic import atomic_path

__all__ = ["TransformTable", "save_table", "load_table", "TABLE_FORMAT", "TABLE_VERSION",
           "SHADING_VERSION"]

TABLE_FORMAT = "l3-table"
TABLE_VERSION = 1
#: The version of tables that hold a multi-scale stage (``multiscale_*`` keys).
MULTISCALE_VERSION = 3
#: The version of tables that hold a shading gain field (``shading_*`` keys).
SHADING_VERSION = 2

_STR_KEYS = ("format", "cfa", "level_spacing", "contrast_rule", "saturation_rule",
             "output_space", "provenance")
_KEYS = {
    "format": "U", "version": "i", "cfa": "U", "patch": "i", "level_cuts": "f",
    "level_spacing": "U", "contrast_rule": "U", "contrast_cuts": "f", "contrast_eps": "f",
    "saturation_rule": "U", "saturation_threshold": "f", "position_group": "i",
    "kernels": "f", "counts": "i", "lambdas": "f", "empty": "b", "source_class": "i",
    "output_space": "U", "provenance": "U",
}


@dataclass(eq=False)
class TransformTable:
    """An L3 transform table.

    Attributes
    ----------
    definition
        How pixels are classified.
    kernels
        float32 (n_classes, S*S + 1, n_out) affine kernels (constant term last).
    counts
        int64 (n_classes,) training samples per class.
    lambdas
        float64 (n_classes, n_out) ridge parameter per class and output (NaN = empty).
    empty
        bool (n_classes,) classes with too few samples.
    source_class
        int64 (n_classes,) class whose kernel each class uses (itself when trained).
    output_space
        Colour space of the output (:data:`l3cli.colourspace.SPACES`).
    provenance
        JSON-serialisable training record.
    tone_lut
        ``None``, or ``(lut, range)``: the kernels render a learned curve space
        and the output is ``lut`` of their values (:mod:`l3cli.tone.curve`).
    white_balance
        ``None``, or the white-balance record (:mod:`l3cli.whitebalance.model`): the
        table expects mosaics normalised by each raw's as-shot white balance
        and adapts its output to the raw's white.

    Examples
    --------
    A table whose kernels are all zero (it renders black) and its round trip
    through a file:

    >>> import pathlib, tempfile
    >>> d = ClassDefinition.build("RGGB", patch=3, level_cuts=[0.1])
    >>> n = d.n_classes
    >>> t = TransformTable(d, np.zeros((n, d.n_coeffs, 3)), np.full(n, 100),
    ...                    np.zeros((n, 3)), np.zeros(n, bool), np.arange(n))
    >>> t.n_out, t.patch, t.cfa.spec
    (3, 3, 'RG/GB')
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     back = load_table(save_table(pathlib.Path(tmp) / "t.npz", t))
    >>> back.definition.same_as(d), back.kernels.shape
    (True, (64, 10, 3))
    """

    definition: ClassDefinition
    kernels: np.ndarray
    counts: np.ndarray
    lambdas: np.ndarray
    empty: np.ndarray
    source_class: np.ndarray
    output_space: str = "xyz"
    provenance: dict = field(default_factory=dict)
    format: str = TABLE_FORMAT
    version: int = TABLE_VERSION
    white_balance: dict | None = None
    conditions: Any = None  # l3cli.conditions.Conditioned: per-bin kernels (--by iso)
    tone_lut: tuple[np.ndarray, np.ndarray] | None = None  # (lut, range): l3cli.tone.curve
    multiscale: Any = None  # l3cli.multiscale.stage.Multiscale: applied to the rendered output
    shading: Any = None  # l3cli.lens.field.GainField: lens shading corrected before classification

    def __post_init__(self) -> None:
        self.kernels = np.ascontiguousarray(self.kernels, dtype=np.float32)
        self.counts = np.asarray(self.counts, dtype=np.int64)
        self.lambdas = np.asarray(self.lambdas, dtype=np.float64)
        self.empty = np.asarray(self.empty, dtype=bool)
        self.source_class = np.asarray(self.source_class, dtype=np.int64)
        if self.tone_lut is not None:
            lut, rng = (np.ascontiguousarray(a, dtype=np.float32) for a in self.tone_lut)
            n_out = self.kernels.shape[2] if self.kernels.ndim == 3 else -1
            if (lut.ndim != 2 or lut.shape[0] < 2 or lut.shape[1] != n_out
                    or rng.shape != (2, n_out)):
                raise TableError(f"inconsistent table: tone_lut {lut.shape} / tone_range "
                                 f"{rng.shape} do not fit {n_out} outputs")
            if not (np.all(np.isfinite(lut)) and np.all(np.isfinite(rng))
                    and np.all(rng[1] > rng[0])):
                raise TableError("inconsistent table: tone_lut/tone_range hold NaN, Inf or an "
                                 "empty range")
            self.tone_lut = (lut, rng)
        problem = self._shape_problem()
        if problem:
            raise TableError(f"inconsistent table: {problem}")
        if self.output_space not in SPACES:
            raise TableError(f"output space {self.output_space!r} is not one of {', '.join(SPACES)}")
        if self.multiscale is not None and self.multiscale.n_out != self.n_out:
            raise TableError(f"inconsistent table: the multiscale stage takes "
                             f"{self.multiscale.n_out} channels, the kernels give {self.n_out}")
        if (self.shading is not None
                and self.shading.n_positions != self.definition.cfa.n_positions):
            raise TableError(f"inconsistent table: the shading gain field has "
                             f"{self.shading.n_positions} CFA positions, the CFA "
                             f"{self.definition.cfa.n_positions}")
        if self.conditions is not None and self.conditions.kernels.shape[1:] != self.kernels.shape:
            raise TableError(f"inconsistent table: condition kernels have shape "
                             f"{self.conditions.kernels.shape[1:]}, the table's {self.kernels.shape}")

    def _shape_problem(self) -> str | None:
        d = self.definition
        nc, q = d.n_classes, d.n_coeffs
        k = self.kernels
        if k.ndim != 3 or k.shape[:2] != (nc, q) or k.shape[2] < 1:
            return f"kernels have shape {k.shape}, the class definition needs ({nc}, {q}, n_out)"
        n_out = k.shape[2]
        for name, arr, shape in (("counts", self.counts, (nc,)),
                                 ("lambdas", self.lambdas, (nc, n_out)),
                                 ("empty", self.empty, (nc,)),
                                 ("source_class", self.source_class, (nc,))):
            if arr.shape != shape:
                return f"{name} has shape {arr.shape}, expected {shape}"
        if np.any((self.source_class < 0) | (self.source_class >= nc)):
            return "source_class holds indices outside the classes"
        if np.any(self.empty[self.source_class]):
            return "an empty class falls back to another empty class"
        if np.all(self.empty):
            return "no class is trained"
        if not np.all(np.isfinite(self.kernels)):
            return "kernels hold NaN or Inf"
        if kernel_gain(self.kernels) > MAX_KERNEL_GAIN:
            return (f"kernels have an absolute sum beyond {MAX_KERNEL_GAIN:g}: their outputs "
                    "would overflow float32")
        if np.any(self.counts < 0):
            return "counts hold negative sample counts"
        if np.any(np.isinf(self.lambdas)) or np.any(self.lambdas < 0):
            return "lambdas hold negative or infinite values"
        return None

    @property
    def n_out(self) -> int:
        """Number of output channels."""
        return int(self.kernels.shape[2])

    @property
    def cfa(self) -> CFA:
        """The CFA the table was trained for."""
        return self.definition.cfa

    @property
    def patch(self) -> int:
        """Patch size S (odd)."""
        return self.definition.patch

    @property
    def file_version(self) -> int:
        """The version the table is written as: the oldest that holds its stages."""
        if self.multiscale is not None:
            return MULTISCALE_VERSION
        return SHADING_VERSION if self.shading is not None else self.version

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The NPZ content."""
        out = {
            "format": np.array(self.format),
            "version": np.array(self.file_version, dtype=np.int64),
            **self.definition.to_dict(),
            "kernels": self.kernels,
            "counts": self.counts,
            "lambdas": self.lambdas,
            "empty": self.empty,
            "source_class": self.source_class,
            "output_space": np.array(self.output_space),
            "provenance": np.array(json.dumps(self.provenance, sort_keys=True, default=str)),
        }
        if self.white_balance is not None:
            out["white_balance"] = np.array(json.dumps(self.white_balance, sort_keys=True))
        if self.conditions is not None:
            out.update(self.conditions.to_arrays())
        if self.tone_lut is not None:
            out["tone_lut"], out["tone_range"] = self.tone_lut
        if self.shading is not None:
            out.update(self.shading.to_arrays())
        if self.multiscale is not None:  # version 3: an l3 without the stage refuses it
            out.update(self.multiscale.to_arrays())
        return out


def save_table(path: str | os.PathLike, table: TransformTable) -> Path:
    """Write ``table`` to ``path`` (NPZ, atomically). Returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **table.to_arrays())
    return path


def _scalar(arrs, key, path, kind):
    a = arrs[key]
    if a.ndim != 0:
        raise TableError(f"{path}: key {key!r} must be a scalar, has shape {a.shape}")
    return str(a) if kind == "U" else (int(a) if kind == "i" else float(a))


def _extra_features(arrs, path) -> dict:
    """The optional class features of a table (absent in tables without them)."""
    out: dict = {}
    need = {"orientation_bins": ("coherence_threshold", "orientation_rule"),
            "context_block": ("context_cuts", "context_rule"),
            "highlight_bins": ("highlight_fraction",)}
    for key, others in need.items():
        lacking = [k for k in others if key in arrs and k not in arrs]
        if lacking:
            raise TableError(f"{path}: damaged table, missing keys {', '.join(lacking)}")
    if "orientation_bins" in arrs:
        out["orientation_bins"] = _scalar(arrs, "orientation_bins", path, "i")
        out["coherence_threshold"] = _scalar(arrs, "coherence_threshold", path, "f")
        out["orientation_rule"] = _scalar(arrs, "orientation_rule", path, "U")
    if "context_block" in arrs:
        out["context_block"] = _scalar(arrs, "context_block", path, "i")
        out["context_cuts"] = np.asarray(arrs["context_cuts"], dtype=np.float64)
        out["context_rule"] = _scalar(arrs, "context_rule", path, "U")
    if "highlight_bins" in arrs:
        out["highlight_bins"] = _scalar(arrs, "highlight_bins", path, "i")
        out["highlight_fraction"] = _scalar(arrs, "highlight_fraction", path, "f")
    return out


def load_table(path: str | os.PathLike) -> TransformTable:
    """Read and validate a table written by :func:`save_table`.

    Raises
    ------
    TableError
        Not an NPZ, damaged, another format or version, missing keys, wrong
        dtypes, or shapes that do not fit together. The message names the file.
    """
    path = Path(path)
    if not path.exists():
        raise TableError(f"{path}: no such table file")
    if path.is_dir():
        raise TableError(f"{path}: is a folder, expected a table .npz")
    try:  # non-blocking: a FIFO in a table's place is refused, never waited on
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        with open(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise TableError(f"{path}: is not a regular file (a FIFO or device); "
                                 "expected a table .npz")
            magic = fh.read(4)
    except OSError as exc:
        raise TableError(f"{path}: cannot read table ({exc.strerror})") from exc
    if magic[:2] != b"PK":
        raise TableError(f"{path}: not an NPZ table (not a zip archive)")
    from l3cli.io.npz import check_members, read_members

    check_members(path, TableError)  # no header may claim more values than the file holds
    try:
        with np.load(path, allow_pickle=False) as npz:
            keys = set(npz.files)
            if "format" not in keys:
                raise TableError(f"{path}: not an l3 table (no 'format' key)")
            arrs = read_members(npz, path, TableError)
    except TableError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise TableError(f"{path}: not an NPZ table or damaged ({msg})") from exc
    fmt = arrs["format"]
    if fmt.dtype.kind != "U" or str(fmt) != TABLE_FORMAT:
        raise TableError(f"{path}: format is {str(fmt)!r}, expected {TABLE_FORMAT!r}")
    missing = [k for k in _KEYS if k not in arrs]
    if missing:
        raise TableError(f"{path}: damaged table, missing keys {', '.join(missing)}")
    for k, kind in _KEYS.items():
        dk = arrs[k].dtype.kind
        ok = dk == kind or (kind == "i" and dk == "u") or (kind == "f" and dk == "f")
        if not ok:
            raise TableError(f"{path}: key {k!r} has dtype {arrs[k].dtype}, expected kind {kind!r}")
    version = _scalar(arrs, "version", path, "i")
    if version not in (TABLE_VERSION, SHADING_VERSION, MULTISCALE_VERSION):
        raise TableError(
            f"{path}: table version {version} is not supported; this l3 reads versions "
            f"{TABLE_VERSION}, {SHADING_VERSION} and {MULTISCALE_VERSION}"
        )
    has_shading = "shading_rule" in arrs
    if (version == SHADING_VERSION) > has_shading or has_shading > (version >= SHADING_VERSION):
        raise TableError(f"{path}: damaged table, version {version} "
                         + ("holds no shading_* keys" if has_shading
                            else "needs the shading_* keys"))
    patch, kernels = _scalar(arrs, "patch", path, "i"), arrs["kernels"]
    if kernels.ndim != 3 or kernels.shape[1] != patch * patch + 1:
        # checked first: a patch size is also the size of the arrays the class
        # definition builds from it
        raise TableError(f"{path}: inconsistent table: patch {patch} does not fit kernels of "
                         f"shape {kernels.shape} (patch x patch + 1 coefficients)")
    try:
        definition = ClassDefinition(
            cfa=CFA.from_spec(_scalar(arrs, "cfa", path, "U")),
            patch=patch,
            level_cuts=arrs["level_cuts"],
            level_spacing=_scalar(arrs, "level_spacing", path, "U"),
            contrast_cuts=arrs["contrast_cuts"],
            saturation_threshold=_scalar(arrs, "saturation_threshold", path, "f"),
            position_group=arrs["position_group"],
            contrast_eps=_scalar(arrs, "contrast_eps", path, "f"),
            contrast_rule=_scalar(arrs, "contrast_rule", path, "U"),
            saturation_rule=_scalar(arrs, "saturation_rule", path, "U"),
            **_extra_features(arrs, path),
        )
    except (ConfigError, TableError) as exc:
        raise TableError(f"{path}: bad class definition: {exc}") from exc
    except (TypeError, ValueError, IndexError, OverflowError) as exc:
        raise TableError(f"{path}: bad class definition ({type(exc).__name__}: {exc})") from exc
    try:
        prov = json.loads(_scalar(arrs, "provenance", path, "U") or "{}")
    except json.JSONDecodeError as exc:
        raise TableError(f"{path}: provenance is not JSON ({exc.msg})") from exc
    if not isinstance(prov, dict):
        raise TableError(f"{path}: provenance must be a JSON object, got {type(prov).__name__}")
    wb = None
    if "white_balance" in arrs:
        from l3cli.whitebalance.model import WhiteBalanceModel

        try:
            wb = json.loads(_scalar(arrs, "white_balance", path, "U"))
            WhiteBalanceModel.from_dict(wb)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise TableError(f"{path}: bad white_balance record ({exc})") from exc
    from l3cli.conditions import Conditioned

    try:
        cond = Conditioned.from_arrays(arrs)
    except TableError as exc:
        raise TableError(f"{path}: {exc}") from exc
    tone = None
    if ("tone_lut" in arrs) != ("tone_range" in arrs):
        raise TableError(f"{path}: damaged table, tone_lut and tone_range come together")
    if "tone_lut" in arrs:
        tone = (arrs["tone_lut"], arrs["tone_range"])
        if any(a.dtype.kind != "f" for a in tone):
            raise TableError(f"{path}: tone_lut/tone_range must be floating point")
    from l3cli.lens.field import field_from_arrays

    try:
        shading = field_from_arrays(arrs, definition.cfa.n_positions)
    except TableError as exc:
        raise TableError(f"{path}: {exc}") from exc
    from l3cli.multiscale.stage import Multiscale

    try:
        multiscale = Multiscale.from_arrays(arrs)
    except TableError as exc:
        raise TableError(f"{path}: {exc}") from exc
    if (version == MULTISCALE_VERSION) != (multiscale is not None):
        raise TableError(f"{path}: damaged table, version {version} "
                         + ("needs the multiscale_* keys" if version == MULTISCALE_VERSION
                            else "holds multiscale_* keys"))
    try:
        return TransformTable(
            definition=definition,
            kernels=arrs["kernels"],
            counts=arrs["counts"],
            lambdas=arrs["lambdas"],
            empty=arrs["empty"],
            source_class=arrs["source_class"],
            output_space=_scalar(arrs, "output_space", path, "U"),
            provenance=prov,
            white_balance=wb,
            conditions=cond,
            tone_lut=tone,
            multiscale=multiscale,
            shading=shading,
        )
    except L3Error as exc:
        raise TableError(f"{path}: {exc}") from exc
