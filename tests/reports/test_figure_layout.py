"""GridLayoutEngine (dynid.reports.figure_layout) against matplotlib's constrained layout."""
from __future__ import annotations

import re

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine

from dynid.reports import figures as F
from dynid.reports.figure_layout import GridLayoutEngine


def _panels(rows=2, cols=3, legend=True, suptitle=True):
    """A report-like grid of panels: long y tick labels on some, titles, a figure legend."""
    with matplotlib.rc_context(F.STYLE):
        fig = Figure(figsize=(3.3 * cols, 1.9 * rows + 0.3), layout="constrained")
        axes = fig.subplots(rows, cols, squeeze=False)
        t = np.linspace(0, 20, 50)
        for j, ax in enumerate(axes.flat):
            ax.plot(t, (10.0 ** (j - 2)) * np.sin(t + j), label="measured")
            ax.set_title(f"joint {j + 1}: JB p = 0.0{j}", loc="left")
            if j % cols == 0:
                ax.set_ylabel("torque [N m]")
            if j >= (rows - 1) * cols:
                ax.set_xlabel("time [s]")
        if legend:
            fig.legend(*axes.flat[0].get_legend_handles_labels(), loc="outside upper right", frameon=False)
        if suptitle:
            fig.suptitle("a suptitle")
    return fig


def _positions(fig):
    FigureCanvasAgg(fig)
    fig.draw_without_rendering()
    px = np.array([fig.bbox.width, fig.bbox.height] * 2)
    return np.array([ax.get_position().bounds for ax in fig.axes]) * px


def test_grid_engine_places_panels_as_the_constrained_layout():
    """Same panel rectangles as matplotlib's engine (to a fraction of a pixel), with a figure
    legend outside and a suptitle."""
    ref, ours = _panels(), _panels()
    default = np.array([ax.get_position(original=True).bounds for ax in ref.axes])
    ours.set_layout_engine(GridLayoutEngine.like(ref.get_layout_engine(), thin=False))
    assert isinstance(ref.get_layout_engine(), ConstrainedLayoutEngine)
    a, b = _positions(ref), _positions(ours)
    assert np.abs(a - b).max() < 0.5, np.abs(a - b).max()
    px = np.array([ref.bbox.width, ref.bbox.height] * 2)
    assert np.abs(default * px - a).max() > 5          # the layout did move them


def test_spanning_panels_fall_back_to_the_constrained_layout():
    with matplotlib.rc_context(F.STYLE):
        figs = []
        for _ in range(2):
            fig = Figure(figsize=(6, 4), layout="constrained")
            gs = fig.add_gridspec(2, 2)
            fig.add_subplot(gs[0, :]).set_ylabel("spans two columns")
            fig.add_subplot(gs[1, 0]).plot([0, 1e-4])
            fig.add_subplot(gs[1, 1]).set_xlabel("x [m]")
            figs.append(fig)
    figs[1].set_layout_engine(GridLayoutEngine.like(figs[0].get_layout_engine(), thin=False))
    assert np.abs(_positions(figs[0]) - _positions(figs[1])).max() < 1e-9


def test_render_figure_lays_out_in_one_measuring_pass(monkeypatch):
    """render_figure swaps the constrained layout for the grid engine, which measures the panels
    once (a first placement from the label sizes gets the final tick labels)."""
    from dynid.reports import figure_layout as L
    passes = []
    place = L._place

    def spy(*args, **kwargs):
        passes.append(kwargs.get("estimate", False))
        return place(*args, **kwargs)

    monkeypatch.setattr(L, "_place", spy)
    fig = _panels(1, 2)
    F.render_figure(fig, "fig-grid", "grid")
    assert isinstance(fig.get_layout_engine(), GridLayoutEngine)
    assert passes == [True, False]


def test_multiline_labels_are_measured_line_by_line_without_a_glyph_warning():
    """A two-line title is placed as matplotlib's engine places it, and no 'Glyph 10 missing' warning."""
    import warnings

    def make():
        with matplotlib.rc_context(F.STYLE):
            fig = Figure(figsize=(6.6, 2.2), layout="constrained")
            for j, ax in enumerate(fig.subplots(1, 2)):
                ax.plot([0, 1], [0, 10 ** j])
                ax.set_title("joint 1\nspring found", loc="left")
                ax.set_ylabel("torque\n[N m]")
        return fig
    ref = make()
    FigureCanvasAgg(ref).draw()
    fig = make()
    fig.set_layout_engine(GridLayoutEngine.like(fig.get_layout_engine()))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        FigureCanvasAgg(fig).draw()
    for a, b in zip(ref.axes, fig.axes):
        np.testing.assert_allclose(a.get_position().bounds, b.get_position().bounds, atol=0.5 / 72 / 3.3)


def test_log_axes_are_labelled_with_plain_numbers_without_mathtext():
    """`log_scale`: decades labelled "0.01" ... "1000" (not 10^k in TeX, which matplotlib parses
    at every draw); an axis spanning less than a decade still gets labels on its minor ticks."""
    svg = str(F.rel_std_bar_figure(["a", "b", "c", "d"], [0.05, 2.0, 40.0, 1500.0], fmt="svg").markup)
    labels = set(re.findall(r">([^<>]+)</text>", svg))
    assert {"0.1", "1", "10", "100", "1000"} <= labels
    assert not any("10^" in t or "mathdefault" in t for t in labels)
    with matplotlib.rc_context(F.STYLE):
        fig = Figure(figsize=(3, 2))
        ax = fig.subplots()
        ax.bar([0, 1], [0.021, 0.052])
        F.log_scale(ax)
        FigureCanvasAgg(fig).draw()
        shown = [t.get_text() for t in ax.get_yticklabels(minor=True) if t.get_text()]
    assert shown and all(float(t.replace("\u2212", "-")) > 0 for t in shown)


def test_render_figure_draws_the_figure_once(monkeypatch):
    """savefig with a layout engine set draws the figure twice (the first draw, with drawing
    disabled, only runs the engine); render_figure runs the engine itself and draws once, and
    the figure keeps its engine."""
    draws = []
    draw = Figure.draw

    def spy(self, renderer):
        draws.append(type(renderer).__name__)
        return draw(self, renderer)

    monkeypatch.setattr(Figure, "draw", spy)
    for fmt in ("svg", "png"):
        fig = _panels(2, 3)
        draws.clear()
        F.render_figure(fig, "fig-grid", "grid", fmt=fmt)
        assert len(draws) == 1, (fmt, draws)
        assert isinstance(fig.get_layout_engine(), GridLayoutEngine)


def test_a_users_automatic_layout_setting_does_not_change_the_figure():
    """With the engine taken off for saving, a user's figure.autolayout or
    figure.constrained_layout.use must not put another one on (STYLE turns both off)."""
    def svg():
        return str(F.rel_std_bar_figure(["a", "b", "c"], [0.5, 3.0, 80.0], fmt="svg").markup)

    plain = svg()
    for setting in ({"figure.autolayout": True}, {"figure.constrained_layout.use": True}):
        with matplotlib.rc_context(setting):
            assert svg() == plain, setting
