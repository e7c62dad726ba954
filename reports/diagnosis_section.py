"""Report sections of a residual diagnosis (`dynid.analysis.diagnosis.selection.diagnose`).

`diagnosis_sections(result, robot=None)` returns `dynid.reports.html.Section`
objects to append to an IDIM report (`render_idim_report(...,
extra_sections=...)`) or to render on their own
(`render_sections(sections, title=...)`):

* `diagnosis`: the selection rule, each greedy step (winner, runner-up,
  gap, how often the winner predicts the held-out blocks better), the
  ranked table of effects, and the error after each step;
* `diagnosis-effects`: the selected effects and their identified parameters;
* `diagnosis-errors`: relative error and per-joint RMS before/after, on the
  identification data and on the validation data;
* `diagnosis-residuals`: the residual before (red) and, when effects were added, after (blue) the
  effects, binned against velocity (the friction signature), position and
  time, and its PDF per joint; the catalogue-free structure tests of the final
  residual (joints whose residual has structure no candidate explains: the
  variable it depends on, its size and p-value, and a figure of the residual
  against that variable).

Ids of sections, figures and tables all start with `diagnosis` or `diag-`
so that they never clash with those of the IDIM report.
"""
from __future__ import annotations

import math

import matplotlib
import numpy as np
import pandas as pd
from markupsafe import Markup

from dynid.analysis.diagnosis.selection import nonlinear_text
from dynid.analysis.diagnosis.summary_text import sigma_text
from dynid.analysis.units import parameter_unit, prismatic_of
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import Section, bullets, join, kv_list, para

__all__ = ["diagnosis_sections", "diagnosis_title", "diagnosis_lead", "SECTION_IDS"]

SECTION_IDS = ("diagnosis-summary", "diagnosis", "diagnosis-effects", "diagnosis-errors", "diagnosis-residuals")
MAX_RANKED_ROWS = 30


def _names(robot, n):
    if robot is not None and len(getattr(robot, "joint_names", [])) == n:
        return list(robot.joint_names)
    return [f"j{j + 1}" for j in range(n)]


def _pct(x, digits=3):
    x = float(x)
    return "\u2014" if not math.isfinite(x) else f"{100 * x:.{digits}g} %"


def _nl_text(nl):
    return nonlinear_text(nl, prose=True)


# ------------------------------------------------------------------ sections
def diagnosis_title(result):
    """The title of a diagnosis report (the report is the diagnosis, not the identification)."""
    return f"Residual diagnosis of {result.robot_name}: {_verdict_words(result)}"


def _verdict_words(res):
    if not res.effects and not res.unexplained and not res.findings and not res.hidden:
        return "nothing missing found"
    parts = []
    if res.effects:
        parts.append(f"{len(res.effects)} effect(s) added")
    if res.findings:
        parts.append(f"{len(res.findings)} finding(s) named")
    if res.unexplained:
        parts.append(f"{len(res.unexplained)} joint(s) flagged")
    if res.hidden:
        parts.append(f"{len(res.hidden)} effect(s) hidden in the parameters")
    return ", ".join(parts)


