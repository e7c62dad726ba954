"""Report sections for a Bayesian posterior (`dynid.analysis.sampling.posterior.PosteriorResult`).

`bayes_sections` returns `dynid.reports.html.Section` objects to pass
as `extra_sections` to `dynid.reports.html.render_idim_report` or to
`dynid.reports.html.render_sections`:

* `<prefix>`: the convergence verdict first and prominently (a run that did
  not converge says so in the section title and in a red box, with the
  reason), the posterior table beside the LS value and %σ, and a corner plot
  drawn here with matplotlib (histograms on the diagonal, scatter and
  39 % / 86 % highest-density contours below it, the LS estimate and its
  95 % ellipse in red). With more than `max_corner` (8) parameters the
  plot shows the `max_corner` with the largest |posterior correlation|
  with another parameter, and its caption says which and why.
* `<prefix>-convergence`: τ, ESS, split R̂ per parameter, acceptance, the
  rule and the τ estimate against chain length / 50.
"""
from __future__ import annotations

from dataclasses import dataclass

import matplotlib
import numpy as np
import pandas as pd
from markupsafe import Markup
from matplotlib.figure import Figure
from scipy import stats

from dynid.analysis.units import parameter_unit
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import Section, join, kv_list, para

__all__ = ["bayes_sections", "corner_figure", "tau_history_figure",
           "posterior_table", "diagnostics_table", "corner_selection", "status_markup"]

MAX_CORNER = 8
_SCATTER_MAX = 1500


# ------------------------------------------------------------------ helpers
def _noise(name: str) -> bool:
    return name.startswith("sigma")


def corner_selection(result, max_params: int = MAX_CORNER, include_noise: bool = False):
    """(indices, note): the parameters of the corner plot and, if some were left out, why.

    The model parameters (without the noise σ's unless `include_noise` or
    nothing else is left); if more than `max_params`, those with the largest
    max_j |corr_ij| (j ≠ i), in their original order.
    """
    idx = [i for i, n in enumerate(result.names) if include_noise or not _noise(n)]
    if len(idx) < 2:
        idx = list(range(len(result.names)))
    note = ""
    if len(idx) > max_params:
        C = np.abs(np.nan_to_num(result.corr[np.ix_(idx, idx)]))
        np.fill_diagonal(C, 0.0)
        score = C.max(axis=1)
        order = np.argsort(-score, kind="stable")[:max_params]
        chosen = sorted(int(k) for k in order)
        note = (f"{max_params} of {len(idx)} parameters shown: those with the largest absolute "
                f"posterior correlation with another parameter")
        idx = [idx[k] for k in chosen]
    return idx, note


def _hdr_levels(H, masses=(0.393, 0.865)):
    """Density thresholds enclosing the given probability masses of histogram H."""
    flat = np.sort(H.ravel())[::-1]
    cum = np.cumsum(flat)
    if cum[-1] <= 0:
        return []
    cum /= cum[-1]
    levels = []
    for m in sorted(masses, reverse=True):
        k = min(np.searchsorted(cum, m), flat.size - 1)
        levels.append(flat[k])
    levels = sorted(set(float(v) for v in levels if v > 0))
    return levels


def _ellipse(mean, cov, level):
    w, V = np.linalg.eigh(cov)
    if not np.all(np.isfinite(w)) or np.any(w <= 0):
        return None
    t = np.linspace(0, 2 * np.pi, 121)
    r = np.sqrt(stats.chi2.ppf(level, 2) * w)
    return mean + (np.stack([np.cos(t), np.sin(t)], 1) * r) @ V.T


def _thin_index(n, m=_SCATTER_MAX):
    return np.linspace(0, n - 1, min(n, m)).astype(int)


# ------------------------------------------------------------------ figures
def corner_figure(result, *, indices=None, note="", key="fig-posterior-corner", caption=None,
                  max_params=MAX_CORNER):
    """Corner plot of the posterior (PNG: thousands of points)."""
    if indices is None:
        indices, note = corner_selection(result, max_params)
    names = [result.names[i] for i in indices]
    S = result.samples[:, indices]
    k = len(indices)
    ls = result.ls_value[indices]
    lcov = None if result.ls_cov is None else result.ls_cov[np.ix_(indices, indices)]
    truth = result.truth or {}
    c = _Corner(S=S, names=names, ls=ls, lcov=lcov, truth=truth, sel=_thin_index(S.shape[0]),
                lims=_corner_limits(S, ls, truth, names), ci95=[result.ci95[i] for i in indices])
    with matplotlib.rc_context(F.STYLE):
        size = min(11.0, 1.35 * k + 0.6)
        fig = Figure(figsize=(size, size))
        axes = fig.subplots(k, k, squeeze=False)
        fig.subplots_adjust(left=0.09, bottom=0.09, right=0.985, top=0.985, wspace=0.08, hspace=0.08)
        for i in range(k):
            for j in range(k):
                ax = axes[i, j]
                if j > i:
                    ax.set_visible(False)
                    continue
                ax.grid(False)
                if i == j:
                    _corner_diagonal(ax, c, i)
                else:
                    _corner_pair(ax, c, i, j)
                _corner_labels(ax, names, i, j, k)
    if caption is None:
        caption = _corner_caption(result, truth, note, names)
    return F.render_figure(fig, key, caption, fmt="png")


