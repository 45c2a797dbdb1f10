"""The product, not a stand-in: tables `l3 train` makes with no options, rendered file to file.

Usage::

    .venv/bin/python benchmarks/bench_product.py [--dng PATH] [--copies 8] [--repeat 3]
        [--features-repeat 3] [--cache DIR] [--retrain] [--raws-only]
    .venv/bin/python benchmarks/bench_product.py --gainmaps-only [--table NAME=PATH ...]

Tables (trained once and kept in ``--cache``, keyed by their inputs and l3's version):

* ``synthetic 5x5``: ``bench_files.py``'s table (the plain one every ratio below is
  relative to: patch 5, no white balance, no tone curve);
* ``frames (l3 train defaults)``: ``l3 train examples/infinite_isp/frames`` (the
  bundled Infinite-ISP frames; no white balance in their metadata: tone curve, patch 7);
* ``Blackmagic pair (l3 train defaults)``: ``l3 train PAIRS`` on the Blackmagic DNG of
  the shared data and LibRaw's AHD render of it (rawpy ``postprocess``, as-shot white
  balance, 16-bit TIFF), as a user makes a pair: as-shot white balance + per-shot
  adaptation, tone curve, patch 7. Needs ``--dng`` (default the shared data set's);
  skipped with a note without it.

Five tables are printed:

1. **Per-feature cost** relative to the plain 5x5 table: tables of the plain layout
   with one feature each (white-balance adaptation, tone curve, both, patch 7 and 9,
   ``--by iso`` bins, orientation, context, highlight bins, a learned lens-shading
   field, a multi-scale stage) and the trained ones.
   *Kernel alone*: one process, the render stage of one 9-MP raw (the per-raw kernel
   set, the gains on the mosaic, the fused render + 8-bit display encoding), best of
   ``--features-repeat`` interleaved rounds. *Whole process*: ``l3 render`` of the
   ``--copies`` lossy DNGs to JPEG, best of ``--features-repeat``.
2. **GainMap DNGs** (:func:`gainmap_table`): ``--copies`` 12-MP uncompressed DNGs with
   four GainMap opcodes (a phone's or action camera's lens shading) against the same
   pixels without opcodes, kernel alone (the gains folded into the kernel, and as passes
   over the mosaic as before) and whole process, with LibRaw AHD's time on them and the
   ratio. ``--gainmaps-only`` prints this table alone (the plain 5x5 table, it with a
   lens-shading field, and tables given with ``--table NAME=PATH``).
3. **Against LibRaw**: the trained tables → JPEG q95 4:4:4 and 16-bit TIFF, the
   ``--copies`` lossy DNGs (9 MP) and as many uncompressed 12-MP DNGs (the
   Blackmagic mosaic, tiled to 4000x3000 and written by ``l3cli.io.raw.write_raw``
   with its as-shot white, as ``l3 simulate`` writes DNGs), whole processes against
   one Python process of rawpy (LibRaw AHD) + OpenImageIO with the same encoder
   settings (``bench_files.peer``), interleaved, best of ``--repeat``; and the
   *floor* (LibRaw's decode + the write alone, ``bench_files.floor``), which says
   where LibRaw is the bottleneck. The other raw kinds users have, made from the
   same 12-MP mosaic (:func:`raw_kinds`): lossless-JPEG DNG, 12-bit packed DNG, and
   headerless ``.raw`` dumps (whose peer reads the uncompressed DNG: LibRaw cannot
   read a headerless file). Before it, the **per-file read** of each kind in this
   process (:func:`decode_table`): l3's ``read_raw`` against LibRaw's decode. The
   GainMap DNGs are one of the kinds.
4. **One 9-MP DNG → JPEG**, whole process, each trained table.

Without the shared DNG a synthetic 9-MP DNG (with an as-shot white) stands in for the
per-feature table and tables 2 to 4 are skipped (``--gainmaps-only`` uses a synthetic
12-MP mosaic then).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(HERE))

from bench_files import DEFAULT_DNG, _fresh, _l3_cmd, _run, photo_table  # noqa: E402

FRAMES = REPO / "examples" / "infinite_isp" / "frames"
DEFAULT_CACHE = Path(tempfile.gettempdir()) / "l3-bench-cache"
PLAIN = "plain 5x5 (synthetic)"


# ------------------------------------------------------------------ tables
def _key(*paths: Path) -> str:
    import l3cli

    h = hashlib.sha1(str(getattr(l3cli, "__version__", "")).encode())
    for p in paths:
        for f in sorted(p.rglob("*")) if p.is_dir() else [p]:
            if f.is_file():
                st = f.stat()
                h.update(f"{f.name}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()[:12]


def _training_code() -> list[Path]:
    """The sources whose change can change what ``l3 train`` with no options makes."""
    pkg = REPO / "l3cli"
    return [pkg / "defaults.py", pkg / "cli" / "train.py", *sorted((pkg / "train").glob("*.py"))]


def _content_key(paths: list[Path]) -> str:
    h = hashlib.sha1()
    for p in paths:
        h.update(p.read_bytes())
    return h.hexdigest()[:8]


def trained_table(name: str, pairs: Path, cache: Path, retrain: bool = False) -> Path:
    """``l3 train PAIRS -o TABLE`` with no options, once per input and training code
    (kept in ``cache``: a change of the defaults or of the training code trains anew, so
    the benchmark always times the table today's ``l3 train`` makes)."""
    cache.mkdir(parents=True, exist_ok=True)
    out = cache / f"{name}-{_key(pairs)}-{_content_key(_training_code())}.npz"
    if out.exists() and not retrain:
        return out
    t0 = time.perf_counter()
    subprocess.run([*_l3_cmd(), "-q", "train", str(pairs), "-o", str(out)], cwd=REPO,
                   check=True)
    print(f"(trained {name}: `l3 train {pairs}` in {time.perf_counter() - t0:.0f} s)",
          flush=True)
    return out


def blackmagic_pair(dng: Path, cache: Path) -> Path:
    """A pairs folder: the DNG and LibRaw's AHD render of it (as-shot white, 16-bit TIFF)."""
    import OpenImageIO as oiio
    import rawpy

    folder = cache / f"pair-{_key(dng)}"
    tif = folder / (dng.stem + ".tif")
    if tif.exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(dng, folder / dng.name)
    with rawpy.imread(str(dng)) as raw:
        rgb = raw.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD,
                              use_camera_wb=True, output_bps=16)
    spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, "uint16")
    part = folder / ".part.tif"
    o = oiio.ImageOutput.create(str(part))
    o.open(str(part), spec)
    o.write_image(rgb)
    o.close()
    os.replace(part, tif)
    return folder


