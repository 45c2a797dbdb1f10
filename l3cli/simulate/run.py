"""Write a simulation directory: raw mosaics, ideal targets, noise-free responses, manifest.

Each capture is one map task (:func:`capture_task`: build the scene, simulate,
write the files), run in process or on a dask.distributed cluster
(:func:`l3cli.parallel.map_reduce`). Everything is first written into a temporary folder next to ``SIM_DIR`` and
moved into place only when every capture succeeded, the manifest last; on any
error the temporary folder is removed and ``SIM_DIR`` is left as it was.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from l3cli import spectral
from l3cli.camera import Camera
from l3cli.errors import ConfigError, OutputError
from l3cli.io.atomic import forget_temporary, make_temp_dir
from l3cli.io.manifest import MANIFEST_FORMAT, MANIFEST_NAME, MANIFEST_VERSION, write_manifest
from l3cli.parallel import map_reduce
from l3cli.simulate.core import (
    TARGET_SCALE_DOC,
    CameraModel,
    Capture,
    capture_stem,
    illuminant_irradiance,
    prepare_camera,
    simulate_capture,
)
from l3cli.simulate.scenes import check_scene_name, expand_scene_names, make_scene

__all__ = ["run_simulation", "DEFAULT_SCENES", "DEFAULT_SIZE", "MANIFEST_FORMAT",
           "MANIFEST_VERSION", "dng_colour_matrix", "write_capture", "CaptureJob", "capture_task"]

log = logging.getLogger(__name__)

DEFAULT_SCENES: tuple[str, ...] = ("macbeth", "natural")
DEFAULT_SIZE: tuple[int, int] = (480, 320)
MIN_SIZE = (48, 32)


def dng_colour_matrix(model: CameraModel) -> tuple[np.ndarray, np.ndarray] | None:
    """ColorMatrix1 (XYZ → camera, D65) for a 3-colour camera, fitted on the Macbeth chart.

    Returns ``(matrix, camera_white_d65)`` or None when the CFA is not R, G, B
    (or D65 does not cover the camera's wavelengths: then the visible+IR
    daylight ``visir-DAY`` is used).
    """
    ch = model.channels
    if sorted(ch) != ["B", "G", "R"]:
        return None
    wl = model.wavelengths
    ill = "D65" if _covers("D65", wl) else "visir-DAY"
    e = illuminant_irradiance(ill, 1000.0, wl)
    refl = spectral.macbeth_reflectances(wl)  # (N, 24)
    order = [ch.index(c) for c in ("R", "G", "B")]
    photons = e * wl
    cam = (refl * photons[:, None]).T @ model.qe[:, order]  # (24, 3)
    xyz = (refl * e[:, None]).T @ model.cmfs  # (24, 3)
    m, *_ = np.linalg.lstsq(xyz, cam, rcond=None)  # xyz @ m ≈ cam
    mat = m.T  # XYZ → camera
    white_xyz = model.cmfs.T @ e
    white_cam = mat @ white_xyz
    mat = mat / np.max(white_cam / white_xyz[1])  # D65 white (Y = 1) → max channel 1
    return mat, photons @ model.qe[:, order]


#: A channel whose response to a white under the scene light is below this
#: fraction of the strongest channel's is warned about (an RGB-NIR camera that
#: kept a Bayer camera's IR-cut filter: its NIR channel gets ~1 %).
WEAK_CHANNEL = 0.05


def channel_responses(model: CameraModel, illuminant: str) -> np.ndarray:
    """Relative response of each CFA channel to a perfect white under ``illuminant``.

    Photo-electrons per channel (irradiance x wavelength x effective QE, the IR-cut
    filter included), divided by the strongest channel's: the strongest is 1.
    """
    wl = model.wavelengths
    resp = (illuminant_irradiance(illuminant, 1.0, wl) * wl) @ model.qe
    top = float(np.max(resp))
    return resp / top if top > 0 else resp


def warn_weak_channels(model: CameraModel, illuminant: str) -> list[str]:
    """Warn about channels that hardly respond (:data:`WEAK_CHANNEL`); their names."""
    cam = model.camera
    rel = channel_responses(model, illuminant)
    best = model.channels[int(np.argmax(rel))]
    weak = []
    for name, r in zip(model.channels, rel, strict=True):
        if r < WEAK_CHANNEL:
            weak.append(name)
            log.warning(
                "%s: channel %s responds at %.1f %% of channel %s under %s: check its QE curve "
                "(cfa.qe), the IR-cut filter (cfa.ir_cut = %r) and the spectrum (%g-%g nm)",
                cam.file or cam.name, name, 100 * r, best, illuminant, cam.cfa.ir_cut,
                cam.spectrum.start_nm, cam.spectrum.stop_nm)
    return weak


def _covers(name: str, wl: np.ndarray) -> bool:
    try:
        spectral.load_illuminant(name, wl)
    except ConfigError:
        return False
    return True


def write_capture(folder: Path, cap: Capture, model: CameraModel) -> dict[str, Any]:
    """Write one capture's files into ``folder``; return its manifest entry."""
    from l3cli.io.image import write_image
    from l3cli.io.raw import write_raw

    cam = model.camera
    ro = cam.readout
    cmat = dng_colour_matrix(model)
    kwargs: dict[str, Any] = {}
    if cmat is not None:
        mat, _ = cmat
        wl = model.wavelengths
        neutral = None
        if cap.illuminant:
            e = illuminant_irradiance(cap.illuminant, 1.0, wl)
            ch = model.channels
            order = [ch.index(c) for c in ("R", "G", "B")]
            resp = (e * wl) @ model.qe[:, order]
            neutral = resp / resp.max()
        kwargs = {"color_matrix": mat, "as_shot_neutral": neutral}
    raw_path = write_raw(folder / f"{cap.stem}.dng", cap.dn, cam.cfa.cfa,
                         black_level=float(ro.black_level_dn), white_level=float(ro.white_level_dn),
                         make="l3", model=f"simulated {cam.name}",
                         description=f"l3 simulate: {cap.stem}",
                         shot=_shot(cam, cap), **kwargs)
    target = folder / f"{cap.stem}.target.exr"
    write_image(target, cap.target, space="xyz")
    nf = folder / f"{cap.stem}.noisefree.exr"
    write_image(nf, cap.noise_free, space="data")
    h, w = cap.dn.shape
    entry: dict[str, Any] = {
        "stem": cap.stem,
        "raw": raw_path.name,
        "target": target.name,
        "noise_free": nf.name,
        "scene": cap.scene,
        "illuminant": cap.illuminant,
        "lux": cap.lux,
        "exposure_s": cap.exposure_s,
        "analog_gain": cap.analog_gain,
        "width": int(w),
        "height": int(h),
        "seed": cap.seed,
        "black_level": float(ro.black_level_dn),
        "white_level": float(ro.white_level_dn),
        "chart": cap.chart,
        "edge": cap.edge,
    }
    if raw_path.suffix.lower() != ".dng":
        entry["raw_sidecar"] = raw_path.name + ".toml"
    for k in ("white_xyz", "photometric_exposure_white_lux_s"):
        if k in cap.extra:
            entry[k] = cap.extra[k]
    return entry


