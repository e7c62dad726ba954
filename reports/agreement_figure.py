"""Report figure of the cross-recording (or cross-segment) agreement (issue 26).

`agreement_figure(a)` draws the pairwise z-scores of dynid.analysis.estimators.agreement
(`agreement(...)` or `IDIMResult.agreement`) against N(0, 1): left, their normal Q-Q
plot with the ±1.96 band; right, the histogram of z with the N(0, 1) density. The
title carries the fraction within ±1.96, the count of pairs and the χ² test of equal
parameters; the caption says which covariance produced the σ.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from dynid.reports import figures as F

__all__ = ["agreement_figure"]


def agreement_figure(a: dict, *, key: str = "fig-agreement", caption: str | None = None, fmt: str = "auto"):
    """FigureMarkup of the z-scores of `a` (dict of `agreement`) against N(0, 1).

    Parameters
    ----------
    a : dict
        `z` (list of {a, b, name, z}), `within_95`, `pairs`, `median_abs_z`,
        `chi2`, `dof`, `p_value`, `kind`, optionally `uncertainty`.
    key, caption, fmt
        As for dynid.reports.figures.render_figure.

    Returns
    -------
    FigureMarkup

    Examples
    --------
    >>> fig = agreement_figure(result.agreement)   # doctest: +SKIP
    """
    z = np.array([r["z"] for r in a.get("z", [])], dtype=float)
    fig = F._new_figure(7.5, 3.0)
    ax1, ax2 = fig.subplots(1, 2)
    what = a.get("kind", "recordings")
    if z.size:
        zs = np.sort(z)
        p = (np.arange(1, z.size + 1) - 0.5) / z.size
        q = stats.norm.ppf(p)
        ax1.plot(q, zs, "o", ms=3, color=F.BLUE)
        lim = max(3.0, float(np.max(np.abs(zs))) * 1.05, float(np.max(np.abs(q))) * 1.05)
        ax1.plot([-lim, lim], [-lim, lim], color="k", lw=0.7)
        ax1.axhspan(-1.96, 1.96, color="#cccccc", alpha=0.4, lw=0)
        ax1.set_ylim(-lim, lim)
        cut = 8.0
        ax2.hist(np.clip(z, -cut, cut), bins=np.linspace(-cut, cut, 33), density=True, color=F.BLUE, alpha=0.6)
        x = np.linspace(-cut, cut, 200)
        ax2.plot(x, stats.norm.pdf(x), color=F.RED, lw=1.0, label="N(0, 1)")
        ax2.legend(loc="upper right")
    else:
        ax1.text(0.5, 0.5, "no pair identified in two runs", ha="center", va="center", transform=ax1.transAxes)
    ax1.set_xlabel("N(0, 1) quantile")
    ax1.set_ylabel("z = (chi_a - chi_b) / sqrt(sa^2 + sb^2)")
    ax2.set_xlabel("z (clipped at +-8)")
    ax2.set_ylabel("density")
    within = a.get("within_95", float("nan"))
    fig.suptitle(F._plain(
        f"{a.get('k', '?')} {what}: {100 * within:.0f} % of {a.get('pairs', 0)} pairs within +-1.96 "
        f"(95 % expected); chi2 {a.get('chi2', float('nan')):.4g} on {a.get('dof', 0)} dof, "
        f"p = {a.get('p_value', float('nan')):.2g}"), fontsize=9)
    if caption is None:
        caption = (f"Pairwise differences of the parameters two {what} both identify (%sigma <= "
                   f"{a.get('rel_max', 10):g} %), in units of their combined sigma "
                   f"({a.get('uncertainty', 'classic')} covariance), against N(0, 1).")
    return F.render_figure(fig, key, caption, fmt=fmt)