def _wb_record(space: str = "xyz") -> dict:
    """An adaptation model of the kind training fits (one feature: log b/r)."""
    from l3cli.whitebalance.model import WhiteBalanceModel

    c0 = np.array([[1.05, 0.04, -0.02], [0.03, 0.97, 0.01], [-0.01, 0.05, 1.1]])
    c1 = np.array([[0.1, 0.0, 0.02], [0.0, 0.0, 0.0], [0.01, 0.0, -0.12]])
    return WhiteBalanceModel(space, [0.2], [c0.ravel(), c1.ravel()],
                             [[2.0, 1.0, 1.5], [1.6, 1.0, 2.1]]).as_dict()


def _curve(space: str = "xyz"):
    from l3cli.tone.curve import ToneCurve

    x = np.linspace(0, 1, 33)[:, None]
    return ToneCurve(np.hstack([x ** 2.0, x ** 2.2, x ** 1.9]), space="srgb").lut(space)


def _relayout(base, **features):
    """``base`` (the plain table) with a changed class definition; kernels as the plain ones."""
    import dataclasses

    from l3cli.classify import ClassDefinition

    d0 = base.definition
    patch = features.pop("patch", d0.patch)
    d = ClassDefinition.build(d0.cfa, patch=patch, level_cuts=d0.level_cuts,
                              contrast_cuts=d0.contrast_cuts, **features)
    nc, q = d.n_classes, d.n_coeffs
    k = np.zeros((nc, q, base.n_out), np.float32)
    c = patch // 2
    k[:, c * patch + c, :] = 1.0  # the centre pixel: speed does not depend on the values
    k[:, :, :] += np.float32(0.001)
    return dataclasses.replace(base, definition=d, kernels=k, counts=np.full(nc, 1000),
                               lambdas=np.zeros((nc, base.n_out)), empty=np.zeros(nc, bool),
                               source_class=np.arange(nc))


def shading_field(size: tuple[int, int]):
    """A learned lens-shading field of the kind ``l3 train`` keeps (corners lifted ~1.6x,
    a little off centre, per Bayer position), for raws of ``size``."""
    from l3cli.lens.field import GainField

    coeffs = [[1.0, 0.45, 0.15], [1.0, 0.4, 0.12], [1.0, 0.4, 0.12], [1.0, 0.55, 0.2]]
    return GainField([0.03, -0.02], coeffs, size)


def spline_field(size: tuple[int, int]):
    """A learned lens-shading field of the other kind ``l3 train`` keeps: a cubic B-spline
    grid per Bayer position (4x6 intervals, corners lifted ~1.6x), for raws of ``size``."""
    from l3cli.lens.grid import SplineField

    yy = np.linspace(-1, 1, 7)[:, None]
    xx = np.linspace(-1, 1, 9)[None, :]
    grid = np.stack([1.0 + k * (yy ** 2 + xx ** 2) / 2 for k in (1.2, 1.0, 1.0, 1.4)])
    return SplineField(grid, size)


def multiscale_stage():
    """A multi-scale stage of the default sigmas (1, 3, 9), 3 levels x 2 energies, sRGB
    coded, identity blend (its cost does not depend on the values)."""
    from l3cli.multiscale.stage import Multiscale

    return Multiscale.identity(3, (1.0, 3.0, 9.0), [0.05, 0.3],
                               np.array([[0.001, 0.01]] * 3), transfer="srgb")


