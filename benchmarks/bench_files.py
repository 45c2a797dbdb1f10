"""File to file, as a user times it: a folder of DNGs to JPEG, TIFF and EXR, whole processes.

Usage::

    .venv/bin/python benchmarks/bench_files.py [--dng PATH] [--copies 8] [--repeat 3]
        [--memory-size 6000x4000] [--memory-files 3]

Inputs: ``--copies`` copies of one real 9-MP DNG (default: the Blackmagic
Pocket 4K frame of the shared data set, ``../shared/data/raw/misc/``; a clone
without it skips the timing tables with a note) in a temporary folder, and a
table with the layout of ``bench_render.py`` (4 positions x 40 levels x 2
contrasts) whose kernels render a photograph (:func:`photo_table`: the
render's speed does not depend on the values, the encoders' does).

Timed, interleaved, best of ``--repeat``, each a fresh process started from
the shell's point of view (Python start-up, imports and kernel loading
included):

* ``l3 render TABLE DNG... -o DIR --format FMT`` (one process for the folder);
* one Python process looping over the files with rawpy (LibRaw AHD, then PPG)
  and writing with OpenImageIO with the same encoder settings: JPEG quality 95
  4:4:4 from 8-bit sRGB, uncompressed 16-bit TIFF, uncompressed float32 EXR
  (linear, from LibRaw's 16-bit output; l3's defaults);
* the *floor*: one Python process that only decodes each file with LibRaw and
  writes an image of the output's size with the same encoder, 3 files at a
  time (:func:`floor`). Every renderer that decodes with LibRaw pays this;
  ``AHD / floor`` is the largest speed-up over AHD such a renderer could
  show on this machine. (l3 decodes this DNG's lossy JPEG tiles itself,
  :mod:`l3cli.io.dng_lossy`, in a third of LibRaw's time; the stage table
  shows both decodes.);

and one file end to end (one DNG to JPEG). Peak memory (``ru_maxrss`` of the
child) is reported beside each l3 run, and for a folder of ``--memory-files``
synthetic 24-MP DNGs rendered to 16-bit TIFF.

A last table splits a file's CPU into stages, each timed alone (process CPU,
user + system, best of ``--repeat``) in one fresh process: the start-up
(imports of the render path, then loading the table and the kernels from
numba's cache), LibRaw's decode alone (``unpack``) and l3's whole read
(decode + normalisation + metadata) with LibRaw decoding and with l3's own
decoder of lossy DNGs, the render with display encoding, and
the JPEG and TIFF writes (atomic: temporary file, end check, fsync, rename).
The decode and render stages reuse the previous call's arrays
(:mod:`l3cli.buffers`), as every file after the first few of a folder does.
"""

from __future__ import annotations

import argparse
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

DEFAULT_DNG = REPO.parent / "shared" / "data" / "raw" / "misc" / "blackmagic_pocket4k_rggb.dng"
#: format -> (l3 --format, output suffix)
FORMATS = {"JPEG q95 4:4:4": ("jpg", ".jpg"), "TIFF 16-bit, uncompressed": ("tiff", ".tif"),
           "EXR float, uncompressed": ("exr", ".exr")}


# ----------------------------------------------------------------- the peer
def _encoder_spec(fmt: str, shape: tuple[int, ...]):
    """OpenImageIO spec of the benchmark's encoder settings for ``fmt``."""
    import OpenImageIO as oiio

    h, w = shape[:2]
    if fmt == "jpg":
        spec = oiio.ImageSpec(w, h, 3, "uint8")
        spec.attribute("Compression", "jpeg:95")
        spec.attribute("jpeg:subsampling", "4:4:4")
    else:
        spec = oiio.ImageSpec(w, h, 3, "uint16" if fmt == "tiff" else "float")
        spec.attribute("compression", "none")
    return spec


def _write(path: str, spec, data: np.ndarray) -> None:
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(path)
    out.open(path, spec)
    out.write_image(data)
    out.close()


