"""Figures explain themselves: labelled axes and colour bars, plain titles, readable log axes.

Each figure function is run on a small table or report, its Figure captured
as it is saved, and its texts checked: every axis and colour bar labelled, the
CFA position named by colour ("G at (0,1)") rather than by group number, no
overprinting tick labels (their drawn bounding boxes do not intersect).
"""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.figures import group_name, log_subs, plain_log_axis, pyplot
from tests.builders import plausible_table

BANNED = ("grp", "group 0", "saturated -", "n=", "b=", "samples/deg,")


@pytest.fixture
def captured(monkeypatch):
    """Figures passed to the modules' ``_save`` (kept open for inspection)."""
    import l3cli.evaluate.plots as ep
    import l3cli.plots_table as pt

    figs = []
    for mod in (pt, ep):
        orig = mod._save

        def keep(fig, path, _orig=orig):
            figs.append(fig)
            return _orig(fig, path)

        monkeypatch.setattr(mod, "_save", keep)
    yield figs
    for f in figs:
        pyplot().close(f)


def _texts(fig) -> list[str]:
    out = [fig._suptitle.get_text()] if fig._suptitle is not None else []
    for ax in fig.axes:
        out += [ax.get_title(), ax.get_xlabel(), ax.get_ylabel()]
    return [t for t in out if t]


