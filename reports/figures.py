"""Figures of the HTML reports, as inline SVG (or base64 PNG for dense plots).

Every figure is drawn on a `matplotlib.figure.Figure` of its own (no
pyplot, no global figure registry) under a fixed style, and serialised to a
string the report embeds directly:

* SVG by default, with a fixed `svg.hashsalt` and no date so that the same
  input gives byte-identical output; the XML prologue, metadata, comments and
  namespace declarations are dropped (inline SVG in HTML needs none of them),
  and element ids are prefixed with the figure's key so that several figures
  in one page never share an id;
* PNG (Agg, base64 `data:` URI) when a plot has too many points for a
  compact SVG.

Time series with more than `MAX_POINTS` samples are decimated for
plotting only (every k-th sample); the caption says so.

A figure made with `layout="constrained"` is laid out by
dynid.reports.figure_layout.GridLayoutEngine when rendered: the same placement for
a grid of panels, measured once instead of twice, with the crowded x ticks of narrow
panels thinned at their final size.
"""
from __future__ import annotations

import base64
import io
import math
import re
from contextlib import contextmanager
from dataclasses import dataclass

import matplotlib
import numpy as np
from markupsafe import Markup, escape
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_svg import FigureCanvasSVG
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from matplotlib.ticker import LogFormatter, LogLocator, NullFormatter

from dynid.analysis.results import p_phrase, p_value_text
from dynid.dynamics.robot import joint_label as robot_joint_label
from dynid.reports.figure_layout import GridLayoutEngine, thin_crowded_ticks

__all__ = [
    "FigureMarkup", "MAX_POINTS", "SVG_MAX_VERTICES", "RED", "BLUE",
    "decimate_for_plot", "joint_label", "render_figure",
    "torque_figure", "residual_pdf_figure", "essential_path_figure", "rel_std_bar_figure",
    "verdict_rel_std_figure", "masked",
]

#: Samples per line above which a series is decimated for plotting.
MAX_POINTS = 5000
#: Total line vertices above which a figure is written as PNG rather than SVG.
SVG_MAX_VERTICES = 20000
RED, BLUE, GREY, GREEN = "#d62728", "#1f4fb4", "#777777", "#2ca02c"
AMBER = "#c77700"
EXCLUDED_COLOR = "#e3e6ea"
PAPER_COLOR = "#e0a030"

STYLE = {
    "svg.hashsalt": "dynid-report",
    "figure.autolayout": False,        # the report's figures choose their layout engine
    "figure.constrained_layout.use": False,
    "svg.fonttype": "none",            # text as <text>: small files, selectable labels
    "font.family": "DejaVu Sans",
    "font.size": 8.0,
    "axes.titlesize": 8.5,
    "axes.labelsize": 8.0,
    "xtick.labelsize": 7.0,
    "ytick.labelsize": 7.0,
    "legend.fontsize": 7.0,
    "axes.linewidth": 0.6,
    "lines.linewidth": 0.9,
    "grid.linewidth": 0.4,
    "grid.color": "#dddddd",
    "axes.grid": True,
    "axes.axisbelow": True,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "figure.dpi": 100,
    "savefig.dpi": 110,
    "path.simplify": True,
    "path.simplify_threshold": 0.5,
}


@dataclass
class FigureMarkup:
    """A rendered figure: `markup` is trusted HTML (SVG element or <img>)."""

    key: str
    caption: str
    markup: Markup
    kind: str            # "svg" or "png"

    @property
    def n_bytes(self) -> int:
        return len(self.markup.encode("utf-8"))

    def __html__(self):
        return self.markup


# ------------------------------------------------------------------ helpers
def joint_label(j: int, name: str) -> str:
    """`joint 3` for default names (`j3`, `joint3`, `3`), else `joint 3 (name)`."""
    return robot_joint_label(j, name, prefix="joint ")


def _plain(text) -> str:
    """User text for matplotlib: no mathtext (`$` escaped)."""
    return str(text).replace("$", r"\$")


