"""Report figure of the cross-recording (or cross-segment) agreement (issue 26).

`agreement_figure(a)` draws the pairwise z-scores of an `Agreement`
(dynid.analysis.estimators.agreement: `agreement(...)` or `IDIMResult.agreement`) against N(0, 1): left, their normal Q-Q
plot with the ±1.96 band; right, the histogram of z with the N(0, 1) density. The
title carries the fraction within ±1.96, the count of pairs and the χ² test of equal
parameters; the caption says which covariance produced the σ. `agreement_section(a)`
is the report section: the verdict's line, the figure and the per-parameter table
(random-effects pooled value, between-run spread, Cochran's Q p-value) with units.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from dynid.analysis.estimators.agreement import Agreement
from dynid.analysis.results import p_phrase
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import Section, para

__all__ = ["agreement_figure", "agreement_section"]


def agreement_figure(a: Agreement, *, key: str = "fig-agreement", caption: str | None = None,
                     fmt: str = "auto"):
    """FigureMarkup of the pairwise z-scores of `a` against N(0, 1).

    Parameters
    ----------
    a : Agreement
        Its `z` (list of {a, b, name, z}), `within_95`, `pairs`, the χ² test and `uncertainty`.
    key, caption, fmt
        As for dynid.reports.figures.render_figure.

    Returns
    -------
    FigureMarkup

    Examples
    --------
    >>> fig = agreement_figure(result.agreement)   # doctest: +SKIP
    """
    z = np.array([r["z"] for r in a.z], dtype=float)
    fig = F._new_figure(7.5, 3.0)
    ax1, ax2 = fig.subplots(1, 2)
    what = a.kind
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
    fig.suptitle(F._plain(
        f"{a.k} {what}: {100 * a.within_95:.0f} % of {a.pairs} pairs within +-1.96 "
        f"(95 % expected); chi2 {a.chi2:.4g} on {a.dof:.1f} dof, {p_phrase(a.p_value)}"), fontsize=9)
    if caption is None:
        caption = (f"Pairwise differences of the parameters two {what} both identify (%sigma <= "
                   f"{a.rel_max:g} %), in units of their combined sigma "
                   f"({a.uncertainty} covariance), against N(0, 1).")
    return F.render_figure(fig, key, caption, fmt=fmt)


def agreement_section(a: Agreement, line: str) -> Section:
    """The report section of the cross-recording (cross-segment) agreement.

    Parameters
    ----------
    a : Agreement
        `IDIMResult.agreement`.
    line : str
        The verdict's agreement line (`IDIMResult.agreement_line`), shown first.

    Returns
    -------
    Section
        Id `agreement`: the line, a paragraph on how to read it, `agreement_figure`
        and the per-parameter table `tab-agreement`.
    """
    what = a.kind
    one = what[:-1]
    body = para(line, " ", (
        f"Each {one} was identified alone (per-joint WLS with the weights of the whole); for every "
        f"parameter that two {what} both identify (%sigma <= {a.rel_max:g} %) the "
        f"difference is divided by its combined sigma. If the intervals held what another {one} "
        "finds, these z would follow N(0, 1): 95 % within +-1.96, median |z| 0.67. More spread "
        "means model error that differs between trajectories (friction shape, elasticity, an "
        f"unmodelled torque): the sigma of one {one} does not include it, and the pooled value "
        f"with its between-{one} spread below is the more honest figure."
        + (f" Left out (not identified by every {one}): {', '.join(a.left_out)}."
           if a.left_out else "")))
    df = a.to_frame().drop(columns="rel_std_percent").rename(columns={"value": "pooled", "std": "pooled_std"})
    tab = T.make_table(df, "tab-agreement", f"Per parameter over the {a.k} {what}: "
                       "random-effects (DerSimonian-Laird) pooled value and its sigma including the "
                       f"between-{one} spread, that spread, and the p-value of Cochran's Q test of "
                       "equal values", formats={"unit": "text"},
                       labels={"pooled": "pooled value", "pooled_std": "pooled sigma",
                               "between_std": f"between-{one} sigma", "p_value": "Q p-value"})
    title = f"Do the {what} agree within their intervals?"
    return Section("agreement", title, body, figures=[agreement_figure(a)], tables=[tab])
