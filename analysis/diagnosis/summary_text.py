"""The terminal text of a residual diagnosis (`DiagnosisResult.summary`), one function per
section, and the small formatters it shares with the report."""
from __future__ import annotations

import numpy as np

from dynid.analysis.diagnosis.effects import order_text
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import has_selection_bias
from dynid.analysis.results import notices_block, p_value_text
from dynid.analysis.units import parameter_unit, prismatic_of

__all__ = ["diagnosis_summary", "overview_lines", "fmt_p", "nonlinear_text", "sigma_text"]


def fmt_p(p):
    """A p-value as text (`dynid.analysis.results.p_value_text`; "-" if not finite)."""
    return p_value_text(p, "-")


def nonlinear_text(nl, *, prose=False):
    """The nonlinear parameter of an effect as text: compact for tables of the
    summary (`v_s=0.1 rad/s`), or `prose` for reports (`v_s = 0.1 rad/s`)."""
    eq = " = " if prose else "="
    if not nl:
        return ""
    if "vs" in nl:
        return f"v_s{eq}{nl['vs']:.3g} rad/s"
    if "d" in nl:
        return f"d{eq}{1e3 * nl['d']:.3g} ms"
    if "signal" in nl:
        return f"{'from ' if prose else ''}{nl['signal']}{nl['source']}"
    if nl.get("shape") == "friction":
        return "friction level" if prose else "friction lvl"
    if "order" in nl:
        return f"order {order_text(nl['order'])}"
    return ", ".join(f"{k}{eq}{v}" for k, v in nl.items())


def diagnosis_summary(res):
    """The text of `DiagnosisResult.summary()`."""
    lines = _header(res) + overview_lines(res) + [""] + _steps(res) + _ranking(res) + _selected(res)
    lines += _errors(res) + _structure(res) + _hidden(res)
    if res.notices:
        lines += [""] + ["  " + x for x in notices_block(res.notices)]
    return "\n".join(lines)


def overview_lines(res):
    """The first screen: effects added, findings, flagged joints with their hypothesis, effects
    cut by max_effects, errors before/after."""
    eff = res.effects
    lines = [f"  DIAGNOSIS: {len(eff)} effect(s) added, {len(res.findings)} finding(s) named but not "
             f"added, {len(res.unexplained)} joint(s) flagged, {len(res.cut)} effect(s) cut by max_effects"]
    lines += [f"    added: {e.label}" for e in eff]
    onsets = [e for e in res.selected if e.kind != "effect"]
    lines += [f"    kept in the model as a Coulomb onset (not an effect of the robot): {e.label}" for e in onsets]
    lines += [f"    finding (not added): {f.sentence()}" for f in res.findings]
    lines += [f"    flagged joint {u.joint}: {u.hypothesis or u.depends_on}" for u in res.unexplained]
    st = res.structure
    for u in ([] if st is None else st.dropped):
        lines.append(f"    not raised on joint {u.joint}: {u.hypothesis or u.depends_on} ({u.reason})")
    if res.cut:
        k = res.settings["max_effects"]
        lines.append(f"    cut: {len(res.cut)} effect(s) pass the rule but max_effects = {k} were added "
                     f"already; include them with --max-effects {k + len(res.cut)} "
                     f"(Python: diagnose(..., max_effects={k + len(res.cut)})):")
        lines += [f"      {r.label}: CV gain {100 * r.cv_gain:.2f} %, LR {r.statistic:.1f}, "
                  f"p_adj {fmt_p(r.p_value)}" for r in res.cut]
    v = res.errors.get("validation")
    if v is not None:
        lines.append(f"    held-out error (moving samples): {100 * v['before'].rel_error:.2f} % -> "
                     f"{100 * v['after'].rel_error:.2f} %")
    if res.rest is not None:
        lines += ["    " + x for x in res.rest.lines()]
    return lines