def _shot(cam: Any, cap: Any) -> dict[str, Any]:
    """Shot metadata of a capture's raw: exposure time, and for a camera with
    auto gain (``exposure.max_analog_gain`` > 1) the ISO, 100 x analog gain."""
    shot: dict[str, Any] = {"exposure_time": float(cap.exposure_s)}
    if cam.exposure.mode == "auto" and cam.exposure.max_analog_gain > 1:
        shot["iso"] = int(round(100 * cap.analog_gain))
    return shot


def _commit(tmp: Path, out_dir: Path) -> None:
    umask = os.umask(0)
    os.umask(umask)
    for p in tmp.iterdir():
        os.chmod(p, 0o666 & ~umask)
    os.chmod(tmp, 0o777 & ~umask)
    if not out_dir.exists():
        os.replace(tmp, out_dir)
        return
    if not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a folder")
    names = sorted(p.name for p in tmp.iterdir() if p.name != MANIFEST_NAME)
    for n in names:
        os.replace(tmp / n, out_dir / n)
    os.replace(tmp / MANIFEST_NAME, out_dir / MANIFEST_NAME)
    shutil.rmtree(tmp, ignore_errors=True)


def run_simulation(
    camera: Camera,
    out_dir: str | os.PathLike,
    *,
    scenes: Sequence[str] | None = None,
    illuminant: str | None = None,
    lux: Sequence[float] | None = None,
    seed: int = 0,
    size: tuple[int, int] | None = None,
    blur: bool = True,
    noise: bool = True,
    exposure_s: float | None = None,
    oversample: int = 1,
    on_capture: Callable[[int, int, str], None] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    show_progress: bool | None = False,
    protect: Sequence[str | os.PathLike] = (),
) -> dict[str, Any]:
    """Simulate every (scene, light level) capture of a camera into ``out_dir``.

    Parameters
    ----------
    camera
        From :func:`l3cli.camera.load_camera`.
    out_dir
        SIM_DIR; created if missing (its parent must exist and be writable).
        Files of the same names are replaced; the manifest lists this run.
    scenes
        Scene names or paths (default :data:`DEFAULT_SCENES`); ``natural``
        expands to every bundled photo.
    illuminant
        Illuminant name (default: the camera's ``exposure.illuminant``).
    lux
        Light levels in lux (default: the camera's ``exposure.light_levels_lux``).
    seed
        Noise seed; each capture draws from (seed, stem).
    size
        (width, height) in pixels (default :data:`DEFAULT_SIZE`).
    blur, noise, exposure_s
        Switch off the optics blur or the noise, or fix the exposure time.
    oversample
        Scene samples per pixel and axis (1-8) for the optics; the pixel
        aperture then averages them. 1 applies the OTF at the pixel grid.
    on_capture
        Progress callback ``(index, total, stem)`` called after each capture
        (in capture order).
    workers, scheduler
        Simulate the captures on a local dask cluster of this many workers, or
        on the running scheduler at this address (default: in process). Each
        capture is one :func:`capture_task`; its noise depends only on
        ``(seed, stem)``, so the files and the manifest are the same whichever
        way the captures run.
    show_progress
        Progress bar on stderr.
    protect
        Input files (the camera TOML, scene images) that no output may replace.

    Returns
    -------
    dict
        The manifest.

    Raises
    ------
    ConfigError, InputError, OutputError
        Bad scene/illuminant/lux/size, unreadable scene file, unwritable output.
    """
    out_dir = Path(out_dir)
    width, height = size or DEFAULT_SIZE
    if width < MIN_SIZE[0] or height < MIN_SIZE[1] or width > 20000 or height > 20000:
        raise ConfigError(f"size {width}x{height} is out of range; allowed: "
                          f"{MIN_SIZE[0]}x{MIN_SIZE[1]} to 20000x20000")
    check_capture_memory(width, height, oversample)
    names = expand_scene_names(list(scenes or DEFAULT_SCENES))
    for n in names:
        check_scene_name(n)
    ill = illuminant or camera.exposure.illuminant
    levels = [float(x) for x in (lux if lux else camera.exposure.light_levels_lux)]
    for x in levels:
        if not (np.isfinite(x) and 0 < x <= 1e6):
            raise ConfigError(f"--lux must be in (0, 1e6] lux, got {x:g}")
    if exposure_s is not None and not (np.isfinite(exposure_s) and 0 < exposure_s <= 3600):
        raise ConfigError(f"--exposure must be in (0, 3600] seconds, got {exposure_s:g}")
    model = prepare_camera(camera)
    illuminant_irradiance(ill, 1.0, model.wavelengths)  # unknown / range errors now
    warn_weak_channels(model, ill)
    parent = out_dir.parent if str(out_dir.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{out_dir}: parent folder {parent} does not exist")
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK) or (out_dir.is_dir() and not os.access(out_dir, os.W_OK | os.X_OK)):
        raise OutputError(f"{out_dir}: output folder is not writable")
    stems = [capture_stem(_scene_label(n), ill, x) for n in names for x in levels]
    if len(set(stems)) != len(stems):
        dup = next(s for s in stems if stems.count(s) > 1)
        raise ConfigError(f"two captures would both be named {dup!r}; give distinct scenes and light levels")
    if protect:
        from l3cli.io.paths import refuse_overwrite

        outs = [MANIFEST_NAME] + [f"{s}{ext}" for s in stems for ext in
                                    (".dng", ".tif", ".tif.toml", ".target.exr", ".noisefree.exr")]
        refuse_overwrite([(out_dir / n, "-o") for n in outs], protect)

    tmp = make_temp_dir(parent, out_dir.name)
    try:
        remote = workers is not None or scheduler is not None
        folder = str(tmp.absolute()) if remote else str(tmp)
        jobs = [CaptureJob(camera=camera, folder=folder, scene=n, height=height, width=width,
                           oversample=oversample, illuminant=ill, lux=x, seed=int(seed),
                           stem=capture_stem(_scene_label(n), ill, x), blur=blur, noise=noise,
                           exposure_s=exposure_s)
                for n in names for x in levels]
        captures: list[dict[str, Any]] = []
        total = len(jobs)

        def collect(acc: None, entry: dict[str, Any]) -> None:
            captures.append(entry)
            if on_capture is not None:
                on_capture(len(captures), total, entry["stem"])

        map_reduce(capture_task, jobs, reduce=collect, workers=workers, scheduler=scheduler,
                   label="simulate", show_progress=show_progress)
        manifest = {
            "format": MANIFEST_FORMAT,
            "version": MANIFEST_VERSION,
            "camera": {**camera.to_dict(), "target_h_ref_lux_s": model.h_ref,
                       "saturation_e": model.sat_e, "dn_per_electron": model.dn_per_e,
                       "channels": list(model.channels)},
            "target": {"space": "xyz", "observer": "CIE 1931 2 degree",
                       "scale": TARGET_SCALE_DOC.format(h_ref=model.h_ref),
                       "h_ref_lux_s": model.h_ref},
            "noise_free": "linear sensor response without noise or fixed-pattern noise, "
                          "full-well clipped, same normalisation as the raw (0 black, 1 white level)",
            "options": {"seed": int(seed), "blur": blur, "noise": noise, "oversample": oversample,
                        "illuminant": ill, "lux": levels, "scenes": names,
                        "width": width, "height": height},
            "captures": captures,
        }
        write_manifest(tmp, manifest)
        _commit(tmp, out_dir)
        forget_temporary(tmp)
    except BaseException:
        _remove_folder(tmp)
        raise
    return manifest