class PlainLogFormatter(LogFormatter):
    """matplotlib's choice of which log-scale ticks to label (`LogFormatter`), with each label a
    plain number: "0.01", "100", "1e+06". matplotlib's default writes 10^k in mathtext, which it
    parses as TeX for every label of every draw, a large share of a report figure's time."""

    def __call__(self, x, pos=None):
        if not super().__call__(x, pos):
            return ""
        text = f"{x:g}"
        return text.replace("-", "\u2212") if matplotlib.rcParams["axes.unicode_minus"] else text


def log_scale(ax, *, minor_labels: bool = True) -> None:
    """A log y axis on `ax` with plain-number labels (`PlainLogFormatter`); `minor_labels`
    False: the minor ticks unlabelled, else labelled where matplotlib would label them (an
    axis spanning less than a decade or two)."""
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(PlainLogFormatter())
    ax.yaxis.set_minor_formatter(PlainLogFormatter(labelOnlyBase=False) if minor_labels else NullFormatter())


def _break_at_gaps(t, *series):
    """`t` and each (N, n) series with a NaN row inserted after every step longer than ten median
    steps (the joint between two stacked recordings), so that no line is drawn across it."""
    if t.size < 3:
        return (t, *series)
    d = np.diff(t)
    gaps = np.flatnonzero(d > 10 * np.median(d)) + 1
    if not gaps.size:
        return (t, *series)
    t = np.insert(t, gaps, np.nan)
    return (t, *(np.insert(np.asarray(x, dtype=float), gaps, np.nan, axis=0) for x in series))


def decimate_for_plot(n: int, max_points: int = MAX_POINTS):
    """`(index, step)`: every `step`-th of `n` samples, at most `max_points` of them."""
    step = max(1, math.ceil(n / max_points)) if max_points else 1
    return np.arange(0, n, step), step


def _new_figure(width, height):
    fig = Figure(figsize=(width, height), layout="constrained")
    return fig


_ID = re.compile(r'\bid="([^"]+)"')


def _clean_svg(text: str, key: str) -> str:
    """Strip the prologue, metadata, comments, style and namespaces; prefix the ids."""
    text = re.sub(r"<\?xml[^>]*\?>\s*", "", text)
    text = re.sub(r"<!DOCTYPE[^>]*>\s*", "", text)
    text = re.sub(r"<!--.*?-->\s*", "", text, flags=re.S)
    text = re.sub(r"<metadata>.*?</metadata>\s*", "", text, flags=re.S)
    text = re.sub(r"<defs>\s*<style[^>]*>.*?</style>\s*</defs>\s*", "", text, flags=re.S)
    text = re.sub(r"<style[^>]*>.*?</style>\s*", "", text, flags=re.S)
    text = re.sub(r'\s+xmlns(:\w+)?="[^"]*"', "", text)
    text = re.sub(r'\s+version="1\.1"', "", text, count=1)
    text = text.replace("xlink:href=", "href=")
    # keep only the ids something refers to, prefixed with the figure's key
    referenced = set(re.findall(r"url\(#([^)]+)\)", text)) | set(re.findall(r'href="#([^"]+)"', text))
    ids = set(_ID.findall(text)) & referenced
    text = _ID.sub(lambda m: m.group(0) if m.group(1) in ids else "", text)
    text = re.sub(r"<g\s*>", "<g>", text)
    if ids:
        prefix = f"{key}-"
        text = _ID.sub(lambda m: f'id="{prefix}{m.group(1)}"', text)
        text = re.sub(r"url\(#([^)]+)\)",
                      lambda m: f"url(#{prefix}{m.group(1)})" if m.group(1) in ids else m.group(0), text)
        text = re.sub(r'href="#([^"]+)"',
                      lambda m: f'href="#{prefix}{m.group(1)}"' if m.group(1) in ids else m.group(0), text)
    # compact: 2 decimals in path data, no indentation or line breaks
    text = re.sub(r'\bd="([^"]*)"', lambda m: 'd="' + _short_path(m.group(1)) + '"', text)
    text = re.sub(r">\s+<", "><", text)
    # width="460.8pt" -> px, so that CSS max-width:100% scales it on small screens
    def px(m):
        return f'{m.group(1)}="{float(m.group(2)) * 96 / 72:.0f}"'
    text = re.sub(r'\b(width|height)="([0-9.]+)pt"', px, text, count=2)
    # one font declaration on the root (with fallbacks where DejaVu Sans is not installed)
    text = re.sub(r";?\s*font-family: 'DejaVu Sans'", "", text)
    text = text.replace("<svg ", "<svg style=\"font-family: 'DejaVu Sans', Verdana, Arial, "
                        "sans-serif\" ", 1)
    text = re.sub(r' transform="rotate\(-?0 [^"]*\)"', "", text)
    text = re.sub(r'\b(x|y)="(-?\d+\.\d+)"', lambda m: f'{m.group(1)}="{float(m.group(2)):.2f}"', text)
    text = text.replace('style=""', "")
    return text.strip()


