"""Per-raw kernel sets: a table and a raw's metadata, prepared once, run by one fused kernel.

Everything a table does to a raw that is linear and the same for every pixel
of the raw is settled here, once per raw, before the tile kernel runs:

1. **mosaic gains** (:class:`l3cli.lens.gainmaps.MosaicGains`): a DNG's GainMap
   opcodes, the table's learned lens shading and a white-balancing table's
   as-shot gains multiply the mosaic *before* classification (the levels and
   the saturation classes see the gained values). They are not passes over
   the mosaic: the tile kernel evaluates them per pixel as it copies each
   tile's band (:func:`l3cli.classify.run_tiles`' ``gains``), with the rules
   and the float32 products of :func:`l3cli.lens.gainmaps.apply_maps`,
   :func:`l3cli.lens.field.correct_mosaic` and
   :func:`l3cli.whitebalance.model.apply_gains`. Only where the kernel cannot
   (a context guide, whose block means read the corrected mosaic, or a DNG
   map of an unusual layout) does :meth:`KernelSet.prepare_mosaic` multiply
   the mosaic first.
2. **kernels**: the condition bins of a ``--by`` table interpolated for the
   raw (:func:`l3cli.conditions.kernels_for`), and the white balance's 3x3
   adaptation folded into them when nothing non-linear comes after the
   kernels (no tone curve, a linear output space): ``A (Kᵀ p) = (K Aᵀ)ᵀ p``.
3. **post matrix**: with a learned tone curve the adaptation acts on the
   curve's output, so it cannot move into the kernels; it becomes a 3x3
   ``post`` that the display encoder applies per pixel in the same fused
   pass (:func:`l3cli.render_rows.encode_row`'s matrix, combined with the
   XYZ to linear sRGB matrix of ``xyz`` tables), or that float renders apply
   per band. Only an adaptation that is not linear in the table's output
   space (``srgb`` and ``lab`` tables) is applied to float bands with
   :func:`l3cli.whitebalance.model.adapt_image`.

Per pixel, a white-balancing or shading table, or a DNG with GainMaps,
therefore costs what a plain table costs:
the tile kernel (:func:`l3cli.classify.run_tiles`) with the tone curve and
the display encoding fused. :func:`render_mosaic` (float) and
:func:`render_display` (8/16-bit display integers) run a :class:`KernelSet`;
given a :class:`~l3cli.table.TransformTable` they run its plain kernels (no
per-raw white balance or conditions), as they always did.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Any

import numpy as np

from l3cli import buffers
from l3cli.classify import MODE_DISPLAY, MODE_RENDER, check_mosaic, run_tiles
from l3cli.classify.layout import RENDER_LANES, pack_taps
from l3cli.errors import InputError
from l3cli.table import TransformTable

if TYPE_CHECKING:
    from l3cli.classify import ClassDefinition
    from l3cli.io.raw import RawImage
    from l3cli.lens.gainmaps import MosaicGains

__all__ = ["DISPLAY_BAND_PIXELS", "KernelSet", "linear_adaptation",
           "pack_kernels", "prepare_kernels", "render_display", "render_mosaic",
           "tone_curve_arrays"]

_RGB = ("R", "G", "B")


def pack_kernels(table: TransformTable | np.ndarray) -> np.ndarray:
    """Kernels in the render kernel's layout (a copy: ~1 MB, a few ms).

    Parameters
    ----------
    table
        A table (its ``kernels``) or float (n_classes, S*S + 1, n_out) kernels.

    Returns
    -------
    numpy.ndarray
        float32. Tables of up to 4 outputs: the tap-lane layout of
        :func:`l3cli.render_rows.pack_taps` for 3 outputs (three-output tables)
        or 4 (zero-padded), (n_classes, outputs * S * L + 4). Otherwise
        (n_classes, (S*S + 1) * n_out), tap-major (patch row-major, then the
        constant).
    """
    kernels = table.kernels if isinstance(table, TransformTable) else table
    k = np.asarray(kernels, dtype=np.float32)  # (n_classes, q, n_out)
    nc, q, n_out = k.shape
    if n_out > RENDER_LANES:
        return np.ascontiguousarray(k.reshape(nc, q * n_out))
    packed = np.zeros((nc, q, RENDER_LANES), dtype=np.float32)
    packed[:, :, :n_out] = k
    return pack_taps(packed, 3 if n_out == 3 else RENDER_LANES)


def tone_curve_arrays(table: TransformTable) -> tuple[np.ndarray, ...] | None:
    """The table's learned tone curve as the tile kernel reads it (None: no curve).

    The kernels render the curve's linear space; the kernel maps each output
    row through the curve (:func:`l3cli.tone.curve.curve_row`).
    """
    if table.tone_lut is None:
        return None
    from l3cli.tone.curve import curve_arrays

    return curve_arrays(*table.tone_lut)


def linear_adaptation(matrix: np.ndarray, output_space: str, space: str) -> np.ndarray | None:
    """The 3x3 that :func:`l3cli.whitebalance.model.adapt_image` applies in ``output_space``, or None.

    ``adapt_image(img, matrix, output_space, space)`` converts to the linear
    ``space``, applies ``matrix`` and converts back; between ``xyz`` and
    ``linear-srgb`` the conversions are the 3x3 matrices of
    :mod:`l3cli.colourspace`, so the whole is one matrix (float64). ``srgb``
    and ``lab`` outputs are not linear in ``space``: None.
    """
    from l3cli.colourspace import LINEAR_SRGB_TO_XYZ, XYZ_TO_LINEAR_SRGB

    linear = {"xyz": "xyz", "linear-srgb": "linear-srgb"}
    if output_space not in linear or space not in linear:
        return None
    to_space = {("xyz", "linear-srgb"): XYZ_TO_LINEAR_SRGB,
                ("linear-srgb", "xyz"): LINEAR_SRGB_TO_XYZ}
    m = np.asarray(matrix, dtype=np.float64)
    if output_space == space:
        return np.ascontiguousarray(m)
    return np.ascontiguousarray(to_space[(space, output_space)] @ m
                                @ to_space[(output_space, space)])


@dataclasses.dataclass(frozen=True)
class KernelSet:
    """What the tile kernel runs for one raw (:func:`prepare_kernels`).

    Attributes
    ----------
    definition
        The table's class definition.
    kernels
        float32 packed kernels (:func:`pack_kernels`), with the raw's
        condition interpolation and (where linear) white-balance adaptation
        folded in.
    n_out
        Outputs per pixel.
    output_space
        The table's output space (of the render, after ``post``).
    curve
        The learned tone curve (:func:`tone_curve_arrays`), or None.
    post
        float64 (3, 3) applied per pixel after the curve, in
        ``output_space`` (the adaptation of a curve table), or None.
    adapt
        ``(matrix, space)``: an adaptation that is not linear in
        ``output_space``, applied to float bands by
        :func:`l3cli.whitebalance.model.adapt_image` after the curve; or None.
    mosaic_gains
        float32 (ph, pw): per CFA position, the white-balance gain the mosaic
        is multiplied by before classification; or None.
    saturation
        The table's saturation threshold: a pixel at or above it stays at or
        above it after a gain below one.
    gains
        Every gain of the raw's mosaic before classification (DNG maps, lens
        shading, ``mosaic_gains``): :class:`l3cli.lens.gainmaps.MosaicGains`, or None.
    """

    definition: ClassDefinition
    kernels: np.ndarray
    n_out: int
    output_space: str
    curve: tuple[np.ndarray, ...] | None = None
    post: np.ndarray | None = None
    adapt: tuple[np.ndarray, str] | None = None
    mosaic_gains: np.ndarray | None = None
    saturation: float = 1.0
    gains: MosaicGains | None = None

    @classmethod
    def plain(cls, table: TransformTable, kernels: np.ndarray | None = None) -> KernelSet:
        """The table's own kernels (or ``kernels``), no per-raw steps."""
        return cls(table.definition, pack_kernels(table if kernels is None else kernels),
                   table.n_out, table.output_space, tone_curve_arrays(table),
                   saturation=float(table.definition.saturation_threshold))

    @property
    def fused(self) -> bool:
        """True when every step after the kernels runs inside the tile kernel's pass."""
        return self.adapt is None

    @property
    def folded(self) -> bool:
        """True when the tile kernel applies the raw's gains (:attr:`gains`) itself."""
        return self.gains is not None and self.gains.foldable

    def prepare_mosaic(self, mosaic: np.ndarray, *, inplace: bool = False) -> np.ndarray:
        """The mosaic :func:`render_mosaic` and :func:`render_display` take for this raw.

        With folded gains (:attr:`folded`, the usual case) that is ``mosaic``
        itself: the tile kernel multiplies each band as it copies it. Else the
        gains multiply the mosaic here (:meth:`corrected_mosaic`).

        Parameters
        ----------
        mosaic
            float32 (H, W), the raw's CFA phase, as read (no gains applied).
        inplace
            Multiply ``mosaic`` itself (a decoded mosaic the caller owns);
            else a copy is made when there are gains to apply here.
        """
        if self.gains is None:
            return mosaic
        if self.gains.foldable:
            self._check_shape(mosaic)
            return mosaic
        return self.corrected_mosaic(mosaic, inplace=inplace)

    def corrected_mosaic(self, mosaic: np.ndarray, *, inplace: bool = False) -> np.ndarray:
        """``mosaic`` times the raw's gains, as passes over it
        (:meth:`l3cli.lens.gainmaps.MosaicGains.apply`): the mosaic the classes see."""
        if self.gains is None:
            return mosaic
        m = check_mosaic(mosaic, self.definition.cfa, self.definition.patch)
        if not (inplace and m is mosaic):
            m = m.copy()
        return self.gains.apply(m)

    def _check_shape(self, mosaic: np.ndarray) -> None:
        if self.gains is not None and tuple(mosaic.shape) != tuple(self.gains.shape):
            raise ValueError(f"the kernel set's gains are for a {self.gains.shape[1]}x"
                             f"{self.gains.shape[0]} mosaic, not {mosaic.shape[1]}x"
                             f"{mosaic.shape[0]}")

    def kernel_gains(self, mosaic: np.ndarray) -> tuple | None:
        """The tile kernel's ``gains`` argument for ``mosaic`` (None: not folded)."""
        if not self.folded:
            return None
        self._check_shape(mosaic)
        return self.gains.kernel_args()  # type: ignore[union-attr]