#: Peak memory of one capture per output pixel (per scene sample with --oversample):
#: measured with /usr/bin/time on 480x320 and 1920x1280 captures (macbeth and natural
#: scenes: 85-108 bytes per added pixel), rounded up.
CAPTURE_BYTES_PER_PIXEL = 120


def check_capture_memory(width: int, height: int, oversample: int = 1) -> None:
    """Refuse a capture size whose simulation cannot fit in the available memory.

    Raises
    ------
    ConfigError
        Naming ``--size`` and the estimate (one capture at a time is held per
        process), instead of "out of memory" part way through.
    """
    from l3cli.buffers import available_memory

    need = int(width) * int(height) * int(oversample) ** 2 * CAPTURE_BYTES_PER_PIXEL
    have = available_memory()
    if need > have:
        gib = 1 << 30
        raise ConfigError(f"--size {width}x{height}"
                          f"{f' with --oversample {oversample}' if oversample > 1 else ''} "
                          f"needs about {need / gib:,.1f} GiB of memory per capture, more "
                          f"than the {have / gib:,.1f} GiB available; use a smaller --size")


def _remove_folder(folder: Path, attempts: int = 20) -> None:
    """Remove the run's temporary folder, again while something still writes into it.

    On a running cluster a capture task cancelled by a failed job may still be
    executing (dask does not interrupt running tasks) and create a file while
    the folder is being removed; once the folder is gone its writes fail
    (:func:`l3cli.io.atomic.atomic_path` needs the folder), so a few attempts
    leave nothing behind.
    """
    import time

    for _ in range(attempts):
        with contextlib.suppress(OSError):
            shutil.rmtree(folder)
        if not folder.exists():
            return
        time.sleep(0.05)