_NUM = re.compile(r"-?\d+\.\d+")


def _short_path(d: str) -> str:
    def fix(m):
        v = f"{float(m.group(0)):.2f}".rstrip("0").rstrip(".")
        return "0" if v in ("-0", "") else v
    return re.sub(r"\s+", " ", _NUM.sub(fix, d)).strip()


def _count_vertices(fig) -> int:
    total = 0
    for ax in fig.axes:
        for line in ax.get_lines():
            total += len(line.get_xdata())
    return total


def thin_overlapping_ticks(fig) -> None:
    """Fewer numeric x ticks on every narrow axes whose x tick labels overlap, at the axes'
    current positions (dynid.reports.figure_layout.thin_crowded_ticks; figures laid out by
    `render_figure` are thinned by their layout engine)."""
    thin_crowded_ticks(fig, FigureCanvasAgg(fig).get_renderer())


def _grid_layout(fig) -> None:
    """Lay `fig` out in one pass: a constrained layout becomes the equivalent GridLayoutEngine
    (which also thins crowded ticks); a figure placed by hand has its crowded ticks thinned."""
    engine = fig.get_layout_engine()
    if (isinstance(engine, ConstrainedLayoutEngine) and not getattr(engine, "_compress", False)
            and tuple(engine.get()["rect"]) == (0, 0, 1, 1)):
        fig.set_layout_engine(GridLayoutEngine.like(engine))
    elif not isinstance(engine, (GridLayoutEngine, ConstrainedLayoutEngine)):
        thin_overlapping_ticks(fig)


@contextmanager
def _laid_out_for_saving(fig, dpi):
    """Within: `fig` laid out by its layout engine as `savefig`'s first pass would, at the dpi
    it draws at (72 for SVG, savefig.dpi for PNG), and the engine off (put back after).

    With a layout engine set, `savefig` draws the whole figure twice: once with drawing
    disabled, only so that the engine runs at the start of the draw, and once for real.
    The first draw still computes every tick, text and title position, a third of a report
    figure's cost; the engine alone is what the layout needs. The files are the same
    (`STYLE` keeps a user's `figure.autolayout` or `figure.constrained_layout.use` from
    putting an engine back when this one is taken off).
    """
    engine = fig.get_layout_engine()
    if engine is None:
        yield
        return
    saved = fig.dpi
    try:
        fig.dpi = dpi
        if fig.axes:                  # as Figure.draw runs the engine
            try:
                engine.execute(fig)
            except ValueError:        # ignored by Figure.draw too
                pass
    finally:
        fig.dpi = saved
    fig.set_layout_engine(None)
    try:
        yield
    finally:
        fig.set_layout_engine(engine)