def _first_screen_section(res):
    """Verdict, effects added, findings, flagged joints with their hypothesis, effects cut,
    errors before/after on all samples and while moving."""
    pairs = [("Verdict", _verdict_words(res)),
             ("Effects added", ", ".join(e.label for e in res.effects) or "none")]
    if res.findings:
        pairs.append(("Findings (named, not added)", "; ".join(f.sentence() for f in res.findings)))
    pairs.append(("Joints flagged", "; ".join(f"joint {u.joint}: {u.hypothesis or u.depends_on}"
                                              for u in res.unexplained) or "none"))
    st = getattr(res, "structure", None)
    if st is not None and st.dropped:
        pairs.append(("Not raised", "; ".join(f"joint {u.joint}: {u.hypothesis or u.depends_on} "
                                              f"({u.reason})" for u in st.dropped)))
    if res.cut:
        k = res.settings["max_effects"]
        pairs.append(("Cut by max_effects", "; ".join(
            f"{r.label} (CV gain {100 * r.cv_gain:.2f} %, LR {r.statistic:.1f})" for r in res.cut)
            + f": they pass the rule; include them with --max-effects {k + len(res.cut)} "
              f"(Python: diagnose(..., max_effects={k + len(res.cut)}))"))
    v = res.errors.get("validation")
    if v is not None:
        pairs.append(("Held-out error, moving samples", f"{_pct(v['before'].rel_error)} \u2192 "
                                                        f"{_pct(v['after'].rel_error)}"))
    rest = getattr(res, "rest", None)
    if rest is not None:
        pairs.append(("Held-out error, all samples (the identified model without the added effects)",
                      f"{_pct(rest.rel_error_before)} \u2192 {_pct(rest.rel_error_after)} with the friction at "
                      "rest chosen per joint (" + ", ".join(f"j{j + 1} {m}" for j, m in enumerate(rest.model))
                      + "); the effects are scored on the moving samples, above"))
        pairs.append(("Share of the all-samples error from rest phases", ", ".join(
            f"j{j + 1} {100 * b:.0f} \u2192 {100 * a:.0f} % ({100 * f:.0f} % of the rows at rest)"
            for j, (b, a, f) in enumerate(zip(rest.rest_share_before, rest.rest_share_after,
                                               rest.rest_fraction)))))
    return Section("diagnosis-summary", "Diagnosis", kv_list(pairs))


def _step_texts(res):
    """One sentence per greedy step: winner, outcome, aliases, runner-up."""
    steps = []
    for st in res.steps:
        w = st.winner
        if w is None:
            steps.append(f"Step {st.step}: no candidate outside the model's span.")
            continue
        text = (f"Step {st.step}: best {w.label}, CV gain {100 * w.cv_gain:.2f} % (cross-validated squared "
                f"error lower by that share) "
                f"({w.folds_better}/{w.n_folds} blocks better), LR {w.statistic:.1f} with "
                f"n_eff = {w.n_eff:.0f}, {F.p_equals(w.p_value, 'Bonferroni p')}: "
                + ("selected." if st.accepted else f"not selected ({st.reason})."))
        if w.aliases:
            text += (f" Same columns on these data as {', '.join(w.aliases)}: the data of a moving "
                     "joint cannot tell them apart.")
        if st.runner_up is not None:
            text += (f" Runner-up {st.runner_up.label} ({100 * st.runner_up.cv_gain:.2f} %): gap "
                     f"{100 * st.gap:.2f} points; the winner predicts the held-out block better in "
                     f"{100 * st.confidence:.0f} % of the blocks.")
        steps.append(text)
    return steps