def _header(res):
    s = res.settings
    return [f"Residual diagnosis of {res.source} (robot '{res.robot_name}')",
            f"  model: {len(res.model_before.names)} parameters ({s.get('model', 'essential WLS')}); "
            f"{s['n_candidates']} candidates ({len(s['effects'])} effects x joints x grid)",
            f"  rule: blocked CV in {s['folds']} contiguous blocks (guard {s['gap']} samples) "
            f"and Bonferroni LR test with n_eff, alpha = {s['alpha']:g}"
            + ("; an effect that passes is kept only if the held-out error falls too (the held-out "
               "figures below then helped choose the effects: they are not an independent test)"
               if s.get("confirm_on_validation") else ""), ""]


def _steps(res):
    lines = []
    for st in res.steps:
        w = st.winner
        if w is None:
            lines.append(f"  step {st.step}: no candidate to score")
            continue
        lines.append(f"  step {st.step}: best {w.label}: CV gain {100 * w.cv_gain:.2f} %, "
                     f"{w.folds_better}/{w.n_folds} blocks, LR {w.statistic:.1f} "
                     f"(n_eff {w.n_eff:.0f}), p_adj {fmt_p(w.p_value)} -> "
                     f"{'SELECTED' if st.accepted else 'not selected: ' + st.reason}")
        if w.aliases:
            lines.append(f"          same columns on these data (indistinguishable): "
                         f"{', '.join(w.aliases)}")
        if st.runner_up is not None:
            lines.append(f"          runner-up {st.runner_up.label}: CV gain "
                         f"{100 * st.runner_up.cv_gain:.2f} %; gap {100 * st.gap:.2f} points; "
                         f"the winner predicts better in {100 * st.confidence:.0f} % of the blocks")
    return lines


def _ranking(res):
    lines = ["", "  Ranking (most to least likely):",
             "  rank  effect               joint  nonlinear            CV gain %  blocks   "
             "LR        p_adj      dBIC(n_eff)  sel"]
    for k, r in enumerate(res.ranking[:15], 1):
        j = "all" if r.joint is None else str(r.joint)
        nl = nonlinear_text(r.nonlinear)
        lines.append(f"  {k:4d}  {r.name:<20} {j:>5}  {nl:<20} {100 * r.cv_gain:9.3f}  "
                     f"{r.folds_better}/{r.n_folds}    {r.statistic:8.1f}  {fmt_p(r.p_value):>9}  "
                     f"{r.ic_gain:11.1f}  {'yes' if r.selected else ''}")
    if len(res.ranking) > 15:
        lines.append(f"  ... {len(res.ranking) - 15} more")
    return lines


def effect_unit(name, prismatic=frozenset()) -> str:
    """SI unit of an effect's parameter (`Fs2` N m, `Ks4` N m/rad, `Rc6k4.03` N m, `d` s), "" if unknown."""
    if name == "d":
        return "s"
    return parameter_unit(name, prismatic)


def sigma_text(res) -> str:
    """What the diagnosis' sigma are: the covariance of the identification it started from
    (`settings["parameters_uncertainty"]`), in words, and whether the bias of the base
    parameters the final model leaves out was added (`selection.py`, `_reported_fit`)."""
    unc = (getattr(res, "settings", None) or {}).get("parameters_uncertainty", "classic")
    biased = has_selection_bias(getattr(res, "model_after", None))
    return ls.UNCERTAINTY_WORDS.get(unc, unc) + (", with the bias of the base parameters left out" if biased else "")


def _selected(res):
    if not res.selected:
        return ["", "  No effect selected: nothing the candidates describe is missing from the model."]
    prismatic = prismatic_of(res)
    lines = ["", f"  Selected effects (sigma: {sigma_text(res)}):"]
    for e in res.selected:
        lines.append(f"    {e.label}:")
        for p, v, sd, r in zip(e.params, e.values, e.sigma, e.rel_sigma):
            unit = effect_unit(p, prismatic)
            lines.append(f"      {p:<10} = {v: .5g} +- {sd:.3g}{' ' + unit if unit else ''} ({r:.1f} %)")
        if e.note:
            lines.append(f"      note: {e.note}")
    return lines