def render_figure(fig, key: str, caption: str, *, fmt: str = "auto") -> FigureMarkup:
    """Serialise `fig` to a `FigureMarkup` (SVG, or PNG when dense / asked).

    Returns
    -------
    FigureMarkup
        The figure as trusted HTML, with its key and caption; x tick labels that
        would overlap are thinned first.
    """
    _grid_layout(fig)
    if fmt == "auto":
        fmt = "png" if _count_vertices(fig) > SVG_MAX_VERTICES else "svg"
    label = escape(caption)
    with matplotlib.rc_context(STYLE):
        buf = io.BytesIO()
        if fmt == "svg":
            FigureCanvasSVG(fig)
            with _laid_out_for_saving(fig, 72):            # the SVG backend draws at 72 dpi
                fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
            text = _clean_svg(buf.getvalue().decode("utf-8"), key)
            text = text.replace("<svg ", f'<svg role="img" aria-label="{label}" ', 1)
            markup = Markup(text)
        elif fmt == "png":
            FigureCanvasAgg(fig)
            with _laid_out_for_saving(fig, matplotlib.rcParams["savefig.dpi"]):
                fig.savefig(buf, format="png", metadata={"Software": None})
            data = base64.b64encode(buf.getvalue()).decode("ascii")
            markup = Markup('<img alt="{}" src="data:image/png;base64,{}">').format(caption, data)
        else:
            raise ValueError(f"fmt must be 'auto', 'svg' or 'png', not {fmt!r}")
    return FigureMarkup(key=key, caption=caption, markup=markup, kind=fmt)


def grid_shape(n: int, max_cols: int = 3):
    """(rows, cols) of a grid of per-joint panels."""
    cols = min(n, max_cols) if n > 1 else 1
    rows = math.ceil(n / cols)
    return rows, cols


# ------------------------------------------------------------------ figures
def masked(values, mask):
    """`values` with the samples outside `mask` set to NaN (drawn as gaps, never as zeros)."""
    values = np.asarray(values, dtype=float)
    if mask is None:
        return values
    m = np.broadcast_to(np.asarray(mask, dtype=bool), values.shape)
    return np.where(m, values, np.nan)


def _excluded_spans(t, excluded):
    """(start, end) time spans of consecutive excluded samples, each edge halfway to the
    neighbouring kept sample (the first and last sample: the edge is the sample itself)."""
    t = np.asarray(t, dtype=float)
    ex = np.asarray(excluded, dtype=bool)
    n = ex.size
    edges = np.diff(np.concatenate([[False], ex, [False]]).astype(np.int8))
    first = np.flatnonzero(edges == 1)                 # first excluded sample of each run
    end = np.flatnonzero(edges == -1)                  # one past its last
    lo = np.where(first > 0, t[np.maximum(first - 1, 0)], t[first])
    hi = np.where(end < n, t[np.minimum(end, n - 1)], t[end - 1])
    return list(zip((0.5 * (lo + t[first])).tolist(), (0.5 * (hi + t[end - 1])).tolist()))


def _shade(ax, spans, label):
    """Grey bands over the full height of `ax` on the time `spans`: one collection, one legend
    entry (a dead zone has hundreds of spans; one artist each would cost more than the curves)."""
    if not spans:
        return
    verts = [[(a, 0.0), (a, 1.0), (b, 1.0), (b, 0.0)] for a, b in spans]
    ax.add_collection(PolyCollection(verts, facecolors=EXCLUDED_COLOR, edgecolors="none", linewidths=0,
                                     zorder=0, label=label, transform=ax.get_xaxis_transform()),
                      autolim=False)
    ax.update_datalim([(spans[0][0], 0.0), (spans[-1][1], 0.0)], updatey=False)