def _overview_section(res):
    s = res.settings
    pairs = [
        ("Model", s.get("model", "")),
        ("Candidates", f"{s['n_candidates']} (effects: {', '.join(s['effects'])}; every joint; "
                       "grid of each nonlinear parameter)"),
        ("Selection rule", f"blocked cross-validation in {s['folds']} contiguous blocks "
                           f"(guard {s['gap']} decimated samples on each side of the held-out "
                           f"block): cross-validated error lower in at least {s['folds'] - 1} blocks; and "
                           f"likelihood-ratio test with the effective sample size, Bonferroni over "
                           f"the candidates, \u03b1 = {s['alpha']:g}"
                           + ("; an effect that passes is kept only if the held-out error falls too "
                              "(the held-out figures then helped choose the effects: they are not an "
                              "independent test)" if s.get("confirm_on_validation") else "")),
        ("Effects selected", ", ".join(e.label for e in res.selected) or "none"),
    ]
    if getattr(res, "structure", None) is not None:
        un = res.unexplained
        pairs.append(("Unexplained structure",
                      "; ".join(f"joint {u.joint}: {u.hypothesis or u.depends_on} ({u.rms:.3g} N m, "
                                f"{F.p_equals(u.p_value)})" for u in un) if un else
                      "none (no joint's final residual has significant structure large against "
                      "its noise)"))
    steps = _step_texts(res)
    body = join(kv_list(pairs), Markup("<h3>Greedy selection</h3>"), bullets(steps),
                para("Ranked from most to least likely: the selected effects in the order they were "
                     "added, then the others by their score against the final model. CV gain: "
                     "fraction of the held-out (WLS-weighted) squared error the effect removes; LR: "
                     "likelihood-ratio statistic with the effective sample size (\u03c7\u00b2 with "
                     "as many degrees of freedom as parameters if nothing is missing); \u0394BIC: "
                     "LR \u2212 k ln n_eff.", cls="hint"))
    if res.notices:
        body = join(body, Markup("<h3>Notices</h3>"), bullets(res.notices, cls="notices"))
    rows = []
    for k, r in enumerate(res.ranking[:MAX_RANKED_ROWS], 1):
        rows.append({"rank": k, "effect": r.name, "joint": "all" if r.joint is None else str(r.joint),
                     "nonlinear": _nl_text(r.nonlinear), "parameters": ", ".join(r.params),
                     "cv_gain_pct": 100 * r.cv_gain, "blocks": f"{r.folds_better}/{r.n_folds}",
                     "lr": r.statistic, "p_value": r.p_value, "ic_gain": r.ic_gain,
                     "aliases": ", ".join(r.aliases), "selected": bool(r.selected)})
    df = pd.DataFrame(rows)
    tables = []
    if len(df):
        df = df.set_index("rank")
        note = "" if len(res.ranking) <= MAX_RANKED_ROWS else \
            f"{len(res.ranking) - MAX_RANKED_ROWS} more in the CSV and the JSON results"
        # one value per cell: lists joined by "; ", the joint as text ("all" when none), cv_gain a
        # fraction as in the JSON (docs/formats.md)
        csv = pd.DataFrame([{k: ("; ".join(map(str, v)) if isinstance(v, (list, tuple)) else v)
                             for k, v in {**r.to_dict(), "nonlinear": _nl_text(r.nonlinear),
                                          "joint": "all" if r.joint is None else str(r.joint)}.items()}
                            for r in res.ranking])
        tables.append(T.make_table(
            df, "diag-ranking", "Effects ranked from most to least likely",
            formats={"effect": "text", "joint": "text", "nonlinear": "text", "parameters": "code",
                     "cv_gain_pct": "num", "blocks": "text", "aliases": "text", "selected": "bool"},
            labels={"cv_gain_pct": "CV gain [%]", "lr": "LR (n_eff)", "p_value": "p (Bonferroni)",
                    "ic_gain": "\u0394BIC (n_eff)", "aliases": "same columns as"},
            note=note, csv_frame=csv, csv_index=False))
    if len(res.path) > 1:
        prow = []
        for p in res.path:
            v = p["validation"]
            prow.append({"step": p["step"], "added": p["added"] or "(IDIM model)",
                         "ident_rel_error_pct": 100 * p["identification"].rel_error,
                         "valid_rel_error_pct": np.nan if v is None else 100 * v.rel_error})
        pdf = pd.DataFrame(prow).set_index("step")
        tables.append(T.make_table(pdf, "diag-path", "Relative error after each step",
                                   formats={"added": "text", "ident_rel_error_pct": "num",
                                            "valid_rel_error_pct": "num"},
                                   labels={"ident_rel_error_pct": "identification [%]",
                                           "valid_rel_error_pct": "validation, moving samples [%]"}))
    return Section("diagnosis", "Residual diagnosis", body, tables=tables, tables_first=True)