def _errors(res):
    lines = ["", "  Errors before -> after (relative error norm on the moving samples, as the effects are scored; "
                 "RMS per joint [N m]):"]
    for key in ("identification", "validation"):
        e = res.errors.get(key)
        if e is None:
            continue
        b, a = e["before"], e["after"]
        lines.append(f"    {key:<14}: {100 * b.rel_error:.3f} % -> {100 * a.rel_error:.3f} %   "
                     f"RMS " + " ".join(f"{x:.4g}->{y:.4g}" for x, y in zip(b.rms, a.rms)))
    if len(res.path) > 1:
        lines += ["", "  Relative error after each step (identification / validation):"]
        for p in res.path:
            v = p["validation"]
            lines.append(f"    {p['step']}: {p['added'] or 'IDIM model':<45} "
                         f"{100 * p['identification'].rel_error:.3f} %"
                         + ("" if v is None else f" / {100 * v.rel_error:.3f} %"))
    return lines


def _structure(res):
    st = res.structure
    if st is None:
        return []
    floor = np.asarray(st.noise_floor, dtype=float)
    floor_text = ("noise floor RMS unknown on every joint" if not np.isfinite(floor).any() else
                  "noise floor RMS " + ", ".join(f"j{j + 1} {x:.3g}" if np.isfinite(x) else f"j{j + 1} unknown"
                                                 for j, x in enumerate(floor)) + " N m")
    lines = ["", f"  Structure left in the final residual ({st.n_tests} catalogue-free tests, "
                 f"Bonferroni alpha = {st.alpha:g}; {floor_text}):"]
    over = (np.full(floor.shape, np.nan) if getattr(st, "floor_over_residual", None) is None
            else np.asarray(st.floor_over_residual, dtype=float))
    above = [j + 1 for j in range(floor.size) if not np.isnan(over[j])]
    unknown = [j + 1 for j, k in enumerate(st.floor_known) if not k and j + 1 not in above]
    if unknown:
        lines.append(f"    noise floor unknown on joint(s) {', '.join(map(str, unknown))}: the "
                     f"torque's full-rate increments are not white (var(d3)/var(d2) "
                     + ", ".join(f"{st.whiteness[j - 1]:.2g}" for j in unknown)
                     + ", white noise 3.33): its noise does not show at the full rate (a low-pass "
                     "filter before logging, or noise below the logged resolution), so the "
                     "excess-over-floor test is not run")
    if above:
        lines.append(f"    noise floor unknown on joint(s) {', '.join(map(str, above))}: its torque-noise part, "
                     "estimated from the full-rate torque's increments, would be "
                     + ", ".join(f"{over[j - 1]:.3g}" for j in above)
                     + " x the residual's own RMS, so those increments are not white noise (fast "
                     "torque the decimation removes: a limit cycle, or noise shaped by the loop); the "
                     "excess-over-floor test is not run")
    if not st.unexplained:
        lines.append("    none: no joint's residual has significant structure large against "
                     "its noise")
    for u in st.unexplained:
        lines.append(f"    UNEXPLAINED {u.sentence()}")
        if u.also:
            lines.append(f"      also significant and large: {', '.join(u.also[:6])}")
    return lines


def _hidden(res):
    if not res.hidden_tests:
        return []
    physical = getattr(res.hidden_tests[0], "route", "") == "physical"
    lines = ["", "  Effects hidden in the parameters ("
             + ("physically consistent fit" if physical else "prior fit toward the a-priori values") + "):"]
    if res.hidden:
        return lines + [f"    HIDDEN {h.sentence()}" for h in res.hidden]
    best = res.hidden_tests[0]
    what = ", ".join(a for a, *_ in best.contradicted[:3])
    if getattr(best, "route", "") == "physical":
        # the physical route's "contradiction" is the consistent fit held at its bounds
        said = f"the physically consistent fit is held at its bounds ({what})"
    else:
        said = f"the parameters contradict the a-priori values ({what})"
    lines.append(f"    none: {said}, but no gravity-shaped spring explains it (best joint {best.joint}: "
                 f"{best.shortfall()})")
    return lines