def prepare_kernels(table: TransformTable, raw: RawImage | None = None, *,
                    white_balance: np.ndarray | None = None,
                    table_name: str = "table") -> KernelSet:
    """The kernel set that renders ``raw`` with ``table`` (the one per-raw step of a render).

    Parameters
    ----------
    table
        The transform table.
    raw
        The raw (its metadata: condition value, as-shot white balance); None
        gives the table's plain kernels.
    white_balance
        Gains ``[r, g, b]`` instead of the raw's own (white-balancing tables only).
    table_name
        The table's name in messages.

    Raises
    ------
    InputError
        ``white_balance`` given for a table trained without white balance;
        the table expects a white balance and the raw has none (nor is one
        given); the raw's CFA is not R, G, B.
    """
    ks = _prepare(table, raw, white_balance, table_name)
    if raw is None:
        return ks
    from l3cli.lens.gainmaps import mosaic_gains

    gains = mosaic_gains(raw, field=getattr(table, "shading", None), wb=ks.mosaic_gains,
                         saturation=float(table.definition.saturation_threshold),
                         fold=not table.definition.context_block)
    return ks if gains is None else dataclasses.replace(ks, gains=gains)


def _prepare(table: TransformTable, raw: RawImage | None, white_balance: np.ndarray | None,
             table_name: str) -> KernelSet:
    """:func:`prepare_kernels` but for the mosaic's gains other than the white balance's."""
    if table.white_balance is None and white_balance is not None:
        raise InputError(f"{table_name}: the table was trained without white balance; "
                         "--white-balance does not apply to it")
    if raw is None:
        return KernelSet.plain(table)
    kernels = table.kernels
    if table.conditions is not None:  # per-bin kernels, interpolated for this raw
        from l3cli.conditions import LABELS, kernels_for, raw_condition

        value = raw_condition(raw, table.conditions.by)
        if value is None:
            logging.getLogger(__name__).warning(
                "%s: no %s in the metadata; rendering with the pooled kernels",
                raw.path, LABELS[table.conditions.by])
        kernels = kernels_for(table, value)
    if table.white_balance is None:
        return KernelSet.plain(table, kernels)
    from l3cli.whitebalance.model import WhiteBalanceModel, gain_pattern, gains_or_error

    gains = gains_or_error(raw, white_balance)
    gmap = gain_pattern(raw.cfa, gains)
    model = WhiteBalanceModel.from_dict(table.white_balance)
    matrix = model.matrix(gains)
    if np.array_equal(matrix, np.eye(3)):  # one training white: no adaptation (exactly)
        return dataclasses.replace(KernelSet.plain(table, kernels), mosaic_gains=gmap)
    post = linear_adaptation(matrix, table.output_space, model.space)
    adapt = None if post is not None else (matrix, model.space)
    curve = tone_curve_arrays(table)
    if post is not None and curve is None:  # nothing after the kernels: fold it in
        k = np.asarray(kernels, dtype=np.float64)
        kernels = np.einsum("cqj,ij->cqi", k, post).astype(np.float32)
        post = None
    return KernelSet(table.definition, pack_kernels(kernels), table.n_out, table.output_space,
                     curve, post, adapt, gmap, float(table.definition.saturation_threshold))


