"""Run an exported model over a frame in strips, one per thread (numpy and onnxruntime only).

The graph renders a frame in bands already (:mod:`l3cli.export.bands`), one
after the other; ONNX Runtime spreads each operator of a band over its
threads, which synchronise once per operator. :func:`run_strips` instead
cuts the frame into horizontal strips, runs them on single-threaded
sessions in parallel threads (ONNX Runtime releases the GIL), and joins the
outputs: no synchronisation inside a strip, and no threads spinning while
they wait. Every strip is fed with the frame's rows its patches need beyond
it (:func:`strip_rows`), its first row on the table's CFA phase, so every
pixel's output is the one the whole frame gives (the classes bit for bit).
A model of a table with context bins (``l3.features``) is refused: their
guide is made of block means over the whole frame.

This module imports only numpy and onnxruntime, so it can be copied next to a
model and used without l3.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["run_strips", "strip_rows", "strip_session"]


def strip_session(model):
    """A single-threaded ONNX Runtime CPU session of ``model`` (a path or the bytes of a
    model), its threads not spinning while idle."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])


def strip_rows(height: int, strips: int, patch: int, period: int
               ) -> list[tuple[int, int, int, int]]:
    """``(top, bottom, feed_top, feed_bottom)`` of each strip: its own rows ``[top, bottom)``
    and the rows ``[feed_top, feed_bottom)`` fed for them (the strip and ``patch // 2``
    rows each side, rounded out to whole CFA periods); tops on whole periods."""
    margin = -(-(patch // 2) // period) * period
    step = max(period, -(-height // max(strips, 1) // period) * period)
    out = []
    for top in range(0, height, step):
        bottom = min(height, top + step)
        out.append((top, bottom, max(0, top - margin), min(height, bottom + margin)))
    return out


def run_strips(sess, mosaic: np.ndarray, *, threads: int | None = None,
               feeds: dict | None = None, frame: np.ndarray | None = None) -> np.ndarray:
    """The model's output (N, C, H, W) for the float32 mosaic (N, 1, H, W), strip by strip.

    ``sess``: a session of the model (:func:`strip_session`; its ``Run`` may be called from
    several threads at once). ``feeds``: its other inputs (``wb_gains``, ``condition``).
    ``frame``: where the mosaic lies on the full raw, ``(full height, full width, top,
    left)`` (models of tables with lens shading; default: the mosaic is the whole raw).
    ``threads``: strips run at once (default: the CPU count).
    """
    meta = sess.get_modelmeta().custom_metadata_map
    if any(f.startswith("context") for f in json.loads(meta.get("l3.features", "[]"))):
        raise ValueError("a model with context bins renders whole frames only (its guide is "
                         "made of block means over the frame): call sess.run")
    patch = int(meta["l3.patch"])
    period = len(meta["l3.cfa"].split("/"))
    n, _, h, w = mosaic.shape
    threads = threads or os.cpu_count() or 1
    names = {i.name for i in sess.get_inputs()}
    base = dict(feeds or {})
    if "frame" in names:
        full = np.zeros(4, np.int64) if frame is None else np.asarray(frame, np.int64).copy()
        if full[0] == 0:
            full[:] = (h, w, 0, 0)
    parts = strip_rows(h, threads, patch, period)

    def one(part):
        top, bottom, ft, fb = part
        run = {**base, "mosaic": np.ascontiguousarray(mosaic[:, :, ft:fb])}
        if "frame" in names:
            run["frame"] = np.array([full[0], full[1], full[2] + ft, full[3]], np.int64)
        return sess.run(None, run)[0][:, :, top - ft:bottom - ft]

    with ThreadPoolExecutor(max_workers=threads) as pool:
        outs = list(pool.map(one, parts))
    return np.concatenate(outs, axis=2)
