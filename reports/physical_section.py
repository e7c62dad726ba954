"""Report sections of a PC-WLS fit (`dynid.analysis.estimators.physical.PhysicalResult`) and of
effects fitted beside the rigid body (`--effects`).

What the constraints are, which are active at the solution, what they cost
(chi^2 and its p-value bound against the unconstrained WLS), the base
parameters of both fits, and each link's principal moments of inertia about
its centre of mass as a figure (a consistent link has three non-negative
moments, each at most the sum of the other two).
"""
from __future__ import annotations

import matplotlib
import numpy as np
import pandas as pd

from dynid.reports import tables as T
from dynid.reports.figures import BLUE, STYLE, _new_figure, log_scale, render_figure
from dynid.reports.html import Section, bullets, join, para


def principal_moments_figure(result, *, key="fig-physical-moments", fmt="auto"):
    """Bars of the three principal moments (about the centre of mass) of each link, log scale."""
    rows = [(lk["link"], lk["principal_moments"] or [np.nan] * 3, lk["mass"]) for lk in result.links]
    with matplotlib.rc_context(STYLE):
        fig = _new_figure(min(10.0, 1.2 + 0.9 * len(rows)), 3.0)
        ax = fig.subplots()
        x = np.arange(len(rows))
        for i, shade in enumerate((0.45, 0.7, 1.0)):
            vals = [max(float(m[i]), 1e-12) if np.isfinite(m[i]) else np.nan for _, m, _ in rows]
            ax.bar(x + (i - 1) * 0.27, vals, width=0.25, color=BLUE, alpha=shade,
                   label=["smallest", "middle", "largest"][i])
        log_scale(ax)
        ax.set_xticks(x, [f"link {k}\n{m:.3g} kg" for k, _, m in rows])
        ax.set_ylabel("principal moment [kg m\u00b2]")
        ax.grid(axis="x", visible=False)
        ax.legend(loc="upper left", frameon=False, ncols=3)
    return render_figure(fig, key, "Principal moments of inertia about the centre of mass of each link of "
                         "the physically consistent set (log scale; a moment at the 1e-9 floor is a link "
                         "the data make as thin as a rod or a point)", fmt=fmt)