def _kernel_set(table: TransformTable | KernelSet) -> KernelSet:
    return table if isinstance(table, KernelSet) else KernelSet.plain(table)


def _post_rows(ks: KernelSet, part: np.ndarray) -> None:
    """The steps after the curve that the tile kernel does not fuse, on float rows in place."""
    if ks.post is not None:
        flat = part.reshape(-1, part.shape[-1])
        flat[:] = flat @ ks.post.T.astype(np.float32)
    elif ks.adapt is not None:
        from l3cli.whitebalance.model import adapt_image

        part[:] = adapt_image(part, ks.adapt[0], ks.output_space, ks.adapt[1])


#: Pixels of one float band of the two-step paths (``lab`` tables, adaptations not
#: linear in the output space, float renders with a post matrix).
DISPLAY_BAND_PIXELS = 1 << 20


def _render_args(table: TransformTable | KernelSet, mosaic: np.ndarray,
                 rows: tuple[int, int] | None, out: np.ndarray | None, dtype: Any
                 ) -> tuple[KernelSet, np.ndarray, tuple[int, int], np.ndarray]:
    """The kernel set, the checked mosaic, the rows and the output buffer of a render."""
    ks = _kernel_set(table)
    mosaic = check_mosaic(mosaic, ks.definition.cfa, ks.definition.patch)
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    shape = (y1 - y0, w, ks.n_out)
    if out is None:
        out = buffers.empty(shape, dtype)
    elif out.shape != shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous {np.dtype(dtype)} array of shape {shape}")
    return ks, mosaic, (y0, y1), out


