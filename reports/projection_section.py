"""Report section of the closed-loop methods of Bona & Curatella (2005): PM and ML.

`projection_section` shows a `dynid.analysis.estimators.projection.ProjectionResult`
(eqs. (10)-(12)) and, when given, an `dynid.analysis.estimators.maximum_likelihood.MLResult`
(eqs. (13)-(16)): a table of the estimates with %σ next to plain LS (and the
true values of simulated data), the per-joint FIR windows with the
correlation between û and u − û that the paper asks to be ≈ 0, and a figure
of û against u − û. Returns a `dynid.reports.html.Section` for
`dynid.reports.html.render_sections`.
"""
from __future__ import annotations

import matplotlib
import numpy as np
import pandas as pd

from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import Section, bullets, join, kv_list, para

__all__ = ["projection_section", "estimates_frame"]


def estimates_frame(pm, ml=None, truth=None):
    """One row per parameter: LS, PM (and ML) value and %σ (and the true value)."""
    df = pd.DataFrame(index=pd.Index(pm.names, name="parameter"))
    if pm.ls is not None:
        df["ls"] = pm.ls.chi
        df["ls_rel_std"] = pm.ls.rel_std.to_numpy()
    df["pm"] = pm.chi
    df["pm_rel_std"] = pm.rel_std.to_numpy()
    if ml is not None:
        ml_map = dict(zip(ml.names, zip(ml.chi, ml.rel_std.to_numpy())))
        df["ml"] = [ml_map.get(n, (np.nan, np.nan))[0] for n in pm.names]
        df["ml_rel_std"] = [ml_map.get(n, (np.nan, np.nan))[1] for n in pm.names]
    if truth is not None:
        df["true"] = [truth.get(n, np.nan) for n in pm.names] if isinstance(truth, dict) else truth
    return df


def _scatter_figure(pm, key):
    n = pm.u_hat.shape[1]
    with matplotlib.rc_context(F.STYLE):
        fig = F._new_figure(3.3 * min(n, 3), 2.6 * int(np.ceil(n / 3)) + 0.3)
        axes = fig.subplots(int(np.ceil(n / 3)), min(n, 3), squeeze=False)
        for j in range(axes.size):
            ax = axes.flat[j]
            if j >= n:
                ax.set_visible(False)
                continue
            step = max(1, pm.u_hat.shape[0] // 3000)
            ax.plot(pm.u_hat[::step, j], pm.u_tilde[::step, j], ".", ms=1.5, color=F.BLUE)
            ax.set_title(f"joint {j + 1}: corr {pm.corr[j]:.1e}", loc="left")
            ax.set_xlabel("u_hat [N m]")
            if j % 3 == 0:
                ax.set_ylabel("u - u_hat [N m]")
    caption = ("Estimated torque u_hat = S_hat r (eq. (11)) against the remainder u - u_hat: "
               "no trend means the projection removed what the reference explains")
    return F.render_figure(fig, key, caption)


def projection_section(pm, ml=None, *, truth=None, id="projection",
                       title="Closed-loop identification: Projection Method and maximum likelihood "
                             "(Bona & Curatella 2005)"):
    """A `Section` for a Projection Method result, optionally with an ML result.

    `truth`: true parameter values (dict by name, or array in `pm.names`
    order) for simulated data.
    """
    body = [para("Stage 1 fits, per joint, the non-causal FIR filter u(t) = c + Σ s_k r(t−k), "
                 "k = −M1..M2, of the reference r (eq. (10)); stage 2 identifies the parameters by "
                 "least squares with the estimated torque û (eq. (11)) and the regressor projected "
                 "on the same lagged reference (two-stage least squares, eq. (12)).")]
    pairs = [("Rows used", f"{pm.n_rows} of {pm.n_samples}"),
             ("Relative error |u − Wχ|/|u|", T.format_number(pm.rel_error)),
             ("Covariance", f"IV sandwich, Newey–West with {pm.hac_lags} lags")]
    if ml is not None:
        pairs += [("ML latent trajectory", f"K = {ml.n_harmonics} harmonics of {ml.f0:g} Hz"),
                  ("ML noise σ_q / σ_τ", ", ".join(f"{a:.3g} rad / {b:.3g} N m"
                                                   for a, b in zip(ml.sigma_q, ml.sigma_tau)))]
    body.append(kv_list(pairs))
    if pm.notices:
        body.append(bullets(pm.notices, cls="notices"))
    est = estimates_frame(pm, ml, truth)
    labels = {"ls": "LS", "ls_rel_std": "LS %σ", "pm": "PM", "pm_rel_std": "PM %σ",
              "ml": "ML", "ml_rel_std": "ML %σ", "true": "true"}
    formats = {c: "pct" for c in est.columns if c.endswith("_rel_std")}
    tables = [T.make_table(est, f"tab-{id}-estimates",
                           "Parameters by plain LS, the Projection Method" + (" and ML" if ml is not None else ""),
                           labels=labels, formats=formats),
              T.make_table(pm.joint_table(), f"tab-{id}-fir",
                           "FIR windows and the correlation between û and u − û (eq. (11))",
                           labels={"corr_uhat_utilde": "corr(û, u − û)", "max_xcorr": "max |xcorr|",
                                   "max_xcorr_lag": "at lag", "fir_rank": "rank"},
                           formats={"M1": "int", "M2": "int", "fir_rank": "int", "max_xcorr_lag": "int"})]
    figs = [_scatter_figure(pm, f"fig-{id}-uhat")] if pm.u_hat is not None else []
    return Section(id, title, join(*body), figures=figs, tables=tables, tables_first=True)


def ml_section(ml, *, id="maximum-likelihood",
               title="Maximum likelihood with noise on q and τ (Bona & Curatella 2005, eqs. (13)–(16))"):
    """A `Section` for an `dynid.analysis.estimators.maximum_likelihood.MLResult` on its own."""
    body = [para("The positions are measured with noise too: the likelihood of eq. (13) is maximised "
                 "over the parameters and a latent trajectory (a Fourier series in the excitation's "
                 "fundamental), with one noise level per signal and joint; the covariance is the "
                 "inverse Fisher information."),
            kv_list([("Latent trajectory", f"K = {ml.n_harmonics} harmonics of {ml.f0:g} Hz"),
                     ("Noise σ_q / σ_τ", ", ".join(f"{a:.3g} rad / {b:.3g} N m"
                                                   for a, b in zip(ml.sigma_q, ml.sigma_tau)))])]
    if ml.notices:
        body.append(bullets(ml.notices, cls="notices"))
    # the IDIM report's headers: χ̂, σ, %σ; the unit column holds the unit of the value, σ and LS start
    est = ml.to_frame()[["value", "std", "rel_std_percent", "ls_start", "unit"]]
    tab = T.make_table(est, f"tab-{id}-estimates", "ML estimates beside their LS start",
                       labels={"value": "ML \u03c7\u0302", "std": "\u03c3", "rel_std_percent": "%\u03c3",
                               "ls_start": "LS start \u03c7\u0302", "unit": "unit"},
                       formats={"rel_std_percent": "pct", "unit": "text"})
    return Section(id, title, join(*body), tables=[tab], tables_first=True)