@dataclass
class _Corner:
    """What every panel of the corner plot draws from."""

    S: np.ndarray          # draws of the plotted parameters
    names: list
    ls: np.ndarray         # least-squares estimate
    lcov: np.ndarray       # its covariance, or None
    truth: dict
    sel: np.ndarray        # thinned draws shown as points
    lims: list             # axis range per parameter
    ci95: list             # 95 % credible interval per parameter


def _corner_limits(S, ls, truth, names):
    """Axis range of each parameter: its draws' 0.1-99.9 % range, widened to show LS and truth."""
    lims = []
    for i in range(S.shape[1]):
        lo, hi = np.quantile(S[:, i], [0.001, 0.999])
        span = hi - lo if hi > lo else max(abs(hi), 1.0) * 1e-6
        lo, hi = lo - 0.08 * span, hi + 0.08 * span
        for v in (ls[i], truth.get(names[i], np.nan)):
            if np.isfinite(v):
                lo, hi = min(lo, v - 0.02 * span), max(hi, v + 0.02 * span)
        lims.append((lo, hi))
    return lims


def _corner_diagonal(ax, c, i):
    """Marginal histogram with the 95 % interval, the LS estimate and the true value."""
    ax.hist(c.S[:, i], bins=30, range=c.lims[i], color="#c8d3e8", edgecolor="#8fa3c8",
            linewidth=0.4, histtype="stepfilled")
    lo95, hi95 = c.ci95[i]
    ax.axvline(lo95, color=F.BLUE, ls=":", lw=0.8)
    ax.axvline(hi95, color=F.BLUE, ls=":", lw=0.8)
    if np.isfinite(c.ls[i]):
        ax.axvline(c.ls[i], color=F.RED, ls="--", lw=0.9)
    if c.names[i] in c.truth:
        ax.axvline(c.truth[c.names[i]], color=F.GREEN, lw=0.9)
    ax.set_yticks([])
    ax.set_xlim(c.lims[i])


def _corner_pair(ax, c, i, j):
    """Pairwise draws with density contours, the LS estimate and its 95 % ellipse, the true value."""
    ls, names, truth = c.ls, c.names, c.truth
    x, y = c.S[:, j], c.S[:, i]
    ax.plot(x[c.sel], y[c.sel], ".", ms=1.0, color="#8fa3c8", alpha=0.5, rasterized=True)
    H, xe, ye = np.histogram2d(x, y, bins=24, range=[c.lims[j], c.lims[i]])
    levels = _hdr_levels(H)
    if len(levels) >= 1 and np.count_nonzero(H) > 3:
        xc, yc = 0.5 * (xe[1:] + xe[:-1]), 0.5 * (ye[1:] + ye[:-1])
        try:
            ax.contour(xc, yc, H.T, levels=levels, colors=F.BLUE, linewidths=0.7)
        except ValueError:
            pass
    if np.isfinite(ls[i]) and np.isfinite(ls[j]):
        ax.plot(ls[j], ls[i], "+", color=F.RED, ms=6, mew=1.0)
        if c.lcov is not None:
            e = _ellipse(np.array([ls[j], ls[i]]), c.lcov[np.ix_([j, i], [j, i])], 0.95)
            if e is not None:
                ax.plot(e[:, 0], e[:, 1], color=F.RED, lw=0.7, ls="--")
    if names[i] in truth and names[j] in truth:
        ax.plot(truth[names[j]], truth[names[i]], "x", color=F.GREEN, ms=5)
    ax.set_xlim(c.lims[j])
    ax.set_ylim(c.lims[i])


def _corner_labels(ax, names, i, j, k):
    if i == k - 1:
        ax.set_xlabel(F._plain(names[j]))
        ax.tick_params(axis="x", labelrotation=45, labelsize=6)
    else:
        ax.set_xticklabels([])
    if j == 0 and i > 0:
        ax.set_ylabel(F._plain(names[i]))
        ax.tick_params(axis="y", labelsize=6)
    elif i != j:
        ax.set_yticklabels([])