def torque_figure(t, measured, estimated, joint_names, *, key="fig-torque", caption=None,
                  fmt="auto", ylabel="torque [N m]", labels=("measured", "estimated"), mask=None,
                  shade=None, shade_label="velocity dead zone"):
    """Measured (red) vs estimated (blue) torque, one small subplot per joint (Fig. 6).

    `mask` (N, n): samples NOT in it (e.g. the velocity dead zone, zeroed
    for the fit) are drawn as gaps in both curves on a grey band, never as
    zeros. NaN samples are gaps too. `shade` (N, n): samples drawn normally but
    on a grey band labelled `shade_label` (e.g. the dead zone of held-out data,
    predicted but left out of the moving-sample error).
    """
    t = np.asarray(t, dtype=float)
    measured = masked(measured, mask)
    estimated = masked(estimated, mask)
    n = measured.shape[1]
    idx, step = decimate_for_plot(t.size)
    # clock time (ROS or UNIX stamps, ~1.5e9 s) is drawn from the first sample; stacked recordings
    # are drawn apart: no line across the gap between them
    t0 = float(t[0]) if t.size and abs(float(t[0])) > 1e5 else 0.0
    xlabel = "time since the first sample [s]" if t0 else "time [s]"
    tp, mp, ep = _break_at_gaps(t[idx] - t0, measured[idx], estimated[idx])
    t = t - t0
    any_excluded = False
    with matplotlib.rc_context(STYLE):
        rows, cols = grid_shape(n)
        fig = _new_figure(3.3 * cols, 1.9 * rows + 0.3)
        axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
        for j in range(rows * cols):
            ax = axes.flat[j]
            if j >= n:
                ax.set_visible(False)
                continue
            excl = ~np.isfinite(measured[:, j])
            if shade is not None and not excl.any():
                sh = np.broadcast_to(np.asarray(shade, dtype=bool), measured.shape)[:, j]
                _shade(ax, _excluded_spans(t, sh), shade_label)
            if excl.any():
                any_excluded = True
                _shade(ax, _excluded_spans(t, excl), "excluded (not measured here)")
            ax.plot(tp, mp[:, j], color=RED, lw=0.9, label=labels[0])
            ax.plot(tp, ep[:, j], color=BLUE, lw=0.8, label=labels[1])
            ax.set_title(_plain(joint_label(j, joint_names[j])), loc="left")
            if j % cols == 0:
                ax.set_ylabel(ylabel)
            if j >= n - cols:
                ax.set_xlabel(xlabel)
                ax.tick_params(labelbottom=True)
        handles, texts = [], []
        for ax in axes.flat[:n]:
            for h, tx in zip(*ax.get_legend_handles_labels()):
                if tx not in texts:
                    handles.append(h)
                    texts.append(tx)
        fig.legend(handles, texts, loc="outside upper right", ncols=3, frameon=False)
    if caption is None:
        caption = "Measured torque (red) and torque estimated by the identified model (blue), per joint"
    if any_excluded:
        caption += "; excluded samples are gaps on a grey band, not zeros"
    if step > 1:
        caption += f" (every {step}th of {t.size} samples plotted)"
    return render_figure(fig, key, caption, fmt=fmt)


def residual_pdf_figure(residual, joint_names, jarque_bera_p=None, *, key="fig-residual-pdf",
                        caption=None, fmt="auto"):
    """Per joint: histogram of the residual, fitted normal density and KDE; JB p in the title."""
    from scipy import stats

    residual = np.asarray(residual, dtype=float)
    n = residual.shape[1]
    with matplotlib.rc_context(STYLE):
        rows, cols = grid_shape(n)
        fig = _new_figure(3.3 * cols, 1.9 * rows + 0.3)
        axes = fig.subplots(rows, cols, squeeze=False)
        for j in range(rows * cols):
            ax = axes.flat[j]
            if j >= n:
                ax.set_visible(False)
                continue
            e = residual[:, j]
            e = e[np.isfinite(e)]
            title = joint_label(j, joint_names[j])
            if jarque_bera_p is not None:
                title += f": {p_equals(jarque_bera_p[j], 'JB p')}"
            ax.set_title(_plain(title), loc="left")
            if e.size < 3:
                ax.text(0.5, 0.5, "too few samples", ha="center", va="center", transform=ax.transAxes)
                continue
            mu, sd = float(e.mean()), float(e.std(ddof=1))
            bins = int(np.clip(np.ceil(np.sqrt(e.size)), 8, 40))
            ax.hist(e, bins=bins, density=True, color="#c8d3e8", edgecolor="#8fa3c8", linewidth=0.4,
                    label="histogram")
            lo, hi = float(e.min()), float(e.max())
            pad = 0.1 * (hi - lo) if hi > lo else 1.0
            x = np.linspace(lo - pad, hi + pad, 200)
            if sd > 0:
                ax.plot(x, stats.norm.pdf(x, mu, sd), color=RED, lw=1.0, label="normal fit")
                try:
                    ax.plot(x, stats.gaussian_kde(e)(x), color=BLUE, lw=1.0, ls="--", label="KDE")
                except (np.linalg.LinAlgError, ValueError):
                    pass
            ax.set_yticks([])
            ax.grid(False)
            if j >= n - cols:
                ax.set_xlabel("residual [N m]")
        handles, texts = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside upper right", ncols=3, frameon=False)
    if caption is None:
        caption = ("Residual PDF per joint: histogram, fitted normal density (red), kernel "
                   "density estimate (blue, dashed); Jarque-Bera p-value in the title")
    return render_figure(fig, key, caption, fmt=fmt)