def _renderer(fig):
    """A drawn Agg renderer of ``fig`` (also after ``pyplot.close``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _overlaps(texts, renderer) -> list[tuple[str, str]]:
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in texts
             if t.get_visible() and t.get_text()]
    return [(a, b) for i, (a, ba) in enumerate(boxes) for b, bb in boxes[i + 1:]
            if ba.overlaps(bb)]


def _tick_labels(axis):
    lo, hi = sorted(axis.get_view_interval())
    keep = [t for t in axis.get_ticklabels() + axis.get_ticklabels(minor=True)
            if lo * 0.999 <= (t.get_position()[0] if axis.axis_name == "x"
                              else t.get_position()[1]) <= hi * 1.001]
    return keep


def _check_log_axis(ax, which="x"):
    """No labelled minor tick, and no two tick labels drawn over each other."""
    r = _renderer(ax.figure)
    axis = ax.xaxis if which == "x" else ax.yaxis
    assert axis.get_scale() == "log"
    minor = [t.get_text() for t in axis.get_ticklabels(minor=True) if t.get_text()]
    assert minor == []
    labels = _tick_labels(axis)
    assert len([t for t in labels if t.get_text()]) >= 2
    assert _overlaps(labels, r) == []


# --------------------------------------------------------------------------- helpers


def test_overlap_check_sees_overprinted_labels():
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(3, 2))
    a = ax.text(0.5, 0.5, "2x10^-2")
    b = ax.text(0.52, 0.5, "3x10^-2")
    assert _overlaps([a, b], _renderer(fig))
    plt.close(fig)


@pytest.mark.parametrize("lo, hi", [(0.015, 0.4), (0.05, 0.5), (1e-3, 0.9), (1e-5, 1.0)])
def test_plain_log_axis_labels_do_not_overlap(lo, hi):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(3.5, 2.5))
    x = np.geomspace(lo, hi, 30)
    ax.plot(x, np.sqrt(x))
    ax.tick_params(labelsize=7)
    plain_log_axis(ax, "x", lo=lo, hi=hi)
    _check_log_axis(ax)
    texts = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
    assert not any("times" in t or "^" in t for t in texts)  # plain numbers, not 2x10^-2
    if hi / lo <= 10 ** 1.5:
        assert "0.1" in texts or "0.2" in texts  # a decade and a half gets 1, 2, 3, 5 marks
    plt.close(fig)


def test_log_subs_thin_out_with_the_span():
    assert log_subs(0.02, 0.2) == (1.0, 2.0, 3.0, 5.0)
    assert log_subs(1e-3, 1.0) == (1.0, 2.0, 5.0)
    assert log_subs(1e-6, 1.0) == (1.0,)
    assert log_subs(0.0, 1.0) == (1.0,)


def test_group_name_is_the_cfa_colour_and_place():
    from l3cli.classify import ClassDefinition

    d = ClassDefinition.build("GRBG", patch=5, level_cuts=np.array([0.5]))
    assert [group_name(d, g) for g in range(d.n_groups)] == [
        "G at (0,0)", "R at (0,1)", "B at (1,0)", "G at (1,1)"]
    merged = ClassDefinition.build("RGGB", patch=1, level_cuts=np.array([0.5]))
    names = [group_name(merged, g) for g in range(merged.n_groups)]
    assert any(n == "G at (0,1), (1,0)" for n in names), names  # 1x1 patches: both Gs alike


# --------------------------------------------------------------------------- table figures


def test_kernel_figures_label_every_panel(tmp_path, captured):
    from l3cli.plots_table import plot_kernels

    t = plausible_table("GRBG", patch=3, n_levels=6, seed=4)
    paths = plot_kernels(t, tmp_path, name="t")
    assert [p.exists() and p.stat().st_size > 5000 for p in paths] == [True] * len(paths)
    assert len(captured) == len(paths) >= 3
    for fig in captured:
        texts = _texts(fig)
        assert not [t for t in texts for b in BANNED if b in t], texts
        panels = [ax for ax in fig.axes if ax.get_images()]
        assert len(panels) == 4 * 3
        titles = [ax.get_title() for ax in panels]
        assert {ti.split(" →")[0] for ti in titles} == {"G at (0,0)", "R at (0,1)",
                                                         "B at (1,0)", "G at (1,1)"}
        assert all("samples" in ti or "empty" in ti or "filled" in ti for ti in titles)
        assert all("offset" in ti for ti in titles)
        assert {ax.get_xlabel() for ax in panels} == {"", "column offset (pixels)"}
        assert {ax.get_ylabel() for ax in panels} == {"", "row offset (pixels)"}
        bars = [ax for ax in fig.axes if not ax.get_images()]  # the colour bars
        assert sorted(ax.get_ylabel() for ax in bars) == [f"weight in output {c}"
                                                           for c in "XYZ"]
    sup = [fig._suptitle.get_text() for fig in captured]
    assert "no channel saturated" in sup[0]
    assert any("saturated," in s and "no channel" not in s for s in sup)  # the saturated class


def test_curve_figure_has_labelled_readable_log_axes(tmp_path, captured):
    from l3cli.plots_table import LEVEL_LABEL, plot_coefficient_curves
    from l3cli.smooth import smooth_table

    raw = plausible_table("RGGB", patch=3, n_levels=8, seed=5)
    (path,) = plot_coefficient_curves(smooth_table(raw), tmp_path, before=raw, name="s",
                                      before_name="raw.npz")
    assert path.exists() and path.stat().st_size > 5000
    (fig,) = captured
    texts = _texts(fig)
    assert not [t for t in texts for b in BANNED if b in t], texts
    assert "raw.npz" in fig._suptitle.get_text()
    axes = [ax for ax in fig.axes if ax.lines]
    assert len(axes) == 4 * 3
    assert axes[0].get_title() == "R at (0,0) → output X"
    assert {ax.get_xlabel() for ax in axes[-3:]} == {LEVEL_LABEL}
    assert all(ax.get_ylabel() == "weight or offset" for ax in axes[::3])
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend == ["sum of the R weights", "sum of the G weights", "sum of the B weights",
                      "centre pixel's weight", "offset"]
    for ax in axes[-3:]:
        _check_log_axis(ax, "x")


def test_tone_curve_figure(tmp_path, captured):
    from l3cli.colourspace import convert
    from l3cli.plots_table import plot_tone_curve
    from l3cli.tone.curve import KNOTS, ToneCurve

    t = plausible_table("GRBG", n_levels=4, seed=6)
    assert plot_tone_curve(t, tmp_path, name="t") == []  # no curve, no figure
    e = np.linspace(0.0, 1.0, KNOTS + 1)
    knots = np.repeat(np.asarray(convert(e[None, :, None].repeat(3, 2).astype(np.float32),
                                         "srgb", "linear-srgb"))[0, :, :1], 3, axis=1)
    knots = 0.01 + 0.99 * knots  # the dark end lifted, as the bundled camera's curve
    t.tone_lut = ToneCurve(knots.astype(np.float64)).lut("linear-srgb")
    t.output_space = "linear-srgb"
    (path,) = plot_tone_curve(t, tmp_path, name="t")
    assert path.name == "t_tone_curve.png" and path.stat().st_size > 5000
    (fig,) = captured
    lin, log = fig.axes
    for ax in (lin, log):
        assert ax.get_xlabel() == "kernel output (learned tone-curve space)"
        assert ax.get_ylabel() == "table output (linear-srgb)"
    _check_log_axis(log, "x")
    _check_log_axis(log, "y")


# --------------------------------------------------------------------------- evaluation figures


def _report():
    from l3cli.evaluate.metrics import ImageReport
    from l3cli.metrics.mtf import MTFResult
    from l3cli.metrics.scielab import SCIELABResult

    rng = np.random.default_rng(0)
    de = rng.gamma(2.0, 0.3, size=(120, 160))
    de[:3, :3] = 40.0  # a few outliers beyond the histogram's range
    sc = SCIELABResult(delta_e_ab=de, delta_e_2000=de * 0.8, samples_per_deg=66,
                       version="distribution")
    f = np.linspace(0, 1, 101)
    mtf = MTFResult(frequencies=f, mtf=np.exp(-2.5 * f), mtf50_cy_per_px=0.277,
                    mtf50_cy_per_mm=125.9, angle_deg=5.0, orientation="vertical")
    return ImageReport("shot.exr", {"scielab_mean": float(de.mean())}, scielab=sc, mtf=mtf)


def test_scielab_figure_titles_and_labels_do_not_overprint(tmp_path, captured):
    from l3cli.evaluate.plots import plot_report

    paths = plot_report(_report(), tmp_path, dpi=96, distance_m=1.0)
    assert sorted(p.name for p in paths) == ["shot_mtf.png", "shot_scielab.png"]
    sc_fig, mtf_fig = captured
    texts = _texts(sc_fig)
    assert not [t for t in texts for b in BANNED if b in t], texts
    m, h, bar = sc_fig.axes
    assert h.get_title().startswith(
        "S-CIELAB ΔE*ab per pixel (96 dpi at 1 m: 66 samples/degree)")
    assert h.get_xlabel() == "S-CIELAB ΔE*ab" and h.get_ylabel() == "pixels"
    assert bar.get_ylabel().startswith("ΔE*ab")
    legend = [t.get_text() for t in h.get_legend().get_texts()]
    assert any("not shown" in t for t in legend)  # the outliers are counted, not lost
    r = _renderer(sc_fig)
    # the colour bar's label and the histogram's axis label: no overprint
    assert not bar.yaxis.label.get_window_extent(r).overlaps(h.yaxis.label.get_window_extent(r))
    assert not bar.yaxis.label.get_window_extent(r).overlaps(h.get_window_extent(r))
    (ax,) = mtf_fig.axes
    assert ax.get_xlabel() == "spatial frequency (cycles/pixel)" and ax.get_ylabel()
    assert any("Nyquist" in t.get_text() for t in ax.get_legend().get_texts())