def feature_tables(size: tuple[int, int] = (2176, 4128)) -> dict:
    """The plain 5x5 table and tables of its layout with one feature each (``size``: the
    raws' (height, width), where the lens-shading field was learned)."""
    import dataclasses

    from l3cli.conditions import Conditioned

    base = photo_table()
    nc = base.definition.n_classes
    tables = {PLAIN: base,
              "+ white balance (adaptation folded)": dataclasses.replace(
                  base, white_balance=_wb_record()),
              "+ tone curve": dataclasses.replace(base, tone_lut=_curve()),
              "+ white balance + tone curve": dataclasses.replace(
                  base, white_balance=_wb_record(), tone_lut=_curve()),
              "+ --by iso (2 bins)": dataclasses.replace(base, conditions=Conditioned(
                  "iso", np.array([100.0, 1600.0]),
                  np.stack([base.kernels, base.kernels * np.float32(1.1)]),
                  np.full((2, nc), 1000))),
              "patch 7": _relayout(base, patch=7),
              "patch 9": _relayout(base, patch=9),
              "+ orientation 4": _relayout(base, orientation_bins=4),
              "+ context (64 px, 3 bins)": _relayout(
                  base, context_block=64, context_cuts=np.array([0.8, 1.25]),
                  context_rule="ratio"),
              "+ highlight bins 2": _relayout(base, highlight_bins=2),
              "+ lens shading (gain field)": dataclasses.replace(base,
                                                                 shading=shading_field(size)),
              "+ lens shading (spline grid)": dataclasses.replace(base,
                                                                  shading=spline_field(size)),
              "+ multi-scale stage (3 scales)": dataclasses.replace(
                  base, multiscale=multiscale_stage())}
    return tables


# ------------------------------------------------------------------ inputs
def synthetic_dng(path: Path, w: int = 4128, h: int = 2176) -> Path:
    from bench_render import synthetic_mosaic

    from l3cli.io.raw import write_raw

    m = np.round(synthetic_mosaic(h, w) * 4095).astype(np.uint16)
    return write_raw(path, m, "RGGB", white_level=4095, as_shot_neutral=np.array([0.5, 1, 0.7]),
                     shot={"iso": 400})