def p_equals(p, name: str = "p") -> str:
    """`p = 0.012`, `p < 1e-300`, or `p = —` for a test not computed (`p_phrase`)."""
    return p_phrase(p, name, "\u2014")


def format_p(p) -> str:
    """`dynid.analysis.results.p_value_text`, with a dash for a test not computed."""
    return p_value_text(p, "\u2014")


def essential_path_figure(path, *, base_rel_error, base_max_rel_std=None, error_limit=None,
                          key="fig-essential-path", caption=None, fmt="auto"):
    """Relative error and max %σ of the remaining set vs elimination step; stop step marked.

    `path` is `EssentialResult.path`; step 0 is the full base model.
    """
    steps = np.concatenate([[0], np.asarray(path["step"], dtype=float)])
    err = np.concatenate([[base_rel_error], np.asarray(path["rel_error"], dtype=float)])
    mx = np.concatenate([[np.nan if base_max_rel_std is None else base_max_rel_std],
                         np.asarray(path["max_rel_std_remaining"], dtype=float)])
    mx = np.where(np.isfinite(mx) & (mx > 0), mx, np.nan)
    stop = int(steps[-1])
    with matplotlib.rc_context(STYLE):
        fig = _new_figure(7.6, 3.9)
        ax1, ax2 = fig.subplots(2, 1, sharex=True)
        ax1.plot(steps, 100 * err, color=BLUE, marker="o", ms=2.5, lw=1.0, label="relative error")
        if error_limit is not None and math.isfinite(error_limit):
            ax1.axhline(100 * error_limit, color=GREY, ls=":", lw=0.8, label="error limit")
        ax1.set_ylabel("relative error [%]")
        ax2.plot(steps, mx, color=RED, marker="o", ms=2.5, lw=1.0, label="max %\u03c3 remaining")
        if np.any(np.isfinite(mx)):
            log_scale(ax2, minor_labels=False)
            ax2.yaxis.set_minor_locator(LogLocator(subs="auto"))
        ax2.set_ylabel("max %\u03c3 remaining")
        ax2.set_xlabel("elimination step (0 = all base parameters)")
        for ax in (ax1, ax2):
            ax.axvline(stop, color=GREEN, ls="--", lw=1.0)
        ax1.annotate(f"stop: step {stop}", xy=(stop, 1.0), xycoords=("data", "axes fraction"),
                     xytext=(-4, -2), textcoords="offset points", ha="right", va="top",
                     color=GREEN, fontsize=7)
        ax1.legend(loc="upper left", frameon=False)
        ax2.legend(loc="upper right", frameon=False)
    if caption is None:
        caption = ("Essential-parameter elimination path: relative error norm (top) and largest "
                   "%\u03c3 of the remaining parameters (bottom, log scale) after each removal; "
                   "the dashed green line marks the last accepted step")
    return render_figure(fig, key, caption, fmt=fmt)