def _effects_section(res):
    if not res.selected:
        body = para("No effect was selected: none of the candidate effects explains a part of the "
                    "residual that the selection rule accepts. The model lacks nothing the effect "
                    "library describes, at this noise level and with this excitation.")
        return Section("diagnosis-effects", "Selected effects", body)
    rows, notes = [], []
    for e in res.selected:
        for p, v, sd, r in zip(e.params, e.values, e.sigma, e.rel_sigma):
            rows.append({"parameter": p, "effect": e.name,
                         "joint": "all" if e.joint is None else str(e.joint),
                         "nonlinear": _nl_text(e.nonlinear), "value": float(v), "std": float(sd),
                         "unit": parameter_unit(p), "rel_std_percent": float(r), "step": e.step})
        if e.note:
            notes.append(f"{e.label}: {e.note}")
    df = pd.DataFrame(rows).set_index("parameter")
    tab = T.make_table(df, "diag-effect-parameters",
                       "Parameters of the selected effects (WLS with the essential parameters; "
                       f"\u03c3: {sigma_text(res)})",
                       formats={"effect": "text", "joint": "text", "nonlinear": "text", "step": "int",
                                "unit": "text"},
                       labels={"std": "\u03c3", "rel_std_percent": "%\u03c3"})
    body = para("Parameter names: Off offset; dFc, dFv half the difference of the Coulomb / "
                "viscous friction between positive and negative velocity; Fs Stribeck excess; "
                "Rc, Rs ripple cosine / sine; Ks spring stiffness; Cv, Ca coupling by the velocity / "
                "acceleration of another joint; d time delay [s] (> 0: torque late; the model is "
                "re-fitted on W(t \u2212 d)); Dr drift polynomial; Fl load-friction coefficient; "
                "dM, dMX, dMY, dMZ payload mass and first moments.", cls="hint")
    if notes:
        body = join(body, Markup("<h3>Notes</h3>"), bullets(notes))
    return Section("diagnosis-effects", "Selected effects", body, tables=[tab], tables_first=True)


def _errors_section(res, names):
    if not res.selected:
        # Nothing was added: before and after are the same model, say so in one line.
        errs = [f"{label} {_pct(res.errors[key]['before'].rel_error)}"
                for key, label in (("identification", "identification data"), ("validation", "validation data"))
                if res.errors.get(key) is not None]
        return Section("diagnosis-errors", "Errors before and after the effects",
                       para("No effect was added, so the errors are those of the model identified ("
                            + ", ".join(errs) + ", moving samples)."))
    tables = []
    pairs = []
    for key, label in (("identification", "identification data"), ("validation", "validation data")):
        e = res.errors.get(key)
        if e is None:
            continue
        b, a = e["before"], e["after"]
        pairs.append((f"Relative error, {label} (moving samples)", f"{_pct(b.rel_error)} \u2192 {_pct(a.rel_error)}"))
        df = pd.DataFrame({"joint": names, "rms_before": b.rms, "rms_after": a.rms,
                           "rel_before_pct": 100 * np.asarray(b.joint_rel_error),
                           "rel_after_pct": 100 * np.asarray(a.joint_rel_error)},
                          index=pd.Index(np.arange(1, len(names) + 1), name="j"))
        tables.append(T.make_table(
            df, f"diag-errors-{key}", f"Per-joint residual before and after the effects ({label}, moving samples)",
            formats={"joint": "text", "rel_before_pct": "num", "rel_after_pct": "num"},
            labels={"rms_before": "RMS before [N m]", "rms_after": "RMS after [N m]",
                    "rel_before_pct": "rel. error before [%]", "rel_after_pct": "rel. error after [%]"},
            prismatic=bool(prismatic_of(res))))
    body = join(kv_list(pairs),
                para("Rows used by the estimator (outside the velocity dead zone). The validation "
                     "data were processed with the identification's settings; the effects' columns "
                     "were built on them with the identification's model torque and time scale.",
                     cls="hint"))
    return Section("diagnosis-errors", "Errors before and after the effects", body, tables=tables)