def uncompressed_dng(dng: Path, path: Path, w: int = 4000, h: int = 3000) -> Path:
    """The DNG's mosaic tiled to ``w`` x ``h`` (CFA phase kept), written uncompressed by
    l3 (as ``l3 simulate`` writes DNGs), with the DNG's black, white and as-shot white."""
    import rawpy

    from l3cli.io.raw import write_raw

    with rawpy.imread(str(dng)) as raw:
        m = raw.raw_image_visible.copy()
        black = float(np.mean(raw.black_level_per_channel))
        white = float(raw.white_level)
        wb = np.asarray(raw.camera_whitebalance[:3], np.float64)
        cam = np.asarray(raw.rgb_xyz_matrix[:3], np.float64)
        spec = "".join("RGBG"[c] for c in raw.raw_pattern.ravel())
    reps = (-(-h // m.shape[0]), -(-w // m.shape[1]))
    big = np.tile(m[: m.shape[0] // 2 * 2, : m.shape[1] // 2 * 2], reps)[:h, :w]
    return write_raw(path, np.ascontiguousarray(big), spec, black_level=black,
                     white_level=white, as_shot_neutral=wb[1] / wb,
                     color_matrix=cam if np.any(cam) else None)


def _libraw_mosaic(path: Path) -> tuple[np.ndarray, int, int, str, tuple[float, ...]]:
    """A DNG's mosaic as LibRaw reads it, with its black and white levels, CFA spec and
    as-shot neutral: what a copy of its pixels in another raw kind needs."""
    import rawpy

    with rawpy.imread(str(path)) as raw:
        m = raw.raw_image_visible.copy()
        black = int(round(float(np.mean(raw.black_level_per_channel))))
        white = int(raw.white_level)
        wb = np.asarray(raw.camera_whitebalance[:3], np.float64)
        spec = "".join("RGBG"[c] for c in raw.raw_pattern.ravel())
    return m, black, white, spec, tuple(wb[1] / wb)


def raw_kinds(unc: Path, folder: Path, copies: int) -> dict[str, tuple[list[str], list[str]]]:
    """The other raw kinds users have, made from the uncompressed DNG's mosaic (the same
    pixels, levels and white): ``{kind: (l3's files, the peer's files)}``.

    * lossless-JPEG DNG (compression 7, SOF3; 256x256 tiles of two interleaved halves per
      row, as cameras and Adobe's converter write them; imagecodecs' libjpeg-turbo);
    * 12-bit packed uncompressed DNG (the mosaic's top 12 bits);
    * headerless dump (``.raw`` + ``.raw.toml``, 16-bit little-endian): LibRaw cannot read
      those, so the peer reads the uncompressed DNG of the same pixels.
    """
    sys.path.insert(0, str(REPO / "tests"))
    from dngmake import make_dng

    m, black, white, spec, neutral = _libraw_mosaic(unc)
    pattern = tuple("RGB".index(c) for c in spec)
    kinds: dict[str, tuple[list[str], list[str]]] = {}

    def copies_of(first: Path) -> list[str]:
        return [str(first)] + [str(shutil.copyfile(first, first.with_name(
            f"{first.stem[:-2]}{i + 1:02d}{first.suffix}"))) for i in range(1, copies)]

    d = _fresh(folder / "ljpeg")
    files = copies_of(make_dng(d / "lj01.dng", m, pattern=pattern, bits=16, tile=(256, 256),
                               lossless_jpeg=True, components=2, black=black, white=white,
                               neutral=neutral))
    kinds[f"{copies} x 12-MP lossless-JPEG DNG"] = (files, files)
    d = _fresh(folder / "packed12")
    files = copies_of(make_dng(d / "pk01.dng", m >> 4, pattern=pattern, bits=12,
                               black=black >> 4, white=white >> 4, neutral=neutral))
    kinds[f"{copies} x 12-MP 12-bit packed DNG"] = (files, files)
    d = _fresh(folder / "headerless")
    m.astype("<u2").tofile(d / "hl01.raw")
    (d / "hl01.raw.toml").write_text(
        f'width = {m.shape[1]}\nheight = {m.shape[0]}\ndtype = "uint16"\ncfa = "{spec}"\n'
        f"black_level = {black}\nwhite_level = {white}\n"
        f"white_balance = [{neutral[0] ** -1:.6f}, 1.0, {neutral[2] ** -1:.6f}]\n")
    files = copies_of(d / "hl01.raw")
    for f in files[1:]:
        shutil.copyfile(d / "hl01.raw.toml", f + ".toml")
    kinds[f"{copies} x 12-MP headerless .raw (peer: the same pixels as uncompressed DNG)"] = (
        files, [str(unc)] * copies)
    return kinds


def decode_table(kinds: dict[str, tuple[list[str], list[str]]], repeat: int) -> list[str]:
    """Per-file read, one process, interleaved rounds, best of ``repeat``: l3's
    ``read_raw`` (decode + LibRaw's metadata + normalisation) against LibRaw's decode
    (``rawpy.imread(...).raw_image_visible`` copied) and ``read_raw(..., libraw=True)``."""
    import rawpy

    from l3cli.io.raw import read_raw

    def libraw(f: str) -> None:
        with rawpy.imread(f) as raw:
            raw.raw_image_visible.copy()

    lines = [f"Per-file read, one process, best of {repeat} interleaved rounds (the first "
             "file of each kind; LibRaw reads a headerless dump's peer, the uncompressed DNG "
             "of the same pixels):", "",
             "| raws | l3 read_raw | LibRaw decode (raw_image_visible copy) | read_raw via "
             "LibRaw | LibRaw decode / l3 | read_raw LibRaw / l3 |",
             "|---|---:|---:|---:|---:|---:|"]
    print("\n".join(lines), flush=True)
    for kind, (files, peer_files) in kinds.items():
        best = {"l3": np.inf, "libraw": np.inf, "rr_libraw": np.inf}
        calls = (("l3", read_raw, files[0], {}), ("libraw", libraw, peer_files[0], {}),
                 ("rr_libraw", read_raw, peer_files[0], {"libraw": True}))
        for _ in range(repeat):
            for name, fn, arg, kw in calls:
                t = time.perf_counter()
                fn(arg, **kw)
                best[name] = min(best[name], time.perf_counter() - t)
        lines.append(f"| {kind.split(' (')[0]} | {best['l3'] * 1e3:.1f} ms "
                     f"| {best['libraw'] * 1e3:.1f} ms | {best['rr_libraw'] * 1e3:.1f} ms "
                     f"| {best['libraw'] / best['l3']:.2f}x "
                     f"| {best['rr_libraw'] / best['l3']:.2f}x |")
        print(lines[-1], flush=True)
    return lines


def gainmap_dngs(folder: Path, copies: int, dng: Path | None = None, w: int = 4000,
                 h: int = 3000) -> tuple[list[str], list[str]]:
    """``copies`` 12-MP uncompressed DNGs with 4 GainMap opcodes in OpcodeList2 (one per
    Bayer position, 13 x 17 points: a phone's or action camera's lens shading; written by
    ``tests/dngmake.py``), and as many of the same pixels without opcodes. The pixels: the
    DNG's mosaic tiled to ``w`` x ``h`` (:func:`uncompressed_dng`), or the synthetic one."""
    sys.path.insert(0, str(REPO / "tests"))
    from dngmake import make_dng, phone_gain_maps

    from l3cli.io.dng_opcodes import encode_gain_maps

    folder.mkdir(parents=True, exist_ok=True)
    if dng is not None and dng.exists():
        unc = uncompressed_dng(dng, folder / "unc.dng", w, h)
        m, black, white, spec, neutral = _libraw_mosaic(unc)
        unc.unlink()
    else:
        from bench_render import synthetic_mosaic

        m = np.round(synthetic_mosaic(h, w) * 3900 + 64).astype(np.uint16)
        black, white, spec, neutral = 64, 4095, "RGGB", (0.5, 1.0, 0.7)
    pattern = tuple("RGB".index(c) for c in spec)
    ops = encode_gain_maps(phone_gain_maps(h, w, points=(13, 17)))
    out: tuple[list[str], list[str]] = ([], [])
    for i, (name, data) in enumerate((("gm", ops), ("plain", None))):
        d = _fresh(folder / name)
        first = make_dng(d / f"{name}01.dng", m, pattern=pattern, bits=16, black=black,
                         white=white, neutral=neutral, opcode_list2=data)
        out[i].append(str(first))
        out[i].extend(str(shutil.copyfile(first, d / f"{name}{k + 1:02d}.dng"))
                      for k in range(1, copies))
    return out


def gainmap_table(tables: dict[str, Path], gm_files: list[str], plain_files: list[str],
                  tmp: Path, repeat: int) -> list[str]:
    """GainMap DNGs against the same pixels without opcodes, per table: the render stage of
    one file in this process (the gains folded into the kernel; as passes over the mosaic,
    as l3 did before; the file without opcodes), and whole processes (``l3 render`` of the
    files → JPEG, and LibRaw AHD + OpenImageIO of the GainMap DNGs), interleaved, best of
    ``repeat``."""
    from l3cli.io.raw import read_raw
    from l3cli.table import load_table

    me = [sys.executable, str(HERE / "bench_files.py")]
    loaded = {name: load_table(p) for name, p in tables.items()}
    gm, plain = read_raw(gm_files[0]), read_raw(plain_files[0])
    src = {"gm": (gm.mosaic.copy(), gm.gain_maps), "plain": (plain.mosaic.copy(), None)}
    raws = {"gm": gm, "plain": plain}

    def stage(name: str, kind: str, fold: bool) -> float:
        r = raws[kind]
        np.copyto(r.mosaic, src[kind][0])  # the decode's mosaic, fresh (not timed)
        r.gain_maps = src[kind][1]
        t0 = time.perf_counter()
        render_stage(loaded[name], r, fold=fold)
        return time.perf_counter() - t0

    runs = [(name, kind, fold) for name in loaded
            for kind, fold in (("gm", True), ("gm", False), ("plain", True))]
    kern = {r: np.inf for r in runs}
    for r in runs:
        stage(*r)  # kernels loaded, tables built
    for _ in range(repeat):
        for r in runs:
            kern[r] = min(kern[r], stage(*r))
    whole = {(name, kind): np.inf for name in tables for kind in ("gm", "plain")}
    ahd = np.inf
    for _ in range(repeat):
        for name, table in tables.items():
            for kind, files in (("gm", gm_files), ("plain", plain_files)):
                out = _fresh(tmp / "out")
                dt, _, _ = _run([*_l3_cmd(), "-q", "render", str(table), *files, "-o",
                                 str(out), "--format", "jpg"])
                whole[(name, kind)] = min(whole[(name, kind)], dt)
        out = _fresh(tmp / "out")
        ahd = min(ahd, _run([*me, "--peer", "AHD", "jpg", str(out), *gm_files])[0])
    mp = gm.mosaic.size / 1e6
    lines = [f"GainMap DNGs: {len(gm_files)} x {mp:.0f}-MP uncompressed DNGs with 4 GainMap "
             "opcodes (OpcodeList2, one map of 13 x 17 points per Bayer position, as phones "
             "and action cameras write them; `tests/dngmake.py`) against the same pixels "
             f"without opcodes. Kernel alone: the render stage of one file (kernel set, "
             f"the gains, fused render + 8-bit encoding), one process, best of {repeat} "
             "interleaved rounds: the gains folded into the kernel's band copy, and as "
             "passes over the mosaic (l3 before). Whole process: `l3 render` → JPEG q95, "
             f"and LibRaw AHD + OpenImageIO of the GainMap DNGs, best of {repeat} "
             "interleaved.", "",
             "| table | kernel: GainMap folded | kernel: as passes | kernel: no opcodes "
             "| folded vs no opcodes | whole: GainMap DNGs | whole: no opcodes "
             "| GainMap vs no opcodes | LibRaw AHD | l3 vs AHD |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name in tables:
        kf, kp, k0 = (kern[(name, "gm", True)], kern[(name, "gm", False)],
                      kern[(name, "plain", True)])
        wg, w0 = whole[(name, "gm")], whole[(name, "plain")]
        lines.append(f"| {name} | {kf:.3f} s | {kp:.3f} s | {k0:.3f} s | {kf / k0:.2f}x "
                     f"| {wg:.2f} s | {w0:.2f} s | {wg / w0:.2f}x | {ahd:.2f} s "
                     f"| **{ahd / wg:.2f}x** |")
    return lines


# ------------------------------------------------------------------ timings
def kernel_times(tables: dict, raw_path: Path, repeat: int,
                 rounds: list[dict[str, float]] | None = None) -> dict[str, float]:
    """Seconds of the render stage per table (best of ``repeat`` interleaved rounds; each
    round's times appended to ``rounds`` when given)."""
    from l3cli import buffers
    from l3cli.io.raw import read_raw

    raw = read_raw(raw_path)
    raws = {name: _phase(raw, t.cfa) for name, t in tables.items()}
    srcs = {name: r.mosaic.copy() for name, r in raws.items()}
    best = {name: np.inf for name in tables}

    def once(name):
        r, t = raws[name], tables[name]
        np.copyto(r.mosaic, srcs[name])  # the decode's mosaic, fresh (not timed)
        t0 = time.perf_counter()
        render_stage(t, r)
        return time.perf_counter() - t0

    with buffers.recycling():
        for name in tables:  # load the kernels (numba's cache) and the encoder tables
            once(name)
        for _ in range(repeat):
            times = {name: once(name) for name in tables}
            best = {name: min(best[name], times[name]) for name in tables}
            if rounds is not None:
                rounds.append(times)
    return best


def render_stage(table, raw, *, fold: bool = True) -> None:
    """What ``l3 render`` does to a decoded raw before the write (pipeline.render_one): the
    kernel set, the mosaic it takes, the fused render + 8-bit encoding (a multi-scale table:
    the float render, the stage, the encoding). ``fold`` False applies the raw's gains (DNG
    maps, lens shading, white balance) as passes over the mosaic first, as l3 did before
    they were folded into the kernel."""
    import dataclasses

    from l3cli import buffers
    from l3cli.lens.gainmaps import apply_dng_gains
    from l3cli.prepared import prepare

    if not fold:
        apply_dng_gains(raw)  # as read_raw did
    p = prepare(table, raw, inplace=True)
    if not fold and p.kernels.gains is not None:
        ks = p.kernels
        ks = dataclasses.replace(ks, gains=dataclasses.replace(ks.gains, foldable=False))
        p = dataclasses.replace(p, kernels=ks, mosaic=ks.prepare_mosaic(raw.mosaic, inplace=True))
    buffers.release(p.render(8))


def _phase(raw, cfa):
    """``raw`` cropped by at most one CFA period so that its CFA is ``cfa`` (a GRBG table
    times on an RGGB raw one column in)."""
    import dataclasses

    ph, pw = raw.cfa.period
    for dy in range(ph):
        for dx in range(pw):
            if raw.cfa.shifted(dy, dx).spec == cfa.spec:
                h, w = raw.mosaic.shape
                m = np.ascontiguousarray(raw.mosaic[dy:h - ph + dy, dx:w - pw + dx])
                return dataclasses.replace(raw, mosaic=m, cfa=raw.cfa.shifted(dy, dx))
    raise SystemExit(f"no crop of {raw.path} has the CFA {cfa.spec}")


def _kernel_child(table_dir: str, raw_path: str, repeat: int) -> None:
    from l3cli.table import load_table

    names = sorted(Path(table_dir).glob("*.npz"))
    tables = {p.stem: load_table(p) for p in names}
    for name, sec in kernel_times(tables, Path(raw_path), repeat).items():
        print(f"{name}\t{sec:.4f}", flush=True)


def _save_all(tables: dict, folder: Path) -> dict[str, Path]:
    from l3cli.table import save_table

    folder.mkdir(parents=True, exist_ok=True)
    files = {}
    for i, (name, t) in enumerate(tables.items()):
        files[name] = save_table(folder / f"t{i:02d}.npz", t) if not isinstance(t, Path) \
            else Path(shutil.copyfile(t, folder / f"t{i:02d}.npz"))
    return files


def feature_table(tables: dict, files: list[str], raw: Path, tmp: Path,
                  repeat: int) -> list[str]:
    paths = _save_all(tables, tmp / "tables")
    stem = {name: p.stem for name, p in paths.items()}
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--kernel-child",
                           str(tmp / "tables"), str(raw), str(repeat)], cwd=REPO,
                          capture_output=True, text=True, check=True)
    sec = dict((ln.split("\t")[0], float(ln.split("\t")[1]))
               for ln in proc.stdout.strip().splitlines())
    from l3cli.io.raw import read_raw
    from l3cli.table import load_table

    spec = read_raw(raw).cfa.spec
    whole = {name: np.inf for name in tables}
    for _ in range(repeat):
        for name, p in paths.items():
            if load_table(p).cfa.spec != spec:
                continue  # a table of another CFA phase: no file of its phase here
            out = _fresh(tmp / "out")
            dt, _, _ = _run([*_l3_cmd(), "-q", "render", str(p), *files, "-o", str(out),
                             "--format", "jpg"])
            whole[name] = min(whole[name], dt)
    mp = _megapixels(raw)
    k0, w0 = sec[stem[PLAIN]], whole[PLAIN]
    lines = [f"Per-feature cost, relative to the plain 5x5 table. Kernel alone: the render "
             f"stage of one {mp:.1f}-MP raw (`{raw.name}`: kernel set, mosaic gains, fused "
             f"render + 8-bit encoding), one process, best of {repeat} interleaved rounds. "
             f"Whole process: `l3 render` of {len(files)} files → JPEG, best of {repeat}.", "",
             "| table | classes | kernel s | kernel ms/MP | kernel vs plain "
             "| whole process s | whole vs plain |", "|---|---:|---:|---:|---:|---:|---:|"]
    from l3cli.table import load_table

    for name in tables:
        t = load_table(paths[name])
        k = sec[stem[name]]
        w = (f"{whole[name]:.2f} | {whole[name] / w0:.2f}x" if np.isfinite(whole[name])
             else f"— ({t.cfa.spec} table, {spec} files) | —")
        lines.append(f"| {name} | {t.definition.n_classes} | {k:.3f} | {1e3 * k / mp:.1f} "
                     f"| {k / k0:.2f}x | {w} |")
    return lines


def _megapixels(raw: Path) -> float:
    from l3cli.io.raw import read_raw

    return read_raw(raw).mosaic.size / 1e6


def libraw_table(tables: dict[str, Path], kinds: dict[str, list[str] | tuple[list[str], list[str]]],
                 tmp: Path, repeat: int) -> list[str]:
    """Trained tables vs LibRaw AHD + OpenImageIO, whole processes, interleaved (a kind's
    files, or (l3's files, the peer's files) where LibRaw cannot read l3's)."""
    me = [sys.executable, str(HERE / "bench_files.py")]
    lines = [f"Trained tables against LibRaw AHD + OpenImageIO (one Python process, same "
             f"encoder settings), whole processes, best of {repeat}, interleaved; floor = "
             "LibRaw's decode + the write alone (`bench_files.floor`).", "",
             "| raws | output | table | l3 render | LibRaw AHD | l3 vs AHD | floor "
             "| AHD / floor |", "|---|---|---|---:|---:|---:|---:|---:|"]
    print("\n".join(lines), flush=True)
    for kind, both in kinds.items():
        files, peer_files = both if isinstance(both, tuple) else (both, both)
        for fmt, label in (("jpg", "JPEG q95 4:4:4"), ("tiff", "TIFF 16-bit")):
            best = {name: np.inf for name in tables} | {"AHD": np.inf, "floor": np.inf}
            for _ in range(repeat):
                for name, table in tables.items():
                    out = _fresh(tmp / "out")
                    dt, _, _ = _run([*_l3_cmd(), "-q", "render", str(table), *files, "-o",
                                     str(out), "--format", fmt])
                    best[name] = min(best[name], dt)
                for alg in ("AHD", "floor"):
                    out = _fresh(tmp / "out")
                    dt, _, _ = _run([*me, "--peer", alg, fmt, str(out), *peer_files])
                    best[alg] = min(best[alg], dt)
            for name in tables:
                lines.append(f"| {kind} | {label} | {name} | {best[name]:.2f} s "
                             f"| {best['AHD']:.2f} s | {best['AHD'] / best[name]:.2f}x "
                             f"| {best['floor']:.2f} s | {best['AHD'] / best['floor']:.2f}x |")
                print(lines[-1], flush=True)
    return lines


def one_file_table(tables: dict[str, Path], dng: str, tmp: Path, repeat: int) -> list[str]:
    me = [sys.executable, str(HERE / "bench_files.py")]
    lines = ["", f"One 9-MP DNG → JPEG, whole process, best of {repeat}:", "",
             "| table | l3 render | LibRaw AHD |", "|---|---:|---:|"]
    ahd = np.inf
    best = {name: np.inf for name in tables}
    for _ in range(repeat):
        for name, table in tables.items():
            out = _fresh(tmp / "one")
            best[name] = min(best[name], _run([*_l3_cmd(), "-q", "render", str(table), dng,
                                               "-o", str(out / "one.jpg")])[0])
        out = _fresh(tmp / "one")
        ahd = min(ahd, _run([*me, "--peer", "AHD", "jpg", str(out), dng])[0])
    for name in tables:
        lines.append(f"| {name} | {best[name]:.2f} s | {ahd:.2f} s |")
    return lines


def _gainmap_tables(tmp: Path, given: dict[str, Path], size: tuple[int, int]) -> dict:
    """The plain 5x5 table, it with a lens-shading field, a table of the default's
    features (patch 7, white-balance adaptation, tone curve; untrained kernels), and
    ``given`` tables, as files."""
    import dataclasses

    from l3cli.table import save_table

    base = feature_tables()[PLAIN]
    default = dataclasses.replace(_relayout(base, patch=7), white_balance=_wb_record(),
                                  tone_lut=_curve())
    out = {PLAIN: save_table(tmp / "plain.npz", base),
           "plain 5x5 + lens shading": save_table(tmp / "shading.npz", dataclasses.replace(
               base, shading=shading_field(size))),
           "patch 7 + white balance + tone curve (the default's features)": save_table(
               tmp / "default-like.npz", default)}
    return out | given


def _gainmaps_only(a: argparse.Namespace) -> None:
    print(f"load average before: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)", flush=True)
    given = dict((kv.split("=", 1)[0], Path(kv.split("=", 1)[1])) for kv in a.table)
    tmp = Path(tempfile.mkdtemp(prefix="l3bench-gainmap-"))
    try:
        gm, plain = gainmap_dngs(tmp / "gainmap", a.copies, Path(a.dng))
        tables = _gainmap_tables(tmp, given, (3000, 4000))
        print("\n".join(gainmap_table(tables, gm, plain, tmp, a.repeat)), flush=True)
        print(f"load average after: {os.getloadavg()[0]:.1f}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dng", default=str(DEFAULT_DNG))
    ap.add_argument("--copies", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--features-repeat", type=int, default=3)
    ap.add_argument("--cache", default=str(DEFAULT_CACHE))
    ap.add_argument("--retrain", action="store_true")
    ap.add_argument("--raws-only", action="store_true",
                    help="only the raw-kind tables (per-file read, and against LibRaw): no "
                         "per-feature or one-file table")
    ap.add_argument("--gainmaps-only", action="store_true",
                    help="only the GainMap DNG table (the plain 5x5 table, its lens-shading "
                         "variant and the trained tables given with --table)")
    ap.add_argument("--table", action="append", default=[],
                    help="NAME=PATH: a table for the GainMap DNG table instead of training one")
    ap.add_argument("--kernel-child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.kernel_child:
        _kernel_child(a.kernel_child[0], a.kernel_child[1], int(a.kernel_child[2]))
        return
    if a.gainmaps_only:
        _gainmaps_only(a)
        return
    print(f"load average before: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)", flush=True)
    cache = Path(a.cache)
    dng = Path(a.dng)
    trained = {"frames (l3 train defaults)": trained_table("frames", FRAMES, cache, a.retrain)}
    if dng.exists():
        pair = blackmagic_pair(dng, cache)
        trained["Blackmagic pair (l3 train defaults)"] = trained_table(
            "blackmagic", pair, cache, a.retrain)
    tmp = Path(tempfile.mkdtemp(prefix="l3bench-product-"))
    try:
        src = _fresh(tmp / "lossy")
        base = dng if dng.exists() else synthetic_dng(tmp / "synthetic.dng")
        lossy = []
        for i in range(a.copies):
            lossy.append(str(shutil.copyfile(base, src / f"frame{i + 1:02d}.dng")))
        from l3cli.io.raw import read_raw

        tables = feature_tables(read_raw(base).mosaic.shape) | trained
        if not a.raws_only:
            print("\n".join(feature_table(tables, lossy, Path(lossy[0]), tmp,
                                          a.features_repeat)), flush=True)
        if not dng.exists():
            print(f"\n(skipped the LibRaw tables: {dng} is not here; it is in the shared data "
                  "set — pass --dng PATH)", flush=True)
            return
        from l3cli.table import save_table

        peers = {PLAIN: save_table(tmp / "plain.npz", feature_tables()[PLAIN]),
                 **{k: v for k, v in trained.items() if "Blackmagic" in k}}
        big = _fresh(tmp / "uncompressed")
        first = uncompressed_dng(dng, big / "big01.dng")
        unc = [str(first)] + [str(shutil.copyfile(first, big / f"big{i + 1:02d}.dng"))
                              for i in range(1, a.copies)]
        kinds: dict = {f"{a.copies} x 9-MP lossy DNG": lossy,
                       f"{a.copies} x 12-MP uncompressed DNG": unc}
        kinds |= raw_kinds(first, tmp / "kinds", a.copies)
        if not a.raws_only:
            gm, gm_plain = gainmap_dngs(tmp / "gainmap", a.copies, dng)
            print("", flush=True)
            print("\n".join(gainmap_table(
                _gainmap_tables(tmp, {k: v for k, v in peers.items() if k != PLAIN},
                                (3000, 4000)), gm, gm_plain, tmp, a.repeat)), flush=True)
            kinds[f"{a.copies} x 12-MP uncompressed DNG, 4 GainMaps"] = gm
        print("", flush=True)
        decode_table({k: v if isinstance(v, tuple) else (v, v) for k, v in kinds.items()},
                     max(a.repeat, 5))
        print("", flush=True)
        libraw_table(peers, kinds, tmp, a.repeat)
        if not a.raws_only:
            print("\n".join(one_file_table(peers, lossy[0], tmp, a.repeat)), flush=True)
        print(f"load average after: {os.getloadavg()[0]:.1f}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