def _corner_caption(result, truth, note, names):
    caption = ("Posterior corner plot: marginal histograms (diagonal; dotted blue: 95 % credible "
               "interval), pairwise draws with contours enclosing 39 % and 86 % of the posterior "
               f"mass (below); red: {result.ls_label} estimate (+, dashed line) and its 95 % "
               "ellipse")
    if truth:
        caption += "; green: true value"
    if note:
        caption += f". {note}: {', '.join(names)}"
    return caption


def tau_history_figure(result, *, key="fig-posterior-tau", caption=None):
    """max τ estimate after each batch against chain length / tau_multiple (the rule)."""
    dg = result.diagnostics
    h = np.array([(n, t) for n, t in dg.history], dtype=float).reshape(-1, 2)
    with matplotlib.rc_context(F.STYLE):
        fig = Figure(figsize=(4.6, 2.6), layout="constrained")
        ax = fig.subplots()
        if h.size:
            n = np.concatenate([[0.0], h[:, 0]])
            ax.plot(n, n / dg.criteria.tau_multiple, color=F.GREY, ls="--", lw=0.9,
                    label=f"N / {dg.criteria.tau_multiple:g}")
            ax.plot(h[:, 0], h[:, 1], "o-", color=F.BLUE, ms=3, lw=1.0, label="max τ estimate")
        ax.set_xlabel("chain length N [steps]")
        ax.set_ylabel("τ [steps]")
        ax.legend(loc="upper left", frameon=False)
    if caption is None:
        caption = ("Autocorrelation time estimated after each batch (blue) against N / "
                   f"{dg.criteria.tau_multiple:g} (dashed): the chain is long enough where the blue "
                   "point lies below the dashed line (τ on the whole chain, before burn-in is "
                   "discarded)")
    return F.render_figure(fig, key, caption, fmt="svg")


# ------------------------------------------------------------------ tables
def posterior_table(result, *, key="tab-posterior", caption=None):
    """Posterior mean, median, std, 95 % and 99.9 % intervals beside the LS value and %σ."""
    df = pd.DataFrame({
        "unit": [parameter_unit(n) or "-" for n in result.names],
        "ls_value": result.ls_value, "ls_rel_std_percent": result.ls_rel_std,
        "mean": result.mean, "median": result.median, "std": result.std,
        "post_rel_std_percent": result.rel_std,
        "ci95_low": result.ci95[:, 0], "ci95_high": result.ci95[:, 1],
        "ci999_low": result.ci999[:, 0], "ci999_high": result.ci999[:, 1],
    }, index=pd.Index(result.names, name="parameter"))
    labels = {"ls_value": f"{result.ls_label} \u03c7\u0302", "ls_rel_std_percent": f"{result.ls_label} %\u03c3",
              "mean": "mean", "median": "median", "std": "std", "post_rel_std_percent": "%\u03c3 (post.)",
              "ci95_low": "95 % low", "ci95_high": "95 % high",
              "ci999_low": "99.9 % low", "ci999_high": "99.9 % high"}
    if result.truth:
        df["truth"] = [result.truth.get(n, np.nan) for n in result.names]
        labels["truth"] = "true value"
    csv = result.to_frame()
    return T.make_table(df, key, caption or "Posterior summaries beside the LS estimate",
                        labels=labels, csv_frame=csv, formats={"unit": "text"},
                        note=("%\u03c3 (post.) = 100 std / |mean|; intervals are equal-tailed "
                              "credible intervals from the kept draws."
                              + "".join(f" The LS value of \u03c3\u2c7c is eq. (16)'s; the posterior is "
                                        f"{line.strip()}." for line in result._optimum_lines())
                              + ("" if result.converged else " NOT CONVERGED: these numbers are not "
                                 "reliable.")))


def diagnostics_table(result, *, key="tab-posterior-diagnostics", caption=None):
    dg = result.diagnostics
    df = pd.DataFrame({"tau": dg.tau, "chain_over_tau": (dg.n_steps - dg.burn_in) / dg.tau,
                       "ess": result.ess, "rhat": dg.rhat, "sampled": dg.sampled},
                      index=pd.Index(result.names, name="parameter"))
    return T.make_table(df, key, caption or "Per-parameter convergence diagnostics",
                        labels={"tau": "\u03c4 [steps]", "chain_over_tau": "chain / \u03c4",
                                "ess": "ESS", "rhat": "split R\u0302",
                                "sampled": "sampled"},
                        formats={"sampled": "bool"},
                        note=("Parameters not marked 'sampled' are drawn exactly from their "
                              "conditional posterior at each state; the rule applies to the sampled "
                              "ones." if not dg.sampled.all() else
                              "\u03c4 and R\u0302 of \u03c3\u2c7c are those of the sampled log \u03c3\u2c7c."
                              if any(_noise(n) for n in result.names) else ""))