def floor(fmt: str, out_dir: str, files: list[str]) -> None:
    """The floor process: what every renderer that decodes with LibRaw pays, and nothing else.

    Each file is decoded by LibRaw (``unpack``) and an image
    of the output's size is written with the benchmark's encoder settings,
    3 files at a time (l3's pipeline depth). The written image is made once,
    from the first file: its 2x2 CFA cells as RGB, shown at full size, so the
    encoder sees a photograph's content. No demosaicking, no colour: a
    renderer that cost nothing would take this long.
    """
    from concurrent.futures import ThreadPoolExecutor

    import rawpy

    with rawpy.imread(files[0]) as raw:
        m = raw.raw_image_visible.astype(np.float32) / np.float32(raw.white_level)
    h, w = (m.shape[0] // 2) * 2, (m.shape[1] // 2) * 2
    cells = m[:h, :w].reshape(h // 2, 2, w // 2, 2)
    rgb = np.stack([cells[:, 0, :, 0], cells[:, 0, :, 1], cells[:, 1, :, 1]], axis=-1)
    rgb = np.sqrt(np.clip(rgb * 4, 0, 1))  # quantised at half size, then shown at full size
    if fmt == "jpg":
        half = np.round(rgb * 255).astype(np.uint8)
    elif fmt == "tiff":
        half = np.round(rgb * 65535).astype(np.uint16)
    else:
        half = rgb.astype(np.float32)
    data = np.repeat(np.repeat(half, 2, axis=0), 2, axis=1)
    spec = _encoder_spec(fmt, data.shape)
    suffix = {"jpg": ".jpg", "tiff": ".tif"}.get(fmt, ".exr")

    def one(f: str) -> None:
        with rawpy.imread(f) as raw:
            raw.raw_image_visible.astype(np.float32)
        _write(str(Path(out_dir) / (Path(f).stem + suffix)), spec, data)

    with ThreadPoolExecutor(3) as pool:
        list(pool.map(one, files))


def peer(alg: str, fmt: str, out_dir: str, files: list[str]) -> None:
    """The peer process: rawpy (LibRaw) + OpenImageIO, one file after another."""
    import rawpy

    if alg == "floor":
        floor(fmt, out_dir, files)
        return
    algo = {"AHD": rawpy.DemosaicAlgorithm.AHD, "PPG": rawpy.DemosaicAlgorithm.PPG}[alg]
    for f in files:
        with rawpy.imread(f) as raw:
            if fmt == "jpg":
                data = raw.postprocess(demosaic_algorithm=algo, output_bps=8)
            elif fmt == "tiff":
                data = raw.postprocess(demosaic_algorithm=algo, output_bps=16)
            else:
                lin = raw.postprocess(demosaic_algorithm=algo, output_bps=16, gamma=(1, 1),
                                      no_auto_bright=True)
                data = lin.astype(np.float32) * np.float32(1 / 65535)
        path = str(Path(out_dir) / (Path(f).stem + {"jpg": ".jpg", "tiff": ".tif"}.get(fmt, ".exr")))
        _write(path, _encoder_spec(fmt, data.shape), data)


# ------------------------------------------------------------------ helpers
def _run(cmd: list[str]) -> tuple[float, float, float]:
    """Wall seconds, peak RSS (MB) and CPU seconds (user + system) of a child process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    dt = time.perf_counter() - t0
    err = proc.stderr.read().decode() if proc.stderr else ""
    proc.stderr.close() if proc.stderr else None
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:6])}... failed ({proc.returncode}): {err[-500:]}")
    return dt, usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime


def _l3_cmd() -> list[str]:
    exe = Path(sys.executable).parent / "l3"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "l3cli.cli.main"]


def _fresh(folder: Path) -> Path:
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    return folder


def photo_table():
    """``bench_render``'s table layout with kernels that render a photograph.

    Each class's kernel is the bilinear demosaic of its CFA position (the
    centre pixel, or the mean of its nearest neighbours of each channel in
    the 3x3 centre), then linear sRGB → XYZ, times an exposure gain, the same
    at every level. Render speed does not depend on the values (every kernel
    has all 26 taps), but the encoders do: a table of random kernels renders
    noise, whose JPEGs are 5x larger and slower to write than a photograph's.
    """
    from bench_render import bench_table

    from l3cli.colourspace import LINEAR_SRGB_TO_XYZ

    t = bench_table()
    d = t.definition
    s, r = d.patch, d.patch // 2
    group_kernel = np.zeros((d.n_groups, s * s + 1, 3))
    for pos in range(d.cfa.n_positions):
        nb = d.cfa.neighbourhood(pos, s)
        k = np.zeros((s * s + 1, 3), dtype=np.float64)
        for ch, name in enumerate("RGB"):
            c = d.cfa.channels.index(name)
            near = [(y, x) for y in range(r - 1, r + 2) for x in range(r - 1, r + 2)
                    if nb[y, x] == c and (nb[r, r] != c or (y, x) == (r, r))]
            for y, x in near:
                k[y * s + x, ch] = 1.0 / len(near)
        group_kernel[d.position_group[pos]] = 4.0 * k @ LINEAR_SRGB_TO_XYZ.T
    t.kernels[:] = group_kernel[d.class_tuple(np.arange(d.n_classes))[0]]
    return t


def table_file(folder: Path) -> Path:
    from l3cli.table import save_table

    return save_table(folder / "table.npz", photo_table())


def timing_tables(dng: Path, tmp: Path, copies: int, repeat: int) -> list[str]:
    src = tmp / "dngs"
    src.mkdir()
    files = []
    for i in range(copies):
        f = src / f"frame{i + 1:02d}.dng"
        shutil.copyfile(dng, f)
        files.append(str(f))
    table = str(table_file(tmp))
    me = [sys.executable, str(Path(__file__).resolve())]
    lines = [f"{copies} copies of `{dng.name}` (4128x2176, 9 MP), whole processes, best of "
             f"{repeat}, interleaved; peer = one Python process: rawpy (LibRaw) + OpenImageIO, "
             "same encoder settings.", "",
             "| output | l3 render | LibRaw AHD | LibRaw PPG | l3 vs AHD | l3 vs PPG "
             "| CPU s: l3 / AHD / PPG | l3 peak RSS | floor (decode + write) | AHD / floor |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    cases = [(name, fmt, files) for name, (fmt, _) in FORMATS.items()]
    cases.append(("one file → JPEG", "jpg", files[:1]))
    for name, fmt, fs in cases:
        best = {"l3": np.inf, "AHD": np.inf, "PPG": np.inf, "floor": np.inf}
        cpu = dict(best)
        rss = 0.0
        for _ in range(repeat):
            out = _fresh(tmp / "out")
            if len(fs) == 1:
                cmd = [*_l3_cmd(), "-q", "render", table, fs[0], "-o",
                       str(out / f"one{FORMATS_SUFFIX[fmt]}")]
            else:
                cmd = [*_l3_cmd(), "-q", "render", table, *fs, "-o", str(out), "--format", fmt]
            dt, mb, c = _run(cmd)
            best["l3"], cpu["l3"] = min(best["l3"], dt), min(cpu["l3"], c)
            rss = max(rss, mb)
            for alg in ("AHD", "PPG", "floor"):
                out = _fresh(tmp / "out")
                dt, _, c = _run([*me, "--peer", alg, fmt, str(out), *fs])
                best[alg], cpu[alg] = min(best[alg], dt), min(cpu[alg], c)
        lines.append(f"| {name} | {best['l3']:.2f} s | {best['AHD']:.2f} s | {best['PPG']:.2f} s "
                     f"| {best['AHD'] / best['l3']:.2f}x | {best['PPG'] / best['l3']:.2f}x "
                     f"| {cpu['l3']:.1f} / {cpu['AHD']:.1f} / {cpu['PPG']:.1f} "
                     f"| {rss:.0f} MB | {best['floor']:.2f} s "
                     f"| {best['AHD'] / best['floor']:.2f}x |")
        print(lines[-1], flush=True)
    return lines


FORMATS_SUFFIX = {fmt: suffix for fmt, suffix in FORMATS.values()}


def _cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def stages(dng: str, table_path: str, out_dir: str, repeat: int) -> None:
    """The stage child: prints ``name<TAB>cpu seconds`` lines (see the module notes)."""
    c0 = _cpu()
    import l3cli.cli.render  # noqa: F401 - the CLI's own imports
    import l3cli.io.image  # noqa: F401
    import l3cli.io.raw  # noqa: F401
    import l3cli.pipeline  # noqa: F401
    import l3cli.render  # noqa: F401
    c1 = _cpu()
    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw
    from l3cli.pipeline import _render_display, warm_up
    from l3cli.render import table_for_task

    table = table_for_task(table_path)
    warm_up(table, Path(out_dir) / "w.jpg")
    warm_up(table, Path(out_dir) / "w.tif")
    c2 = _cpu()
    print(f"start-up: imports (process start excluded)\t{c1 - c0:.3f}")
    print(f"start-up: table + kernels from numba's cache\t{c2 - c1:.3f}")

    def best(fn):
        fn()  # first use (allocator, page cache) not counted
        times = []
        for _ in range(repeat):
            c = _cpu()
            fn()
            times.append(_cpu() - c)
        return min(times)

    import rawpy

    def libraw_unpack():
        with rawpy.imread(dng) as rp:
            rp.raw_image_visible  # noqa: B018 - unpacks

    from l3cli import buffers

    raw = read_raw(dng)
    img8 = _render_display(table, raw.mosaic, 8)
    img16 = _render_display(table, raw.mosaic, 16)

    def decode():
        buffers.release(read_raw(dng).mosaic)

    def decode_libraw():
        buffers.release(read_raw(dng, libraw_only=True).mosaic)

    rows = [("decode: LibRaw unpack alone", libraw_unpack),
            ("decode: l3 read_raw, LibRaw decoding (+ normalise, metadata)", decode_libraw),
            ("decode: l3 read_raw (its decoder for lossy DNGs, else LibRaw)", decode),
            ("render + display encoding, 8-bit",
             lambda: buffers.release(_render_display(table, raw.mosaic, 8))),
            ("render + display encoding, 16-bit",
             lambda: buffers.release(_render_display(table, raw.mosaic, 16))),
            ("write JPEG q95 4:4:4 (OpenImageIO, atomic)",
             lambda: write_image(Path(out_dir) / "s.jpg", img8, space=table.output_space)),
            ("write TIFF 16-bit uncompressed (OpenImageIO, atomic)",
             lambda: write_image(Path(out_dir) / "s.tif", img16, space=table.output_space))]
    with buffers.recycling():  # the pipeline's buffer reuse
        for name, fn in rows:
            print(f"{name}\t{best(fn):.3f}", flush=True)


def stage_table(dng: Path, tmp: Path, repeat: int) -> list[str]:
    table = tmp / "table.npz"
    if not table.exists():
        table_file(tmp)
    out = _fresh(tmp / "stages")
    # one OpenBLAS thread, as `l3 render` asks for (l3cli.startup): spinning BLAS threads
    # would be counted as start-up CPU
    env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--stages", str(dng),
                           str(table), str(out), str(repeat)], cwd=REPO, capture_output=True,
                          text=True, check=True, env=env)
    lines = [f"CPU per stage, one 9-MP file (`{dng.name}`), each stage alone in one process, "
             f"best of {repeat} (user + system; the render uses every core):", "",
             "| stage | CPU s |", "|---|---|"]
    for row in proc.stdout.strip().splitlines():
        name, sec = row.split("\t")
        lines.append(f"| {name} | {float(sec):.3f} |")
    return lines


def memory_table(tmp: Path, size: str, n_files: int) -> list[str]:
    from bench_render import synthetic_mosaic

    from l3cli.io.raw import write_raw

    w, h = (int(v) for v in size.split("x"))
    mosaic = np.round(synthetic_mosaic(h, w) * 4095).astype(np.uint16)
    folder = _fresh(tmp / "big")
    files = [str(write_raw(folder / f"big{i}.dng", mosaic, "RGGB", white_level=4095))
             for i in range(n_files)]
    del mosaic
    table = str(tmp / "table.npz") if (tmp / "table.npz").exists() else str(table_file(tmp))
    out = _fresh(tmp / "bigout")
    dt, mb, _ = _run([*_l3_cmd(), "-q", "render", table, *files, "-o", str(out), "--format",
                      "tiff"])
    return [f"Peak memory, {n_files} synthetic {w}x{h} ({w * h / 1e6:.0f} MP) DNGs → 16-bit TIFF "
            f"in one `l3 render`: {mb:.0f} MB ({dt:.1f} s)."]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dng", default=str(DEFAULT_DNG))
    ap.add_argument("--copies", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--memory-size", default="6000x4000")
    ap.add_argument("--memory-files", type=int, default=3)
    ap.add_argument("--peer", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--stages", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--only-stages", action="store_true",
                    help="only the per-stage CPU table (needs the DNG)")
    a = ap.parse_args()
    if a.stages:
        stages(a.stages[0], a.stages[1], a.stages[2], int(a.stages[3]))
        return
    if a.peer:
        peer(a.peer[0], a.peer[1], a.peer[2], a.peer[3:])
        return
    tmp = Path(tempfile.mkdtemp(prefix="l3bench-files-"))
    try:
        dng = Path(a.dng)
        if dng.exists() and a.only_stages:
            print("\n".join(stage_table(dng, tmp, a.repeat)), flush=True)
            return
        if dng.exists():
            lines = timing_tables(dng, tmp, a.copies, a.repeat)
            print("", *stage_table(dng, tmp, a.repeat), sep="\n", flush=True)
        else:
            lines = [f"(skipped the file-to-file table: {dng} is not here; it is in the shared "
                     "data set, not in the repository — pass --dng PATH to a 9-MP DNG)"]
            print(lines[0], flush=True)
        if a.memory_files > 0:
            print("", *memory_table(tmp, a.memory_size, a.memory_files), sep="\n", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