def render_mosaic(table: TransformTable | KernelSet, mosaic: np.ndarray, *,
                  out: np.ndarray | None = None,
                  rows: tuple[int, int] | None = None) -> np.ndarray:
    """Render a normalised mosaic (CFA phase as the table's) in the table's space.

    Parameters
    ----------
    table
        The transform table (its plain kernels), or a raw's :class:`KernelSet`
        (then ``mosaic`` is the one :meth:`KernelSet.prepare_mosaic` returned).
    mosaic
        float32 (H, W), 0 = black, 1 = white level.
    out
        Optional float32 C-contiguous (H, W, n_out) output array (or
        (y1 - y0, W, n_out) with ``rows``).
    rows
        Optional ``(y0, y1)``: render only these rows (their patches still
        see the rows around them).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, n_out) in ``table.output_space``.
    """
    ks, mosaic, (y0, y1), out = _render_args(table, mosaic, rows, out, np.float32)
    d, w = ks.definition, mosaic.shape[1]
    run_tiles(mosaic, d, MODE_RENDER, rows=(y0, y1), kernels=ks.kernels,
              n_out=ks.n_out, out=out, curve=ks.curve, gains=ks.kernel_gains(mosaic))
    if ks.post is not None or ks.adapt is not None:
        step = max(1, DISPLAY_BAND_PIXELS // max(w, 1))
        for b0 in range(0, y1 - y0, step):
            _post_rows(ks, out[b0:b0 + step])
    return out


def render_display(table: TransformTable | KernelSet, mosaic: np.ndarray, bits: int, *,
                   out: np.ndarray | None = None,
                   rows: tuple[int, int] | None = None,
                   render_lock: AbstractContextManager | None = None) -> np.ndarray:
    """Render a normalised mosaic straight to display integers (as TIFF, PNG and JPEG hold).

    The tile kernel renders each row, maps it through the tone curve, applies
    the kernel set's ``post`` matrix (with the XYZ to linear sRGB matrix of
    ``xyz`` tables, one 3x3) and display-encodes it while it is in cache
    (:func:`l3cli.render_rows.encode_row`), 8 or 16 bits: no float image is
    held and no second pass is made. With a tone curve and no 3x3 after it,
    the curve and the encoding are one lookup per value (:mod:`l3cli.tone.code`:
    for 8 bits the same codes; for 16 bits interpolated, the same codes or one
    next to them). Only ``lab`` tables (whose conversion
    is colour-science's) and adaptations that are not linear in the table's
    space render bands of about :data:`DISPLAY_BAND_PIXELS` to float and
    encode them one after another. Either way the integers are those of
    :func:`l3cli.io.encode.display_encode` applied to :func:`render_mosaic`'s
    output (a test checks it; a post matrix, or the 16-bit composed lookup, may move a
    value by one code).

    Parameters
    ----------
    table
        The transform table (its plain kernels) or a raw's :class:`KernelSet`.
    mosaic
        float32 (H, W), 0 = black, 1 = white level (for a kernel set, as
        :meth:`KernelSet.prepare_mosaic` returned it).
    bits
        8 (uint8 out) or 16 (uint16 out).
    out
        Optional C-contiguous output of that dtype, (H, W, n_out) (or
        (y1 - y0, W, n_out) with ``rows``).
    rows
        Optional ``(y0, y1)``: render only these rows.
    render_lock
        Held around each call of the (parallel) render kernel (the file
        pipeline's lock); a band's encoding runs outside it.

    Returns
    -------
    numpy.ndarray
        uint8 or uint16 (H, W, n_out) display values (sRGB for 3-channel tables).
    """
    from l3cli.io.encode import display_encode, display_params, encode_into

    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    ks, mosaic, (y0, y1), out = _render_args(table, mosaic, rows, out,
                                             np.uint16 if bits == 16 else np.uint8)
    d, w = ks.definition, mosaic.shape[1]
    lock = render_lock if render_lock is not None else contextlib.nullcontext()
    with lock:  # the encoder's tables (cached per process) are built once, not beside
        params = display_params(ks.output_space, ks.n_out, bits)  # a warm-up's build
    if params is not None and ks.post is not None:  # one 3x3 per pixel, in the encoder
        params = params._replace(use_matrix=True,
                                 matrix=np.ascontiguousarray(params.matrix @ ks.post))
    if params is not None and ks.adapt is None:
        codes = None
        if ks.curve is not None and not params.use_matrix and ks.n_out == 3:
            from l3cli.tone.code import code_table_for

            with lock:
                codes = code_table_for(ks.curve, params.thr, bits)
            if codes is not None and codes.walk > 1:  # the general loop is slower than
                codes = None  # curve-then-encode (measured): only the one-comparison loop
        with lock:
            run_tiles(mosaic, d, MODE_DISPLAY, rows=(y0, y1), kernels=ks.kernels,
                      n_out=ks.n_out, out=out, curve=ks.curve, display=params, codes=codes,
                      gains=ks.kernel_gains(mosaic))
        return out
    # lab (colour-science's conversion) or a non-linear adaptation: float bands of
    # ~1 M pixels, each finished and encoded after its render
    step = max(1, DISPLAY_BAND_PIXELS // max(w, 1))
    band = buffers.empty((min(step, y1 - y0), w, ks.n_out), np.float32)  # reused per file
    for b0 in range(y0, y1, step):
        b1 = min(y1, b0 + step)
        part = band[: b1 - b0]
        with lock:
            run_tiles(mosaic, d, MODE_RENDER, rows=(b0, b1), kernels=ks.kernels,
                      n_out=ks.n_out, out=part, curve=ks.curve, gains=ks.kernel_gains(mosaic))
        _post_rows(ks, part)  # an adaptation (a post matrix is never here: it is fused)
        if params is None:  # lab
            out[b0 - y0:b1 - y0] = display_encode(part, ks.output_space, bits)
        else:
            encode_into(part, params, bits, out[b0 - y0:b1 - y0])
    del part
    buffers.release(band)
    return out