# ------------------------------------------------------------------ body
def status_markup(result) -> Markup:
    """The converged flag as a coloured box (inline style: the template has no alert class)."""
    if result.converged:
        return Markup('<p class="bayes-status ok" style="border:1px solid #2ca02c;background:#eef8ee;'
                      'padding:0.35rem 0.6rem;border-radius:4px"><strong>CONVERGED</strong> \u2014 {}</p>'
                      ).format(result.reason)
    return Markup('<p class="bayes-status not-converged" style="border:2px solid #b3261e;background:#fdecea;'
                  'color:#7a1a14;padding:0.45rem 0.7rem;border-radius:4px;font-size:1.05rem">'
                  '<strong>NOT CONVERGED</strong> \u2014 the intervals below are not reliable. {}</p>'
                  ).format(result.reason)


def _fmt(x, digits=4):
    return T.format_number(x, digits)


def bayes_sections(result, *, prefix: str = "posterior", title: str | None = None,
                   max_corner: int = MAX_CORNER):
    """The report sections of `result` (see the module docstring)."""
    dg = result.diagnostics
    flag = "" if result.converged else " \u2014 NOT CONVERGED"
    st = result.settings
    pairs = [("Model", result.model)]
    for k, label in (("prior_chi", "Prior on \u03c7"), ("priors", "Priors"), ("noise", "Noise"),
                     ("linear_parameters", "Linear parameters"), ("moves", "emcee moves"),
                     ("init", "Initial walkers"), ("seed", "Seed")):
        if k in st:
            v = st[k]
            pairs.append((label, v if isinstance(v, (str, int)) else "Gaussian (given mean and covariance)"))
    nm = st.get("noise_model")
    if isinstance(nm, dict) and nm.get("description"):
        pairs.append(("Noise model", nm["description"]))
    pairs += [("Walkers \u00d7 steps", f"{dg.n_walkers} \u00d7 {dg.n_steps}"),
              ("Burn-in / thin", f"{dg.burn_in} / {dg.thin} steps"),
              ("Kept draws", str(result.n_samples))]
    body = join(status_markup(result), kv_list(pairs))
    idx, note = corner_selection(result, max_corner)
    corner = corner_figure(result, indices=idx, note=note, key=f"fig-{prefix}-corner")
    if note:
        body = join(body, para(f"Corner plot: {note} ({', '.join(result.names[i] for i in idx)}).",
                               cls="hint"))
    main = Section(prefix, (title or "Posterior (emcee)") + flag, body,
                   figures=[corner], tables=[posterior_table(result, key=f"tab-{prefix}")],
                   tables_first=True)

    c = dg.criteria
    conv_pairs = [
        ("Verdict", "converged" if result.converged else "NOT CONVERGED"),
        ("Reason", dg.reason),
        ("Rule", f"chain after burn-in \u2265 {c.tau_multiple:g} \u03c4 for every sampled parameter, "
                 f"split R\u0302 < {c.rhat_max:g}, mean acceptance \u2265 {c.min_acceptance:g}, no stuck "
                 f"walker; burn-in {c.burn_in_tau:g} \u03c4, thin {c.thin_tau:g} \u03c4"),
        ("max \u03c4", f"{_fmt(dg.tau_max)} steps"),
        ("chain / max \u03c4", _fmt(dg.chain_over_tau, 3)),
        ("max split R\u0302", _fmt(dg.rhat_max, 5)),
        ("Acceptance (mean / min walker)", f"{dg.acceptance_mean:.3f} / {float(np.min(dg.acceptance)):.3f}"),
        ("Limits", f"step budget max_steps = {c.max_steps}; " + (
            f"wall-clock limit max_seconds = {c.max_seconds:g} s (asked for)" if c.max_seconds is not None
            else "no wall-clock limit (the stop depends only on the chain)")),
    ]
    if dg.limit:
        conv_pairs.append(("Stopped by", f"the {dg.limit} limit"))
    conv = Section(f"{prefix}-convergence", "MCMC convergence diagnostics" + flag,
                   join(status_markup(result), kv_list(conv_pairs)),
                   figures=[tau_history_figure(result, key=f"fig-{prefix}-tau")],
                   tables=[diagnostics_table(result, key=f"tab-{prefix}-diagnostics")],
                   tables_first=True)
    return [main, conv]