def rel_std_bar_figure(names, rel_sigma, reference=None, *, key="fig-rel-std",
                       caption=None, fmt="auto", ours_label="dynid"):
    """Bars of the %σ of the essential parameters, beside the paper's %σ where names match.

    `reference`: `{name: %σ}` of the paper (or `None`).
    """
    names = [str(n) for n in names]
    rs = np.asarray(rel_sigma, dtype=float)
    ref = dict(reference or {})
    x = np.arange(len(names))
    has_ref = any(n in ref for n in names)
    width = 0.4 if has_ref else 0.7
    finite = rs[np.isfinite(rs) & (rs > 0)]
    pv = np.array([ref.get(n, np.nan) for n in names], dtype=float)
    allv = np.concatenate([finite, pv[np.isfinite(pv) & (pv > 0)]])
    logy = allv.size > 0 and allv.max() / max(allv.min(), 1e-12) > 30
    with matplotlib.rc_context(STYLE):
        fig = _new_figure(min(10.5, max(4.0, 0.26 * len(names) + 1.2)), 3.0)
        ax = fig.subplots()
        shown = np.where(np.isfinite(rs), rs, np.nan)
        off = -width / 2 if has_ref else 0.0
        ax.bar(x + off, shown, width=width, color=BLUE, label=f"{ours_label} %\u03c3")
        if has_ref:
            ax.bar(x + width / 2, pv, width=width, color=PAPER_COLOR, label="paper %\u03c3 (Table 2)")
        if logy:
            log_scale(ax, minor_labels=False)
        ax.set_xticks(x, [_plain(n) for n in names], rotation=90)
        ax.set_xlim(-0.6, len(names) - 0.4)
        ax.set_ylabel("%\u03c3")
        ax.grid(axis="x", visible=False)
        ax.legend(loc="upper left", frameon=False, ncols=2)
    if caption is None:
        caption = "Relative standard deviation %\u03c3 of the essential parameters"
        if has_ref:
            caption += ", beside the paper's %\u03c3 (Table 2) where the parameter is in both"
        if logy:
            caption += " (log scale)"
    return render_figure(fig, key, caption, fmt=fmt)


def verdict_rel_std_figure(names, rel_sigma, threshold, *, key="fig-verdict-rel-std", caption=None,
                           fmt="auto", kind="essential"):
    """%σ of the judged parameters with the identification threshold; flagged bars in amber.

    `kind`: which parameters the verdict judged, "essential" (IDIM, DIDIM) or "base" (the
    Projection Method, ML), named in the default caption.
    """
    names = [str(n) for n in names]
    rs = np.asarray(rel_sigma, dtype=float)
    bad = ~(rs <= threshold)
    x = np.arange(len(names))
    finite = rs[np.isfinite(rs) & (rs > 0)]
    logy = finite.size > 0 and max(finite.max(), threshold) / max(min(finite.min(), threshold), 1e-12) > 30
    with matplotlib.rc_context(STYLE):
        fig = _new_figure(min(10.5, max(4.0, 0.26 * len(names) + 1.2)), 2.6)
        ax = fig.subplots()
        shown = np.where(np.isfinite(rs), rs, np.nan)
        ax.bar(x[~bad], shown[~bad], width=0.7, color=BLUE, label="identified")
        if bad.any():
            top = np.nanmax(np.where(np.isfinite(rs), rs, np.nan)) if np.isfinite(rs).any() else threshold
            ax.bar(x[bad], np.where(np.isfinite(shown[bad]), shown[bad], 2 * max(top, threshold)),
                   width=0.7, color=AMBER, hatch="//", edgecolor="white", linewidth=0.0,
                   label=f"not identified (%\u03c3 > {threshold:g} %)")
        ax.axhline(threshold, color=RED, ls="--", lw=1.0, label=f"threshold {threshold:g} %")
        if logy:
            log_scale(ax, minor_labels=False)
        ax.set_xticks(x, [_plain(n) for n in names], rotation=90)
        ax.set_xlim(-0.6, len(names) - 0.4)
        ax.set_ylabel("%\u03c3")
        ax.grid(axis="x", visible=False)
        fig.legend(*ax.get_legend_handles_labels(), loc="outside upper left", frameon=False, ncols=3)
    if caption is None:
        caption = (f"%\u03c3 = 100 \u03c3/|\u03c7\u0302| of the {kind} parameters; bars above the "
                   f"{threshold:g} % line (amber, hatched) are flagged as not identified"
                   + (" (log scale)" if logy else ""))
    return render_figure(fig, key, caption, fmt=fmt)