def _scene_label(name: str) -> str:
    if name.startswith("natural:"):
        return name.split(":", 1)[1]
    if name in ("macbeth", "slanted-edge"):
        return name
    from l3cli.simulate.scenes import _stem_name

    return _stem_name(Path(name))


@dataclass(frozen=True)
class CaptureJob:
    """One capture to simulate (a small, picklable description; no pixels).

    ``folder`` is where the task writes the capture's files (the run's
    temporary folder); the other fields are the arguments of
    :func:`~l3cli.simulate.scenes.make_scene` and
    :func:`~l3cli.simulate.core.simulate_capture`.
    """

    camera: Camera
    folder: str
    scene: str
    height: int
    width: int
    oversample: int
    illuminant: str
    lux: float
    seed: int
    stem: str
    blur: bool = True
    noise: bool = True
    exposure_s: float | None = None


def capture_task(job: CaptureJob) -> dict[str, Any]:
    """Simulate one capture and write its files into ``job.folder`` (a map task).

    Returns
    -------
    dict
        The capture's manifest entry.
    """
    model = prepare_camera(job.camera)
    scene = make_scene(job.scene, job.height, job.width, model.wavelengths,
                       oversample=job.oversample)
    scene.name = _scene_label(job.scene)
    cap = simulate_capture(model, scene, illuminant=job.illuminant, lux=job.lux, seed=job.seed,
                           stem=job.stem, blur=job.blur, noise=job.noise,
                           exposure_s=job.exposure_s)
    entry = write_capture(Path(job.folder), cap, model)
    log.info("simulated %s (exposure %.4g s)", job.stem, cap.exposure_s)
    return entry