def _joint_panels(n):
    """A figure with one panel per joint (unused panels hidden): (fig, axes, cols)."""
    rows, cols = F.grid_shape(n)
    fig = F.Figure(figsize=(3.3 * cols, 1.9 * rows + 0.3), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, axes, cols


def _binned_figure(key, caption, an_before, an_after, attr, xlabel, names):
    n = len(names)
    with matplotlib.rc_context(F.STYLE):
        fig, axes, cols = _joint_panels(n)
        for j in range(n):
            ax = axes.flat[j]
            for an, color, label in ((an_before, F.RED, "before"), (an_after, F.BLUE, "after")):
                if an is None:
                    continue
                df = getattr(an, attr)[j + 1]
                if len(df):
                    ax.errorbar(df["center"], df["mean"], yerr=df["sem"], color=color, lw=0.9,
                                marker="o", ms=2.2, capsize=1.5, elinewidth=0.6, label=label)
            ax.axhline(0.0, color=F.GREY, lw=0.5)
            ax.set_title(F._plain(F.joint_label(j, names[j])), loc="left")
            if j % cols == 0:
                ax.set_ylabel("mean residual [N m]")
            if j >= n - cols:
                ax.set_xlabel(xlabel)
        handles, texts = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside upper right", ncols=2, frameon=False)
    return F.render_figure(fig, key, caption)


def _pdf_figure(key, caption, an_before, an_after, names):
    from scipy import stats
    n = len(names)
    with matplotlib.rc_context(F.STYLE):
        fig, axes, cols = _joint_panels(n)
        for j in range(n):
            ax = axes.flat[j]
            title = F.joint_label(j, names[j])
            ps = []
            for an, color, label in ((an_before, F.RED, "before"), (an_after, F.BLUE, "after")):
                if an is None:
                    continue
                e = an.residual[:, j][an.mask[:, j]]
                e = e[np.isfinite(e)]
                if e.size < 3:
                    continue
                ax.hist(e, bins=int(np.clip(np.sqrt(e.size), 8, 40)), density=True, color=color,
                        alpha=0.25, label=f"{label} (histogram)")
                mu, sd = float(e.mean()), float(e.std(ddof=1))
                if sd > 0:
                    x = np.linspace(e.min() - 0.1 * np.ptp(e), e.max() + 0.1 * np.ptp(e), 200)
                    ax.plot(x, stats.norm.pdf(x, mu, sd), color=color, lw=1.0,
                            label=f"{label}: normal fit")
                ps.append(f"{label} JB p {F.format_p(an.normality['jarque_bera_p'].iloc[j])}")
            ax.set_title(F._plain(title + (": " + ", ".join(ps) if ps else "")), loc="left",
                         fontsize=7)
            ax.set_yticks([])
            ax.grid(False)
            if j >= n - cols:
                ax.set_xlabel("residual [N m]")
        handles, texts = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside upper right", ncols=4, frameon=False)
    return F.render_figure(fig, key, caption)


def _residual_section(res, names):
    r = res.residuals
    b, a = r.get("identification_before"), r.get("identification_after")
    if not res.selected:
        a = None                      # the same model: draw it once
    if b is None:
        body, figs, tables = _structure_parts(res, para(
            "Residual analysis was not computed (diagnose(..., residual_analysis=False))."), [], [])
        return Section("diagnosis-residuals", "Residuals before and after", body, figures=figs,
                       tables=tables)
    def drawn(after, what="before (red) and after (blue) the effects"):
        # a caption names only the curves drawn: without a selected effect there is no "after"
        return what if after is not None else "of the identified model (red; no effect was added)"

    figs = [
        _binned_figure("diag-fig-velocity", "Identification data: mean residual in equal-count "
                       f"velocity bins (\u00b1 standard error), {drawn(a)}: the friction signature",
                       b, a, "velocity", "qd [rad/s]", names),
        _binned_figure("diag-fig-position", "Identification data: mean residual against joint "
                       f"position, {drawn(a)}", b, a, "position", "q [rad]", names),
        _binned_figure("diag-fig-time", f"Identification data: mean residual over the recording, {drawn(a)}",
                       b, a, "time", "t [s]", names),
        _pdf_figure("diag-fig-pdf", f"Identification data: residual PDF {drawn(a)}, with fitted normal "
                    "densities; Jarque-Bera p in the titles", b, a, names),
    ]
    vb, va = r.get("validation_before"), r.get("validation_after")
    if not res.selected:
        va = None
    if vb is not None:
        figs.append(_binned_figure("diag-fig-velocity-validation", "Validation data: mean residual "
                                   f"against velocity, {drawn(va)}", vb, va,
                                   "velocity", "qd [rad/s]", names))
        figs.append(_pdf_figure("diag-fig-pdf-validation", f"Validation data: residual PDF {drawn(va)}",
                                vb, va, names))
    rows = []
    for label, an in (("before", b), ("after", a)):
        if an is None:
            continue
        for j in range(len(names)):
            ne = an.n_eff.iloc[j]
            rows.append({"residual": label, "joint": names[j], "rms": float(an.rms[j]),
                         "ljung_box_p": float(an.ljung_box["p_value"].iloc[j]),
                         "tau_int": float(ne["tau_int"]), "n_eff": float(ne["n_eff"]),
                         "n": int(ne["n"]),
                         "jarque_bera_p": float(an.normality["jarque_bera_p"].iloc[j])})
    df = pd.DataFrame(rows)
    tab = T.make_table(df, "diag-residual-stats", "Residual whiteness and effective sample size "
                       "(identification data)", index=False,
                       formats={"residual": "text", "joint": "text", "n": "int"},
                       labels={"rms": "RMS [N m]", "ljung_box_p": "Ljung-Box p",
                               "tau_int": "\u03c4_int = 1 + 2\u03a3\u03c1_k", "n_eff": "n_eff",
                               "jarque_bera_p": "Jarque-Bera p"}, prismatic=bool(prismatic_of(res)))
    lb = b.ljung_box
    found = ("the diagnosis added " + ", ".join(f"{s_.name} (joint {s_.joint})" for s_ in res.selected)
             if res.selected else "the diagnosis found no missing effect among the candidates it tested")
    corr = [f"{names[j]} {F.p_equals(lb['p_value'].iloc[j])}" for j in range(len(names))
            if float(lb["p_value"].iloc[j]) < 0.05]
    state = (f"Before the effects the residual is correlated in time (Ljung-Box at lag "
             f"{int(lb['lag'].iloc[0])}: {', '.join(corr)}); {found}." if corr else
             f"Before the effects the residual is white (Ljung-Box p \u2265 0.05 on every joint); {found}.")
    body = join(para(state),
                para("n_eff = n / (1 + 2 \u03a3_{k<K} \u03c1_k), K the first lag where the residual's "
                     "autocorrelation falls inside the white-noise band 2/\u221an. A correlated residual "
                     "(small Ljung-Box p, \u03c4_int well above 1) makes tests that count the samples as "
                     "independent optimistic; it comes from a missing effect only if the diagnosis finds "
                     "one (filtering and decimation alone correlate the residual too). Residual PDFs and "
                     "tests use only the fitted rows.", cls="hint"))
    body, figs, tables = _structure_parts(res, body, figs, [tab])
    return Section("diagnosis-residuals", "Residuals before and after", body, figures=figs,
                   tables=tables)


def _structure_parts(res, body, figs, tables):
    """The catalogue-free structure tests appended to the residual section's parts."""
    st = getattr(res, "structure", None)
    if st is not None:
        body = join(body, Markup("<h3>Structure no candidate explains</h3>"), _structure_text(st))
        if st.unexplained:
            fig = _unexplained_figure(st.unexplained)
            if fig is not None:
                figs.append(fig)
        srows = [{"joint": u.joint, "depends_on": u.depends_on, "test": u.test, "rms": u.rms,
                  "noise_rms": u.noise_rms, "p_value": u.p_value, "also": ", ".join(u.also[:4])}
                 for u in st.unexplained]
        if srows:
            tables.append(T.make_table(
                pd.DataFrame(srows), "diag-unexplained", "Joints with unexplained residual structure (a spectral "
                "line's RMS is the full-rate residual's, where the decimation has not removed it: it can exceed "
                "the decimated residual of the error tables)",
                index=False, formats={"depends_on": "text", "test": "text", "also": "text",
                                      "joint": "int"},
                labels={"rms": "structure RMS [N m]", "noise_rms": "rest / noise RMS [N m]",
                        "p_value": "p (Bonferroni)", "depends_on": "depends on"}, prismatic=bool(prismatic_of(res))))
    return body, figs, tables



def _structure_text(st):
    items = [u.sentence() for u in st.unexplained] or [
        "No joint: the final residual has no significant structure that is large against its "
        "noise."]
    return join(bullets(items), para(
        f"{st.n_tests} catalogue-free tests of the final residual, per joint: binned means against "
        "q_j, qd_j, qdd_j, t, the friction level over time (residual × sign(qd_j) against t) and "
        "the other joints' q and qd; spectral lines against q_j at any order (full-rate residual "
        "resampled on position); a step in time; the residual RMS against the torque-noise floor "
        "(torque noise from the full-rate second differences, through the same decimation: "
        + ", ".join(_floor_text(st, j) for j in range(len(st.noise_floor))) + " N m). Nulls by block permutation "
        f"(blocks of {st.block_length} decimated samples), Bonferroni over tests and joints, "
        f"α = {st.alpha:g}. Flagged when significant and the structure RMS is at least half "
        "the RMS of the rest of the residual (noise-floor test: residual RMS at least twice the "
        "floor).", cls="hint"))


def _unexplained_figure(unexplained):
    items = [u for u in unexplained if u.curve is not None]
    if not items:
        return None
    n = len(items)
    with matplotlib.rc_context(F.STYLE):
        fig, axes, cols = _joint_panels(n)
        for k, u in enumerate(items):
            ax = axes.flat[k]
            x, y = u.curve
            ax.plot(x, y, color=F.BLUE, lw=0.8, marker="o" if len(x) < 60 else None, ms=2.0)
            ax.axhline(0.0, color=F.GREY, lw=0.5)
            ax.set_title(F._plain(f"joint {u.joint}: {u.depends_on}"), loc="left", fontsize=7)
            ax.set_xlabel(u.curve_label)
            if k % cols == 0:
                ax.set_ylabel("mean residual [N m]")
    return F.render_figure(fig, "diag-fig-unexplained", "Final residual against the variable its "
                           "unexplained structure depends on (binned means; noise-floor and step "
                           "tests: the residual over time)")


def diagnosis_lead(result, robot=None):
    """What a diagnosis report shows first: its title, highlights and lead section (the diagnosis),
    and the other sections.

    Parameters
    ----------
    result : DiagnosisResult
    robot : Robot, optional (joint names)

    Returns
    -------
    dict
        `title` (str), `highlights` ((label, value) pairs), `lead` (the `diagnosis-summary`
        section, shown above the identification's verdict) and `sections` (the rest of
        `diagnosis_sections`, after the identification's sections); the keywords of
        `dynid.reports.html.render_idim_report` as `title`, `lead_highlights`,
        `lead_sections`, `extra_sections`.
    """
    secs = diagnosis_sections(result, robot)
    highlights = [("diagnosis", _verdict_words(result))]
    rest = getattr(result, "rest", None)
    if rest is not None:
        highlights.append(("held-out error, all samples, friction at rest (without the effects)",
                           f"{_pct(rest.rel_error_before)} → {_pct(rest.rel_error_after)}"))
    v = result.errors.get("validation")
    if v is not None:
        highlights.append(("held-out error, moving samples", f"{_pct(v['before'].rel_error)} → "
                                                             f"{_pct(v['after'].rel_error)}"))
    return {"title": diagnosis_title(result), "highlights": highlights,
            "lead": [x for x in secs if x.id == "diagnosis-summary"],
            "sections": [x for x in secs if x.id != "diagnosis-summary"]}


def diagnosis_sections(result, robot=None):
    """The report sections of a `dynid.analysis.diagnosis.selection.DiagnosisResult`."""
    n = result.model_before.n_joints
    names = _names(robot, n)
    return [_first_screen_section(result), _overview_section(result), _effects_section(result),
            _errors_section(result, names),
            _residual_section(result, names)]


def _floor_text(st, j):
    """Joint j's noise floor in the tests' description, or why it is unknown."""
    x = st.noise_floor[j]
    if np.isfinite(x):
        return f"{x:.3g}"
    over = getattr(st, "floor_over_residual", None)
    if over is not None and not np.isnan(over[j]):
        return f"unknown (the torque's increments would put it at {over[j]:.3g} x the residual: not white noise)"
    return "unknown (no noise shows in the full-rate torque: filtered upstream or below its resolution)"
