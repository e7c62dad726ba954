"""Report sections of the per-joint identification of Bona & Curatella (2005), section 3.

`decoupled_sections` turns an
`dynid.analysis.decoupled.campaign.DecoupledIdentification` (or the three
`dynid.analysis.decoupled.repeated.RepeatedEstimate` and a validation) into
`dynid.reports.html.Section` objects: Tables 1, 2 and 3 in the paper's layout
(Table 1: parameters by axis; Table 2: axes by β^{v+}, β^{v−}, β^{c+}, β^{c−};
Table 3: axis, parameter, θ̄, σ, t_γ σ/√(n−1)), each entry with dynid's
mean, σ (1/n), 99.9 % half-width and, for simulated data, the true value and
whether it is inside; and the validation of section 3.5 with the error PDFs
of Fig. 8.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.bona_section import noise_pdf_figure
from dynid.reports.html import Section, join, kv_list, para

__all__ = ["decoupled_sections", "gravity_section", "friction_section", "inertia_section",
           "validation_section", "table1_frame", "table2_frame", "table3_frame"]

_STATS = ("mean", "σ", "t_γ σ/√(n−1)")


def _fmt(x, digits=4):
    return T.format_number(x, digits)


def _entry(res, name, scale=1.0):
    i = res.names.index(name)
    row = {"mean": res.mean[i] * scale, "σ": res.std[i] * scale,
           "t_γ σ/√(n−1)": res.half_width[i] * scale}
    if res.truth is not None:
        row["true"] = res.truth[i] * scale
        row["inside"] = bool(res.inside[i])
    return row


def _grouped(rows, index, groups, index_name):
    """A frame with flat columns `group: stat` and the group header spans."""
    cols, spans = {}, []
    for g in groups:
        stats = [k for k in rows[0][g]]
        spans.append((g, len(stats)))
        for k in stats:
            cols[f"{g}: {k}"] = [r[g][k] for r in rows]
    df = pd.DataFrame(cols, index=pd.Index(index, name=index_name))
    return df, spans


def _make(df, spans, key, caption, note=""):
    labels = {c: c.split(": ", 1)[1] for c in df.columns}
    formats = {c: "bool" for c in df.columns if c.endswith(": inside")}
    tab = T.make_table(df, key, caption, labels=labels, formats=formats, note=note)
    tab.groups = [("", 1)] + spans
    return tab


def _coverage(res):
    if res.truth is None:
        return ""
    return (f"True value inside the {100 * res.confidence:g} % interval for "
            f"{int(np.sum(res.inside))} of {len(res.names)} parameters.")


def _stats_text(res):
    return (f"{res.n_repetitions} repetitions; σ with 1/n; half-width t_γ σ/√(n−1), "
            f"t_γ = {res.t_gamma:.4f} (Student, {res.n_repetitions - 1} DoF, two-sided "
            f"{100 * res.confidence:g} %).")


# ------------------------------------------------------------------ Table 1
def table1_frame(res):
    """Table 1 layout: rows k [N m], q^off [deg]; a column group per axis."""
    joints = sorted(set(res.joints))
    rows = []
    for _label, base, scale in (("k [N m]", "k", 1.0), ("q^off [deg]", "qoff", 180 / math.pi)):
        rows.append({f"Axis {j}": _entry(res, f"{base}{j}", scale) for j in joints})
    return _grouped(rows, ["k [N m]", "q^off [deg]"], [f"Axis {j}" for j in joints], "Parameter")


def gravity_section(res, *, id="table1", title="Table 1. Estimated gravity parameters"):
    df, spans = table1_frame(res)
    tab = _make(df, spans, f"tab-{id}", "Gravity τ_g = k sin(q + q^off), eq. (23), from two "
                "constant-velocity slopes of opposite sign (q^off shown in degrees as in the paper; "
                "stored in rad)", note=_stats_text(res))
    body = join(para("Fitted on the constant-velocity samples: τ = a sin q + b cos q + c±, where c+ "
                     "and c− are the friction (and any offset) of the up and down slopes; their "
                     "half-sum and half-difference separate the offset from the friction, "
                     "k = ±√(a² + b²), q^off = atan(b / a)."), para(_coverage(res)))
    return Section(id, title, body, tables=[tab])


# ------------------------------------------------------------------ Table 2
def table2_frame(res):
    """Table 2 layout: a row per axis; column groups β^v+, β^v−, β^c+, β^c−."""
    joints = sorted(set(res.joints))
    groups = [("β^v+", "Fv+"), ("β^v−", "Fv-"), ("β^c+", "Fc+"), ("β^c−", "Fc-")]
    rows = [{g: _entry(res, f"{s}{j}") for g, s in groups} for j in joints]
    return _grouped(rows, [f"Axis {j}" for j in joints], [g for g, _ in groups], "")


def friction_section(res, *, id="table2", title="Table 2. Estimated friction parameters"):
    df, spans = table2_frame(res)
    tab = _make(df, spans, f"tab-{id}", "Asymmetric viscous (N m s/rad) and Coulomb (N m) friction, "
                "eq. (2), from bang-bang accelerations after gravity compensation",
                note=_stats_text(res))
    body = join(para("Least squares on τ − g(q) = M q̈ + β^v± q̇ ± β^c± over the samples away from "
                     "the acceleration switches and from zero velocity; the inertia M takes up the "
                     "hysteresis of Fig. 3 (it is reported in Table 3 from the excitation)."),
                para(_coverage(res)))
    return Section(id, title, body, tables=[tab])


# ------------------------------------------------------------------ Table 3
def table3_frame(res):
    """Table 3 layout: Axis, Parameter [unit], θ̄, σ, t_γ σ/√(n−1) (+ true, inside)."""
    recs = []
    for i, _nm in enumerate(res.names):
        r = {"Axis": res.joints[i], "Parameter": f"{res.symbols[i]} [{res.units[i]}]",
             "θ̄": res.mean[i], "σ": res.std[i], "t_γ σ/√(n−1)": res.half_width[i]}
        if res.truth is not None:
            r["true"] = res.truth[i]
            r["inside"] = bool(res.inside[i])
        recs.append(r)
    df = pd.DataFrame(recs)
    df["Axis"] = [str(a) if k == 0 or a != df["Axis"].iloc[k - 1] else ""
                  for k, a in enumerate(df["Axis"])]
    return df


def inertia_section(res, *, id="table3", title="Table 3. Estimated robot model parameters"):
    df = table3_frame(res)
    tab = T.make_table(df, f"tab-{id}", "Inertia Γ^zz and first moments mx, my per joint, eq. (21), "
                       "from the Fourier excitation after friction compensation",
                       formats={"Axis": "text", "Parameter": "text", "inside": "bool"}, index=False,
                       note=_stats_text(res))
    body = join(para("Least squares on τ − f(q̇) = Γ^zz q̈ + mx g0 cos q − my g0 sin q (joint 1: "
                     "vertical axis, Γ^zz only), velocities and accelerations from the measured "
                     "position by a Savitzky–Golay filter."), para(_coverage(res)))
    return Section(id, title, body, tables=[tab])


# ------------------------------------------------------------------ validation (Fig. 8)
def validation_section(val, *, joint_names=None, id="validation-fig8",
                       title="Model validation by simulation (section 3.5, Fig. 8)"):
    n = val.q_meas.shape[1]
    names = joint_names or [f"j{j + 1}" for j in range(n)]
    df = pd.DataFrame({"max |e_q| [deg]": val.max_q_error_deg, "RMS e_q [deg]": val.rms_q_error_deg,
                       "max |e_τ| [N m]": val.max_tau_error, "RMS e_τ [N m]": val.rms_tau_error,
                       "‖e_τ‖/‖τ‖": val.rel_tau_error, "q error Gaussian": val.q_tests.gaussian,
                       "τ error Gaussian": val.tau_tests.gaussian},
                      index=pd.Index(names, name="joint"))
    tab = T.make_table(df, f"tab-{id}", "Error between the measured (filtered) and the simulated "
                       "identified model", formats={"q error Gaussian": "bool", "τ error Gaussian": "bool"})
    fig_pdf = noise_pdf_figure(val.tau_tests, val.q_tests, joint_names=names, key=f"fig-{id}-pdf",
                               caption="PDF of the validation errors (Fig. 8): torque error left, "
                                       "position error right; histogram, fitted normal (red), KDE "
                                       f"(dashed); {val.q_tests.primary.replace('_', '-')} p-value in "
                                       "the titles")
    fig_q = F.torque_figure(val.t, np.degrees(val.q_meas), np.degrees(val.q_sim), names,
                            key=f"fig-{id}-q", ylabel="q [deg]", labels=("measured", "simulated"),
                            caption="Trapezoidal-velocity validation run: measured (red) and "
                                    "simulated (blue) position")
    fig_t = F.torque_figure(val.t, val.tau_meas, val.tau_sim, names, key=f"fig-{id}-tau",
                            labels=("measured", "simulated"),
                            caption="Measured (red) and simulated (blue) torque on the validation run")
    st = val.settings
    body = join(kv_list([("Model", st.get("model", "")), ("Filter", f"{st.get('filter')}, fc = "
                         f"{_fmt(st.get('fc'))} Hz"),
                         ("Error PDF tests", f"{val.q_tests.rule_text()}, on the error at "
                                             f"{_fmt(st.get('test_rate'))} Hz")]),
                para(f"Largest position error {_fmt(val.max_q_error_deg.max(), 3)}° (paper: below "
                     f"0.1°); largest torque error {_fmt(val.max_tau_error.max(), 3)} N m (paper: below "
                     "0.2 N m on the real robot)."))
    return Section(id, title, body, figures=[fig_q, fig_t, fig_pdf], tables=[tab])


def decoupled_sections(ident, *, joint_names=None):
    """The sections of a `DecoupledIdentification`."""
    out = [gravity_section(ident.gravity), friction_section(ident.friction),
           inertia_section(ident.inertia)]
    if ident.validation is not None:
        out.append(validation_section(ident.validation, joint_names=joint_names))
    return out
