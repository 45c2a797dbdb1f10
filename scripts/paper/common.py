"""Shared helpers of the paper experiments (``make paper``, scripts/paper/).

Every experiment module reads what the Makefile built under the build folder
(``paper_out/`` by default: simulations, tables, renders, ``l3 evaluate``
JSON reports), may run ``l3`` itself for grids that are awkward as Makefile
rules, and writes

* ``BUILD/sections/NAME.md``: its Markdown section of docs/results.md,
* ``BUILD/NAME.json``: its numbers (machine-readable),
* ``docs/figures/NAME_*.png``: its figures (small PNGs).

``scripts/paper/results.py`` assembles the sections into docs/results.md.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from l3cli.io.manifest import read_manifest

ROOT = Path(__file__).resolve().parents[2]
FIGURES = ROOT / "docs" / "figures"


def l3_exe() -> str:
    """The ``l3`` executable: ``$L3``, else the venv's, else the one on PATH."""
    env = os.environ.get("L3")
    if env:
        return env
    venv = ROOT / ".venv" / "bin" / "l3"
    if venv.exists():
        return str(venv)
    found = shutil.which("l3")
    if not found:
        raise SystemExit("l3 not found: run `make setup` or set L3=/path/to/l3")
    return found


def run_l3(*args: Any, quiet: bool = True) -> float:
    """Run ``l3 ARGS`` (stops on failure); returns the wall-clock seconds."""
    cmd = [l3_exe()] + (["-q"] if quiet else []) + [str(a) for a in args]
    print("+ l3 " + " ".join(cmd[1:]), file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    return time.perf_counter() - t0


def raws_of(sim_dir: Path, *, scene: str | None = None) -> list[Path]:
    """Raw files of a simulation folder (from its manifest), optionally one scene only."""
    man = read_manifest(sim_dir)
    return [Path(sim_dir) / c["raw"] for c in man["captures"]
            if scene is None or c["scene"] == scene]


def captures(sim_dir: Path) -> dict[str, dict]:
    """``{stem: capture record}`` of a simulation folder's manifest."""
    man = read_manifest(sim_dir)
    return {c["stem"]: c for c in man["captures"]}


def report(path: Path) -> dict[str, dict]:
    """``{image name: metrics}`` of an ``l3 evaluate --json`` report."""
    rep = json.loads(Path(path).read_text())
    return {im["name"]: im for im in rep["images"]}


def by_scene(rep: dict[str, dict], sim_dir: Path, scene: str, key: str) -> dict[float, float]:
    """``{lux: metric}`` for the captures of ``scene`` in a report of ``sim_dir``."""
    caps = captures(sim_dir)
    out = {}
    for stem, cap in caps.items():
        if cap["scene"] == scene and stem in rep and rep[stem].get(key) is not None:
            out[float(cap["lux"])] = float(rep[stem][key])
    return dict(sorted(out.items()))


def pyplot():
    """matplotlib.pyplot on the Agg backend, with small defaults."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 8, "axes.grid": True, "grid.alpha": 0.3})
    return plt


def save_figure(fig, name: str) -> str:
    """Save ``fig`` as docs/figures/NAME.png (small, 100 dpi); returns the relative link."""
    from l3cli.io.atomic import atomic_path

    FIGURES.mkdir(parents=True, exist_ok=True)
    path = FIGURES / f"{name}.png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    pyplot().close(fig)
    return f"figures/{name}.png"


def write_outputs(build: Path, name: str, markdown: str, numbers: dict) -> None:
    """Write BUILD/sections/NAME.md and BUILD/NAME.json (atomically)."""
    from l3cli.io.atomic import atomic_path

    (build / "sections").mkdir(parents=True, exist_ok=True)
    with atomic_path(build / "sections" / f"{name}.md") as tmp:
        tmp.write_text(markdown.rstrip() + "\n", encoding="utf-8")
    with atomic_path(build / f"{name}.json") as tmp:
        tmp.write_text(json.dumps(numbers, indent=1, default=float) + "\n", encoding="utf-8")


def md_table(header: list[str], rows: list[list[Any]]) -> str:
    """A Markdown table; floats with 2 decimals, None as an en dash."""
    def fmt(v: Any) -> str:
        if v is None:
            return "–"
        if isinstance(v, float):
            return f"{v:.2f}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(fmt(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def train_render_eval(build: Path, name: str, camera: str, *, train_opts: tuple = (),
                      smooth: bool = True, scenes: tuple[str, ...] | None = None,
                      train_sim: Path | None = None, test_sim: Path | None = None,
                      eval_raw: bool = False) -> dict:
    """Train (and smooth) a table on a camera's training captures, render its
    test captures (``scenes`` only, if given) and evaluate them.

    Files go to ``BUILD/runs/NAME/``. Returns ``{"report": {stem: metrics},
    "report_raw" (the table before smoothing, with ``eval_raw``, else None),
    "train_s", "smooth_s", "render_s", "pixels"}`` (wall-clock seconds).
    """
    train_sim = train_sim or build / "sim" / camera / "train"
    test_sim = test_sim or build / "sim" / camera / "test"
    out = build / "runs" / name
    if out.exists():
        shutil.rmtree(out)
    (out / "render").mkdir(parents=True)
    raw_table = out / "table.raw.npz"
    t_train = run_l3("train", train_sim, "-o", raw_table, "--seed", 1, *train_opts)
    table, t_smooth = raw_table, 0.0
    if smooth:
        table = out / "table.npz"
        t_smooth = run_l3("smooth", raw_table, "-o", table)
    raws = [r for s in (scenes or (None,)) for r in raws_of(test_sim, scene=s)]
    t_render = run_l3("render", table, *raws, "-o", out / "render")
    rep = evaluate_robust(out / "render", test_sim, out / "eval.json")
    rep_raw = None
    if smooth and eval_raw:
        run_l3("render", raw_table, *raws, "-o", out / "render_raw")
        rep_raw = evaluate_robust(out / "render_raw", test_sim, out / "eval_raw.json")
    caps = captures(test_sim)
    pixels = sum(caps[r.stem]["width"] * caps[r.stem]["height"] for r in raws)
    return {"report": rep, "report_raw": rep_raw, "train_s": t_train, "smooth_s": t_smooth,
            "render_s": t_render, "pixels": pixels, "table": table}


def evaluate_robust(render_dir: Path, sim: Path, json_path: Path) -> dict[str, dict]:
    """``l3 evaluate RENDER_DIR --reference SIM --json JSON``; returns the report.

    If the folder fails as a whole (``l3 evaluate`` stops at the first image
    whose slanted edge it cannot find), each render is evaluated on its own and
    the images that still fail are left out of the report (with a warning).
    """
    try:
        run_l3("evaluate", render_dir, "--reference", sim, "--json", json_path)
        return report(json_path)
    except subprocess.CalledProcessError:
        print(f"warning: l3 evaluate failed on {render_dir} as a whole; evaluating image by image",
              file=sys.stderr)
    merged = {}
    for f in sorted(Path(render_dir).glob("*.exr")):
        one = json_path.with_name(f"{json_path.stem}_{f.stem}.json")
        try:
            run_l3("evaluate", f, "--reference", sim, "--json", one)
        except subprocess.CalledProcessError:
            print(f"warning: {f.name} left out of the report", file=sys.stderr)
            continue
        merged.update(report(one))
    json_path.write_text(json.dumps({"images": list(merged.values())}, indent=1) + "\n")
    return merged


def plain_log(ax, *, x: bool = False, y: bool = True) -> None:
    """Log axes with plain-number tick labels (2, 5, 10 rather than 2×10⁰)."""
    from matplotlib.ticker import FuncFormatter, LogLocator

    fmt = FuncFormatter(lambda v, _: f"{v:g}")
    for flag, axis, setter in ((x, ax.xaxis, ax.set_xscale), (y, ax.yaxis, ax.set_yscale)):
        if flag:
            setter("log")
            axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(fmt)
            axis.set_minor_formatter(FuncFormatter(lambda v, _: ""))


def patch_electrons(sim_dir: Path, stem: str):
    """Noise-free photo-electrons per channel on the 24 Macbeth patches of a capture.

    The mean of each channel's noise-free response over the inner half of each
    patch, less the dark-current mean (dark current x exposure time; already
    out of the raw for a camera with ``readout.black_clamp``), in electrons at
    the capture's own analog gain: a (24, channels) array, channels in the
    CFA's order.
    """
    import numpy as np

    from l3cli.cfa import CFA
    from l3cli.io.image import read_image

    man = read_manifest(sim_dir)
    cam, cap = man["camera"], captures(sim_dir)[stem]
    px, ro = cam["pixel"], cam["readout"]
    gain = cap.get("analog_gain", ro["analog_gain"])  # auto ISO raises it per capture
    volts_per_e = gain * px["conversion_gain_uv_per_e"] * 1e-6 / px["voltage_swing_v"]
    cfa = CFA.from_spec(cam["cfa_pattern"])
    nf, _ = read_image(Path(sim_dir) / cap["noise_free"])
    nf = nf.reshape(nf.shape[0], nf.shape[1]).astype(np.float64) / volts_per_e
    if not ro.get("black_clamp", False):
        nf -= px["dark_current_e_per_s"] * cap["exposure_s"]
    cmap = cfa.channel_map(*nf.shape)
    out = []
    for x0, y0, x1, y1 in cap["chart"]["patches"]:
        dx, dy = (x1 - x0) // 4, (y1 - y0) // 4
        sl = np.s_[y0 + dy:y1 - dy, x0 + dx:x1 - dx]
        out.append([nf[sl][cmap[sl] == c].mean() for c in range(cfa.n_channels)])
    return np.asarray(out)


def linear_colour_floor(sim_dir: Path, *, pieces: int = 1) -> tuple[float, str]:
    """Mean Macbeth ΔE*ab of the best linear map(s) from the camera's channels to XYZ.

    Takes the brightest test Macbeth capture of ``sim_dir`` whose noise-free
    response stays below 0.95 (no saturation), averages each channel's
    noise-free response over the inner half of each of the 24 patches,
    subtracts the dark-current mean (the manifest's dark current x exposure
    time: the noise-free image contains it unless the camera clamps its black,
    the ideal XYZ does not), fits a
    linear map (channels → XYZ, least squares over the patches, no offset) to
    the patches' ideal XYZ, and scores it like ``l3 evaluate`` (white-normalised
    ΔE*ab with the ideal white patch as white point). No noise, no
    demosaicking: the Luther-Ives floor of a single linear colour transform.

    With ``pieces`` > 1 the patches are split into that many groups by their
    mean response (equal counts, dark to bright) and each group gets its own
    map: a piecewise-linear map over response levels, as L3 uses (one kernel
    per level). It is fitted and scored on the same patches (in sample), so it
    shows how far below the single-map floor a per-level map can go, not what
    L3 reaches on unseen data; the single-map floor therefore does not bound L3.

    Returns (mean ΔE*ab, stem of the capture used).

    References
    ----------
    Wandell, B. A. (1995). Foundations of Vision, ch. 4 (colour matching and
    the Luther condition).
    """
    import colour
    import numpy as np

    from l3cli.io.image import read_image

    man = read_manifest(sim_dir)
    best = None
    for cap in sorted(man["captures"], key=lambda c: c["lux"]):
        if cap["scene"] != "macbeth":
            continue
        nf, _ = read_image(Path(sim_dir) / cap["noise_free"])
        if nf.max() < 0.95:
            best = cap
    if best is None:
        raise SystemExit(f"{sim_dir}: every Macbeth capture saturates")
    cap = best
    a = patch_electrons(sim_dir, cap["stem"])
    ref = np.asarray(cap["chart"]["reference_xyz"], dtype=np.float64)
    est = np.empty_like(ref)
    order = np.argsort(a.mean(axis=1))
    for group in np.array_split(order, pieces):
        m, *_ = np.linalg.lstsq(a[group], ref[group], rcond=None)
        est[group] = a[group] @ m
    wi = cap["chart"]["white_index"]
    est = est * (ref[wi, 1] / est[wi, 1])
    white = ref[wi] / ref[wi, 1]
    lab_est = colour.XYZ_to_Lab(est / ref[wi, 1], colour.XYZ_to_xy(white))
    lab_ref = colour.XYZ_to_Lab(ref / ref[wi, 1], colour.XYZ_to_xy(white))
    return float(np.mean(colour.delta_E(lab_est, lab_ref, method="CIE 1976"))), cap["stem"]


def build_arg(doc: str | None) -> Path:
    """The BUILD folder from the command line (``script.py BUILD``); prints ``doc`` otherwise."""
    if len(sys.argv) != 2 or sys.argv[1].startswith("-"):
        raise SystemExit(doc)
    return Path(sys.argv[1])
