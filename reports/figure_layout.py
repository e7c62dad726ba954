"""Layout of the report figures: matplotlib's constrained layout, solved in one measuring pass.

The report's figures are grids of panels (one per joint, or one or two panels) from
`Figure.subplots`, with an optional figure legend outside at the top and a suptitle.
For such a grid, the constrained layout has a closed form: each column gets a left and
right margin (the widest decorations -- tick labels, axis labels, titles -- of its panels,
plus the pad), each row a top and bottom margin, the panels share what is left in
proportion to the grid's width and height ratios, and the figure's top margin holds the
outside legend and the suptitle. matplotlib's engine solves the same constraints with a
general solver and measures every panel's decorations twice (the tick labels may change
once the panels are resized); measuring them is most of a report figure's cost.

`GridLayoutEngine` measures once, places the panels with the closed form, and measures a
second time only when a panel's tick labels changed with its new size. After the layout it
thins the crowded x ticks of narrow panels (`thin_crowded_ticks`), checked at the panels'
final size from the label widths, without a draw. Figures that are not such a grid
(subfigures, spanning panels, colorbars, `supxlabel`) go to matplotlib's engine unchanged.
"""
from __future__ import annotations

import math

import matplotlib
import numpy as np
from matplotlib.gridspec import GridSpec
from matplotlib.layout_engine import ConstrainedLayoutEngine, LayoutEngine
from matplotlib.ticker import AutoLocator, MaxNLocator
from matplotlib.transforms import Bbox

__all__ = ["GridLayoutEngine", "thin_crowded_ticks", "x_labels_fit"]

#: Panels narrower than this (inches) are checked for crowded x tick labels.
NARROW_IN = 4.0


class GridLayoutEngine(LayoutEngine):
    """The constrained layout of a grid of panels, with one measuring pass (see the module).

    Parameters
    ----------
    h_pad, w_pad, hspace, wspace : float
        As for matplotlib's ConstrainedLayoutEngine (pads in inches).
    thin : bool
        Thin the crowded x ticks of narrow panels after the layout (`thin_crowded_ticks`).
    """

    _adjust_compatible = False
    _colorbar_gridspec = False

    def __init__(self, *, h_pad, w_pad, hspace, wspace, thin=True):
        super().__init__()
        self._params = dict(h_pad=h_pad, w_pad=w_pad, hspace=hspace, wspace=wspace)
        self._thin = thin

    @classmethod
    def like(cls, engine: ConstrainedLayoutEngine, thin=True) -> GridLayoutEngine:
        """The grid engine with the pads and spaces of a constrained `engine`."""
        p = engine.get()
        return cls(h_pad=p["h_pad"], w_pad=p["w_pad"], hspace=p["hspace"], wspace=p["wspace"], thin=thin)

    def execute(self, fig):
        renderer = fig._get_renderer()
        grid = _grid_of(fig)
        if grid is None:                       # not a plain grid: matplotlib's engine, as before
            engine = ConstrainedLayoutEngine(**self._params)
            engine.execute(fig)
            if self._thin and thin_crowded_ticks(fig, renderer):
                engine.execute(fig)
            return
        # a first placement from the label sizes (cheap), so that the measured pass usually
        # sees the tick labels of the final size and is the only one
        _place(fig, grid, renderer, estimate=True, **self._params)
        for _ in range(3):
            measured = _place(fig, grid, renderer, **self._params)
            thinned = self._thin and thin_crowded_ticks(fig, renderer)
            # measured with the labels of the old size: again only if the new size (or the
            # thinning) changed them
            if not thinned and _tick_labels(grid[1]) == measured:
                return


def _grid_of(fig):
    """(gridspec, axes) when `fig` is a plain grid this engine lays out, else None."""
    if fig.subfigs or getattr(fig, "_supxlabel", None) is not None or getattr(fig, "_supylabel", None) is not None:
        return None
    axes = [ax for ax in fig.axes if ax.get_in_layout()]
    if not axes:
        return None
    gs = None
    for ax in axes:
        ss = ax.get_subplotspec()
        if ss is None or getattr(ax, "_colorbars", None) or getattr(ax, "_colorbar", None) is not None:
            return None
        g = ss.get_gridspec()
        if gs is None:
            gs = g
        if g is not gs or type(g) is not GridSpec or len(ss.rowspan) != 1 or len(ss.colspan) != 1:
            return None
    if any(leg._outside_loc and leg._bbox_to_anchor is not None for leg in fig.legends):
        return None
    return gs, axes