def physical_section(result, *, id="physical", fmt="auto", effects_spec=None):
    """The section: constraints, active set, cost, parameter table, principal-moment figure.
    `effects_spec`: the fit was made with these effects beside the rigid body (`--effects`), so
    its unconstrained WLS is that model's, not the rigid body's of the identification."""
    r = result
    wls_is = ("" if effects_spec is None else
              f"The unconstrained WLS here is that of the rigid body with the effects {effects_spec} "
              "(section \u201cEffects fitted beside the rigid body\u201d), not the rigid body alone of the "
              "identification above: its base parameters differ from the identification's where the "
              "effects take up torque. ")
    body = join(
        para("Physically consistent WLS (PC-WLS): the weighted residual of the WLS minimised over the "
             "standard parameters under every link's pseudo-inertia positive semidefinite (Wensing, "
             "Kim & Slotine 2017: mass \u2265 0, centre of mass where a non-negative density can put it, "
             "triangle inequalities), Ia \u2265 0, Fv \u2265 0, Fc \u2265 0"
             + (f", masses within \u00b1{100 * r.mass_tolerance:g} % of the a-priori values"
                if r.mass_tolerance is not None else "")
             + "; solved as an SDP (cvxpy + Clarabel), a global optimum."),
        para(wls_is + f"Verdict: {r.verdict_line()}. \u03c7\u00b2 = {r.chi2:.4g} (growth of the weighted squared "
             f"residual in units of the WLS error variance) on {r.dof} active constraint directions, "
             f"p \u2264 {r.p_value:.3g} (a chi-bar-squared bound). Relative error on the identification "
             f"data: PC {100 * r.rel_error:.3f} %, unconstrained WLS {100 * r.wls_rel_error:.3f} %. "
             f"Unconstrained WLS physical: {'yes' if r.wls_consistent else 'no'}."
             + (f" Held out (all {r.validation['n_samples']} decimated samples): PC "
                f"{100 * r.validation['rel_error_pc']:.3f} %, unconstrained WLS "
                f"{100 * r.validation['rel_error_wls']:.3f} % (PC \u2212 WLS {r.validation['gap_points']:+.3f} "
                "points)." if getattr(r, "validation", None) else "")),
        para(f"A-priori term: {'weight ' + format(r.prior_weight, 'g') if r.prior else 'tie-break only (weight ' + format(r.prior_weight, 'g') + ')'}. "
             f"95 % intervals of the PC parameters: the hull of the percentiles of a parametric bootstrap "
             f"of the constrained fit ({r.n_boot} refits) and the PC value \u00b1 1.96 \u03c3 WLS, one-sided "
             "where the physical bound (Ia, Fv, Fc \u2265 0) cuts them; \u03c3 PC is the wider side of that "
             "interval over 1.96 (so PC \u00b1 1.96 \u03c3 contains it).", cls="hint"),
    )
    body = join(body, bullets(["Active constraints: " + (", ".join(r.active) or "none")] + list(r.notices),
                              cls="notices"))
    comp = r.comparison()
    comp.insert(0, "unit", r._units())
    t_comp = T.make_table(comp, f"tab-{id}-parameters", "Base parameters: unconstrained WLS and PC-WLS"
                          + ("" if effects_spec is None else f" (both with the effects {effects_spec})"),
                          formats={"unit": "text"},
                          labels={"wls": "WLS", "wls_std": "\u03c3 WLS", "wls_rel_std_percent": "%\u03c3 WLS",
                                  "pc": "PC-WLS", "pc_std": "\u03c3 PC",
                                  "shift_sigma": "shift [\u03c3 WLS]"})
    links = pd.DataFrame([{"link": lk["link"], "mass": lk["mass"],
                           "pseudo_inertia_min_eig": lk["pseudo_inertia_min_eig"],
                           "consistent": lk["consistent"]} for lk in r.links]).set_index("link")
    t_links = T.make_table(links, f"tab-{id}-links", "Physical consistency of each link of the PC set",
                           formats={"consistent": "bool"},
                           labels={"mass": "mass [kg]", "pseudo_inertia_min_eig": "smallest eigenvalue of J (SI; \u2265 0: consistent)"})
    return Section(id, "Physically consistent identification (PC-WLS, SDP)", body,
                   figures=[principal_moments_figure(r, key=f"fig-{id}-moments", fmt=fmt)],
                   tables=[t_links, t_comp])


def effects_section(fit, *, id="effects"):
    """Effects fitted beside the rigid body (`EffectsFit`):
    their values and sigma (unconstrained and PC), the errors of both fits of that model."""
    pc = fit.physical is not None
    text = (f"Effects fitted with the rigid body ({fit.spec}): the unconstrained WLS of the base "
            "parameters plus the effects' columns" + (" and its physically consistent fit, the rigid "
            "body constrained and the effects free (profiled out: one SDP)" if pc else "") + ". "
            f"Relative error on the identification data: WLS {100 * fit.rel_error_wls:.3f} %"
            + (f", PC {100 * fit.rel_error_pc:.3f} %" if pc else "") + f". \u03c3: {fit.sigma_label}"
            + (" (the PC \u03c3 never below the unconstrained one)" if pc else "") + ".")
    parts = [para(text)]
    v = fit.validation
    if v is not None:
        parts.append(para(f"Held out (all {v['n_samples']} decimated samples): WLS {100 * v['rel_error_wls']:.3f} %"
                          + (f", PC {100 * v['rel_error_pc']:.3f} % (PC \u2212 WLS {v['gap_points']:+.3f} points)"
                             if pc else "") + "."))
    frame = pd.DataFrame(fit.effects()).set_index("name")
    labels = {"wls": "WLS", "wls_std": "\u03c3 WLS", "pc": "PC-WLS", "pc_std": "\u03c3 PC"}
    table = T.make_table(frame, f"tab-{id}-parameters", "Effect parameters", labels=labels)
    return Section(id, "Effects fitted beside the rigid body", join(*parts), tables=[table])