def _place(fig, grid, renderer, *, h_pad, w_pad, hspace, wspace, estimate=False):
    """One pass of the constrained layout of a plain grid: measure, solve, move the panels.

    `estimate`: the panels' decorations estimated from their tick and axis label sizes
    (a starting point), instead of measured. Returns the tick labels measured.
    """
    gs, axes = grid
    width, height = fig.get_size_inches()
    w_pad, h_pad = w_pad / width, h_pad / height
    nrows, ncols = gs.get_geometry()
    ws = gs.wspace if gs.wspace is not None else wspace
    hs = gs.hspace if gs.hspace is not None else hspace
    ws, hs = ws / 2 / ncols, hs / 2 / nrows
    left, right = np.zeros(ncols), np.zeros(ncols)
    top, bottom = np.zeros(nrows), np.zeros(nrows)
    to_fig = fig.transFigure.inverted()
    measured = None if estimate else _tick_labels(axes)
    for ax in axes:
        ss = ax.get_subplotspec()
        r, c = ss.rowspan.start, ss.colspan.start
        pos = ax.get_position(original=True)
        if estimate:
            bbox = _estimated_bbox(ax, renderer, pos)
        else:
            tight = ax.get_tightbbox(renderer, for_layout_only=True) if ax.get_visible() else None
            bbox = pos if tight is None else tight.transformed(to_fig)
        lcb = ws if ws > w_pad and c > 0 else w_pad
        rcb = ws if ws > w_pad and c < ncols - 1 else w_pad
        bcb = hs if hs > h_pad and r < nrows - 1 else h_pad
        tcb = hs if hs > h_pad and r > 0 else h_pad
        left[c] = max(left[c], pos.x0 - bbox.x0 + lcb)
        right[c] = max(right[c], bbox.x1 - pos.x1 + rcb)
        top[r] = max(top[r], bbox.y1 - pos.y1 + tcb)
        bottom[r] = max(bottom[r], pos.y0 - bbox.y0 + bcb)
    # the figure's own margins: outside legends and the suptitle
    fig_m = dict(left=0.0, right=0.0, top=0.0, bottom=0.0)
    sup = fig._suptitle
    if sup is not None and sup.get_in_layout() and getattr(sup, "_autopos", False):
        sup.set_position((sup.get_position()[0], 1 - h_pad))
        fig_m["top"] = max(fig_m["top"], to_fig.transform_bbox(sup.get_tightbbox(renderer)).height + 2 * h_pad)
    for leg in fig.legends:
        if leg._outside_loc and leg._bbox_to_anchor is None:
            b = to_fig.transform_bbox(leg.get_tightbbox(renderer))
            side = {"lower": "bottom", "upper": "top"}.get(leg._outside_loc, leg._outside_loc)
            fig_m[side] = max(fig_m[side], b.height + 2 * h_pad if side in ("top", "bottom") else b.width + 2 * w_pad)
    # panels share what the margins leave, in proportion to the grid's ratios
    wr = np.asarray(gs.get_width_ratios() or [1.0] * ncols, dtype=float)
    hr = np.asarray(gs.get_height_ratios() or [1.0] * nrows, dtype=float)
    inner_w = 1.0 - fig_m["left"] - fig_m["right"] - left.sum() - right.sum()
    inner_h = 1.0 - fig_m["top"] - fig_m["bottom"] - top.sum() - bottom.sum()
    if inner_w <= 0 or inner_h <= 0:           # decorations larger than the figure: as matplotlib, leave it
        return measured
    w = inner_w * wr / wr.sum()
    h = inner_h * hr / hr.sum()
    x0 = fig_m["left"] + np.concatenate([[0.0], np.cumsum(left + w + right)[:-1]]) + left
    y1 = 1.0 - fig_m["top"] - np.concatenate([[0.0], np.cumsum(top + h + bottom)[:-1]]) - top
    for ax in axes:
        ss = ax.get_subplotspec()
        r, c = ss.rowspan.start, ss.colspan.start
        ax._set_position([x0[c], y1[r] - h[r], w[c], h[r]])
    if sup is not None and sup.get_in_layout() and getattr(sup, "_autopos", False):
        sup.set_position((sup.get_position()[0], 1.0 - fig_m["top"] + h_pad))
        sup.set_verticalalignment("bottom")
    return measured


def _text_size(renderer, text, prop):
    # line by line: the renderer measures one line and has no glyph for a newline
    sizes = [renderer.get_text_width_height_descent(line or " ", prop, ismath="$" in line)[:2]
             for line in text.split("\n")]
    return max(w for w, _ in sizes), sum(h for _, h in sizes) * (1.2 if len(sizes) > 1 else 1.0)


def _visible_labels(axis):
    lo, hi = sorted(axis.get_view_interval())
    span = (hi - lo) * 1e-9
    locs = [v for v in axis.get_major_locator()() if lo - span <= v <= hi + span]
    return locs, (axis.get_major_formatter().format_ticks(locs) if locs else [])


def _estimated_bbox(ax, renderer, pos):
    """`pos` grown by an estimate of the decorations of `ax` (figure fraction)."""
    if not ax.get_visible():
        return pos
    fig = ax.figure.figure   # the root figure (a Figure's .figure is itself), as get_figure(root=True) of matplotlib >= 3.10
    px = fig.dpi / 72.0
    rc = matplotlib.rcParams
    grow = dict(left=0.0, right=0.0, top=0.0, bottom=0.0)
    fw, fh = fig.bbox.width, fig.bbox.height
    for axis, name in ((ax.xaxis, "x"), (ax.yaxis, "y")):
        ticks = axis.get_major_ticks(1)
        if not ticks:
            continue
        label = ticks[0].label1
        prop = label.get_fontproperties()
        locs, texts = _visible_labels(axis)
        sizes = [_text_size(renderer, t, prop) for t in texts if t]
        params = axis.get_tick_params()
        shown = params.get("labelbottom" if name == "x" else "labelleft", True)
        tick = rc[f"{name}tick.major.size"] if rc[f"{name}tick.direction"] != "in" else 0.0
        out = (tick + rc[f"{name}tick.major.pad"]) * px
        angle = math.radians(label.get_rotation())
        if name == "x":
            if shown and sizes:
                grow["bottom"] += out + max(w * abs(math.sin(angle)) + h * abs(math.cos(angle)) for w, h in sizes)
                grow["right"] = max(grow["right"], sizes[-1][0] / 2)
            if axis.label.get_text():
                grow["bottom"] += rc["axes.labelpad"] * px + _text_size(renderer, axis.label.get_text(),
                                                                       axis.label.get_fontproperties())[1]
        else:
            if shown and sizes:
                grow["left"] += out + max(w for w, _ in sizes)
                grow["top"] = max(grow["top"], sizes[-1][1] / 2)
            if axis.label.get_text():
                grow["left"] += rc["axes.labelpad"] * px + _text_size(renderer, axis.label.get_text(),
                                                                     axis.label.get_fontproperties())[1]
    for title in (ax.title, ax._left_title, ax._right_title):
        if title.get_text():
            w, h = _text_size(renderer, title.get_text(), title.get_fontproperties())
            grow["top"] = max(grow["top"], rc["axes.titlepad"] * px + h)
            grow["right"] = max(grow["right"], w - pos.width * fw)
    return Bbox.from_extents(pos.x0 - grow["left"] / fw, pos.y0 - grow["bottom"] / fh,
                             pos.x1 + grow["right"] / fw, pos.y1 + grow["top"] / fh)


def _tick_labels(axes):
    """The tick label texts (and offset texts) of `axes` as drawn at their current size."""
    out = []
    for ax in axes:
        if not ax.get_visible():
            continue
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            span = (hi - lo) * 1e-9
            for which in (axis.major, axis.minor):
                locs = [v for v in which.locator() if lo - span <= v <= hi + span]
                texts = which.formatter.format_ticks(locs) if locs else []
                out.append((tuple(texts), which.formatter.get_offset() if hasattr(which.formatter, "get_offset")
                            else ""))
    return out


def x_labels_fit(ax, renderer, pad=2.0) -> bool:
    """Whether the x tick labels of `ax` stay `pad` pixels apart at its current width.

    Measures the label texts the locator and formatter give with `renderer` (centred labels:
    two neighbours fit when half their widths and the pad fit between their ticks), without a
    draw.
    """
    lo, hi = sorted(ax.get_xlim())
    if not hi > lo:
        return False
    ticks = ax.xaxis.get_major_ticks()
    if not ticks or not ticks[0].label1.get_visible() or ticks[0].label1.get_rotation() != 0:
        return True                           # hidden or already slanted labels do not crowd
    span = (hi - lo) * 1e-9
    locs = [v for v in ax.xaxis.get_major_locator()() if lo - span <= v <= hi + span]
    if len(locs) < 2:
        return True
    texts = ax.xaxis.get_major_formatter().format_ticks(locs)
    prop = ticks[0].label1.get_fontproperties()
    widths = [renderer.get_text_width_height_descent(t, prop, ismath=False)[0] if t else 0.0 for t in texts]
    px_per_x = ax.get_position().width * ax.figure.figure.bbox.width / (hi - lo)
    return all(0.5 * (wa + wb) + pad < (b - a) * px_per_x
               for a, b, wa, wb in zip(locs, locs[1:], widths, widths[1:]))


def thin_crowded_ticks(fig, renderer, min_bins: int = 2, max_width_in: float = NARROW_IN) -> bool:
    """Fewer numeric x ticks on every narrow panel whose x tick labels run into each other.

    Narrow panels (one per joint, a few centimetres wide) with long tick labels (-0.00025) run
    the labels into each other. The ticks are thinned (automatic locators only: named ticks
    such as parameter names are kept); labels still crowded at `min_bins` ticks are slanted.
    Checked at the panels' current size (after the layout). Returns whether anything changed.
    """
    axes = [ax for ax in fig.get_axes() if ax.get_visible()
            and ax.get_position().width * fig.get_figwidth() < max_width_in
            and isinstance(ax.xaxis.get_major_locator(), (AutoLocator, MaxNLocator))]
    changed = False
    for nbins in (5, 4, 3, min_bins, None):
        crowded = [ax for ax in axes if not x_labels_fit(ax, renderer)]
        if not crowded:
            return changed
        changed = True
        for ax in crowded:
            if nbins is None:                 # long labels even at two ticks: slant them
                ax.tick_params(axis="x", labelrotation=35)
                for label in ax.xaxis.get_ticklabels():
                    label.set_horizontalalignment("right")
                    label.set_rotation_mode("anchor")
            else:
                ax.xaxis.set_major_locator(MaxNLocator(nbins=nbins, steps=[1, 2, 2.5, 5, 10]))
    return changed
