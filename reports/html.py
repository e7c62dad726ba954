"""Self-contained HTML reports.

A report is a list of `Section` rendered by `templates/report.html.j2`
into ONE HTML file: inline CSS, inline SVG (or base64 PNG) figures, every
table downloadable as CSV through a `data:` URI, no external fonts, scripts
or URLs, a print stylesheet. Identical inputs give byte-identical files (no
timestamps; deterministic figures).

Escaping: the Jinja2 environment autoescapes everything. Trusted markup is
marked by its *type*: `markupsafe.Markup` (figures we drew, bodies
built with `para`, `kv_list`, `bullets`, which escape their
arguments). A plain `str` anywhere — a file name, a robot or joint name, a
column label, even a section's `html_body` — is escaped. The template never
uses `|safe`.

Extending: later analyses (DIDIM convergence, Bona tables, posterior,
diagnosis) build their own `Section` objects and pass them as
`extra_sections` to `render_idim_report`, or call
`render_sections` with a list of their own.
"""
from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field

import jinja2
import numpy as np
import pandas as pd
from markupsafe import Markup, escape

from dynid.analysis.processing.observation import SETTINGS_HELP
from dynid.analysis.statistics.validation import DEAD_ZONE_REASON
from dynid.analysis.statistics.verdict import parameter_unit
from dynid.analysis.statistics.verdict import verdict as _verdict
from dynid.analysis.units import prismatic_of
from dynid.dynamics.robot import joint_names_of
from dynid.outputs import atomic_write_text
from dynid.provenance import versions
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.paper import reference_for

__all__ = [
    "Section", "para", "kv_list", "bullets", "join", "render_sections", "idim_sections",
    "render_idim_report", "write_report", "environment", "SECTION_IDS", "VerdictBlock",
    "verdict_block",
]

TEMPLATE = "report.html.j2"
_ID_RE = re.compile(r"^[a-z][a-z0-9-]*$")

#: Ids of the sections of an IDIM report, in order (``validation`` only with validation data).
SECTION_IDS = ("run", "model", "base-parameters", "table2", "essential-path", "torques",
               "validation")


@dataclass
class Section:
    """One section of a report: `<section id=…><h2>title</h2>` body, figures, tables.

    `html_body` is escaped unless it is `markupsafe.Markup` (build it
    with `para`, `kv_list`, `bullets`, `join`).
    `figures` are `dynid.reports.figures.FigureMarkup`, `tables`
    `dynid.reports.tables.Table`. With `tables_first` the tables come
    before the figures. `details` are tables shown collapsed (a `<details>`
    element titled `details_summary`): setup tables that are not results.
    """

    id: str
    title: str
    html_body: object = ""
    figures: list = field(default_factory=list)
    tables: list = field(default_factory=list)
    tables_first: bool = False
    details: list = field(default_factory=list)      # tables in a collapsed <details> at the end
    details_summary: str = "Setup details"


# ------------------------------------------------------------------ body helpers
def para(*parts, cls: str = "") -> Markup:
    """`<p>` of the concatenated parts (each escaped unless Markup)."""
    inner = Markup("").join(escape(p) for p in parts)
    if cls:
        return Markup('<p class="{}">{}</p>').format(cls, inner)
    return Markup("<p>{}</p>").format(inner)


def code(text) -> Markup:
    return Markup("<code>{}</code>").format(text)


def kv_list(pairs, cls: str = "kv") -> Markup:
    """A `<dl>` of (label, value) pairs; values may be Markup (e.g. `code`)."""
    items = Markup("").join(Markup("<dt>{}</dt><dd>{}</dd>").format(k, v) for k, v in pairs)
    return Markup('<dl class="{}">{}</dl>').format(cls, items)


def bullets(items, cls: str = "") -> Markup:
    """A `<ul>` of the items (escaped unless Markup)."""
    lis = Markup("").join(Markup("<li>{}</li>").format(i) for i in items)
    if cls:
        return Markup('<ul class="{}">{}</ul>').format(cls, lis)
    return Markup("<ul>{}</ul>").format(lis)


def join(*parts) -> Markup:
    return Markup("").join(escape(p) for p in parts if p is not None and p != "")


# ------------------------------------------------------------------ rendering
TEMPLATE_PACKAGE = "dynid.templates"


@functools.lru_cache(maxsize=1)
def environment() -> jinja2.Environment:
    """The Jinja2 environment of the reports (autoescape on, strict undefined).

    Templates are package data of `dynid.templates` (the repository's `templates/`),
    found through the import system, so they work installed, editable or zipped.
    """
    return jinja2.Environment(
        loader=jinja2.PackageLoader(TEMPLATE_PACKAGE, "."),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )


def _check_sections(sections):
    seen = set()
    for s in sections:
        if not isinstance(s, Section):
            raise TypeError(f"report sections must be dynid.reports.html.Section, got {type(s).__name__}")
        if not _ID_RE.match(s.id):
            raise ValueError(f"section id {s.id!r} must match [a-z][a-z0-9-]*")
        if s.id in seen:
            raise ValueError(f"two report sections have the id {s.id!r}")
        seen.add(s.id)
        keys = [f.key for f in s.figures] + [t.key for t in s.tables]
        for k in keys:
            if k in seen:
                raise ValueError(f"the id {k!r} is used twice in the report")
            seen.add(k)


def render_sections(sections, *, title, subtitle="", highlights=(), footer=(), verdict=None, lead=()) -> str:
    """The HTML page of `sections` (a list of `Section`).

    `highlights`: (label, value) pairs shown under the title; `footer`:
    lines of text at the bottom; `verdict`: a `VerdictBlock` (see
    `verdict_block`) shown above the sections; `lead`: sections shown first, above
    the verdict (what the report is about: a diagnosis report's diagnosis).

    Returns
    -------
    str
        The HTML text.
    """
    sections, lead = list(sections), list(lead)
    _check_sections(lead + sections)
    html = environment().get_template(TEMPLATE).render(
        title=title, subtitle=subtitle, sections=sections, lead=lead, highlights=list(highlights),
        footer=list(footer), generator=f"dynid {versions().get('dynid', '?')}", verdict=verdict,
    )
    return html


def write_report(path, html: str) -> None:
    """Write `html` to `path` atomically (all or nothing, never half a file)."""
    atomic_write_text(path, html)


# ------------------------------------------------------------------ the verdict
#: level -> (css class, icon); the same colours and icons everywhere in the verdict block
LEVELS = {"ok": ("ok", "\u2714"), "info": ("info", "\u2139"), "warn": ("warn", "\u26a0"),
          "bad": ("bad", "\u2716")}
STATUS_LEVEL = {"identified": "ok", "identified with reservations": "warn", "not identified": "bad"}


@dataclass
class VerdictBlock:
    """What the template shows first: status, findings, the %σ figure and the parameter table."""

    status: str
    level: str
    icon: str
    findings: list                  # (css class, icon, text)
    flagged_parameters: list
    flagged_joints: list
    figure: object = None           # FigureMarkup
    table: object = None            # Table
    why: str = ""                   # the reasons of the status, in one line


def verdict_block(v, kind="essential") -> VerdictBlock:
    """The `VerdictBlock` of a `dynid.analysis.statistics.verdict.Verdict`.

    `kind`: the parameters the verdict judged, "essential" (IDIM, DIDIM: their essential model) or
    "base" (the Projection Method and ML: every base parameter), named in the captions.
    """
    level = STATUS_LEVEL.get(v.status, "warn")
    findings = [(LEVELS.get(f["level"], LEVELS["info"])[0], LEVELS.get(f["level"], LEVELS["info"])[1],
                 f["text"]) for f in v.findings]
    names = [p["name"] for p in v.parameters]
    fig = F.verdict_rel_std_figure(names, [p["rel_std_percent"] for p in v.parameters],
                                   v.rel_std_threshold, kind=kind) if names else None
    ap = {c["name"]: c for c in (v.apriori or {}).get("compared", [])}
    df = pd.DataFrame({
        "value": [p["value"] for p in v.parameters],
        "unit": [p["unit"] for p in v.parameters],
        "rel_std_percent": [p["rel_std_percent"] for p in v.parameters],
        "identified": [not p["flagged"] for p in v.parameters],
        "apriori": [ap[n]["apriori"] if n in ap else np.nan for n in names],
        "n_sigma": [ap[n]["n_sigma"] if n in ap else np.nan for n in names],
    }, index=pd.Index(names, name="parameter"))
    k = (v.apriori or {}).get("k", 3.0)
    tab = T.make_table(df, "tab-verdict-parameters",
                       f"{kind.capitalize()} parameters: value, %\u03c3 (identified when \u2264 "
                       f"{v.rel_std_threshold:g} %), a-priori value and distance to it",
                       formats={"unit": "text", "identified": "bool", "rel_std_percent": "pct"},
                       labels={"value": "\u03c7\u0302", "rel_std_percent": "%\u03c3",
                               "apriori": "a-priori", "n_sigma": f"|\u03c7\u0302 \u2212 a-priori| / \u03c3 (flag > {k:g})"})
    reasons = list(getattr(v, "reasons", []) or [])
    warned = any(f.get("level") in ("warn", "bad") for f in (getattr(v, "findings", None) or []))
    why = (("; ".join(reasons) + ".") if reasons else
           "no check below failed; the warnings among them are worth a look." if warned else
           "every check below passed.")
    return VerdictBlock(status=v.status, level=LEVELS[level][0], icon=LEVELS[level][1],
                        findings=findings, flagged_parameters=list(v.not_identified),
                        flagged_joints=list(v.flagged_joints), figure=fig, table=tab,
                        why=f"{'Why' if reasons else 'Identified'}: {why}")


# ------------------------------------------------------------------ IDIM sections
def _pct(x, digits=2) -> str:
    x = float(x)
    return T.MISSING if not math.isfinite(x) else f"{100 * x:.{digits}f}\u00a0%"


def _max_finite(a):
    a = np.asarray(a, dtype=float)
    if a.size == 0:
        return None
    a = np.where(np.isnan(a), np.inf, a)
    m = float(a.max())
    return m if math.isfinite(m) else None


def _setting_value(key, value, joint_names):
    if isinstance(value, (list, tuple, np.ndarray)):
        vals = list(value)
        if len(vals) == len(joint_names):
            return ", ".join(f"{n} {T.format_number(v, 3)}" for n, v in zip(joint_names, vals))
        return ", ".join(T.format_number(v, 4) if isinstance(v, (int, float)) else str(v) for v in vals)
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return T.format_number(value)
    return str(value)


def _run_section(res, robot, experiment, reference):

    obs = res.observation
    names = joint_names_of(robot, obs.tau.shape[1])
    pairs = [("Robot", f"{robot.name}" + (f" \u2014 {robot.description}" if getattr(robot, "description", "") else ""))]
    if getattr(robot, "source", ""):
        pairs.append(("Robot file", code(robot.source)))
    pairs.append(("Data source", code(res.source)))
    if experiment is not None:
        label = getattr(experiment, "name", "") or ""
        pairs.append(("Experiment", f"{label + ': ' if label else ''}{experiment.n_samples} samples at "
                                    f"{T.format_number(experiment.fs)} Hz, "
                                    f"{T.format_number(experiment.duration)} s"))
    used = int(np.asarray(obs.row_mask).sum())
    pairs.append(("Identification data", f"{obs.n_raw} raw samples \u2192 {obs.n_samples} decimated "
                                         f"samples \u00d7 {obs.tau.shape[1]} joints; {used} equations used"))
    pairs.append(("Data hash (SHA-256)", code(res.data_hash or "\u2014")))
    body = kv_list(pairs)
    if res.notices:
        body = join(body, Markup("<h3>Notices</h3>"), bullets(res.notices, cls="notices"))

    # processing settings
    order = ["fs", "fc_position", "order", "nd", "f_decimation_cutoff", "edge", "bandwidth", "qd_threshold"]
    meaning = dict(SETTINGS_HELP, fs="sampling rate of the recording, Hz")
    keys = [k for k in order if k in res.settings] + [k for k in res.settings if k not in order]
    paper = reference.settings if reference is not None else {}
    rows = []
    for k in keys:
        row = {"setting": k, "value": _setting_value(k, res.settings[k], names),
               "meaning": meaning.get(k, "")}
        if paper:
            row["paper"] = _setting_value(k, paper[k], names) if k in paper else ""
        rows.append(row)
    settings_df = pd.DataFrame(rows).set_index("setting")
    labels = {"paper": "paper (section 5)"}
    t_settings = T.make_table(settings_df, "tab-settings", "Processing settings",
                              formats={"value": "text", "meaning": "text", "paper": "text"},
                              labels=labels)
    vers = versions()
    vdf = pd.DataFrame({"package": list(vers), "version": list(vers.values())}).set_index("package")
    t_versions = T.make_table(vdf, "tab-versions", "dynid and dependency versions",
                              formats={"version": "code"})
    return Section("run", "Run and data", body, details=[t_settings, t_versions],
                   details_summary="Processing settings and versions")


def _model_section(robot, res):
    n = robot.n_joints
    names = joint_names_of(robot, n)
    desc = []
    if getattr(robot, "description", ""):
        desc.append(para(robot.description))
    desc.append(para(f"{n} joints ({', '.join(names)}); {robot.n_standard} standard parameters, "
                     f"{res.base.n_base} base parameters."))
    couplings = []
    for c in getattr(robot, "couplings", []) or []:
        joints = ", ".join(str(j) for j in c.joints)
        coefs = ", ".join(T.format_number(x) for x in c.coefficients)
        text = f"motor {c.motor} turns with joints {joints} (coefficients {coefs})"
        if c.parameter_names:
            text += f"; friction parameters {', '.join(c.parameter_names)}"
        couplings.append(text)
    desc.append(Markup("<h3>Couplings</h3>"))
    desc.append(bullets(couplings) if couplings else para("none"))
    tables = []
    dh = robot.dh_table()
    if dh:
        df = pd.DataFrame([{"j": r[0], "joint": nm, "sigma": int(r[1]), "alpha": r[2], "d": r[3],
                            "theta": r[4], "r": r[5]} for r, nm in zip(dh, names)]).set_index("j")
        tables.append(T.make_table(df, "tab-dh", "Modified Denavit-Hartenberg parameters "
                                   "(Khalil-Kleinfinger; angles in rad, lengths in m)",
                                   formats={"alpha": "angle", "theta": "angle", "d": "num", "r": "num",
                                            "joint": "text"},
                                   labels={"alpha": "\u03b1 [rad]", "theta": "\u03b8 [rad]", "sigma": "\u03c3",
                                           "d": "d [m]", "r": "r [m]"}))
    else:
        desc.append(para("No DH table: the joints' placements come from a URDF."))
    jrows = []
    for k, j in enumerate(robot.joints):
        jrows.append({"j": k + 1, "joint": j.name, "type": "prismatic" if j.sigma == 1 else "revolute",
                      "q_min": float(j.q_limits[0]), "q_max": float(j.q_limits[1]),
                      "qd_max": float(j.qd_max), "tau_max": float(j.tau_max),
                      "drive_gain": float(j.drive_gain)})
    jdf = pd.DataFrame(jrows).set_index("j")
    prismatic = any(j.sigma == 1 for j in robot.joints)
    tables.append(T.make_table(jdf, "tab-joints", "Joints and limits",
                               formats={"joint": "text", "type": "text"},
                               labels={"q_min": "q min [rad]", "q_max": "q max [rad]", "qd_max": "qd max [rad/s]",
                                       "tau_max": "\u03c4 max [N m]",
                                       "drive_gain": "drive gain [N m per unit of the logged signal]"},
                               note=("A prismatic joint's limits are in m, m/s and N, and so are its "
                                     "positions, velocities and torques (forces) wherever this report "
                                     "says rad, rad/s and N m." if prismatic else ""), prismatic=prismatic))
    prov = dict(getattr(robot, "provenance", {}) or {})
    if prov:
        pdf = pd.DataFrame({"what": list(prov), "source": [str(v) for v in prov.values()]}).set_index("what")
        tables.append(T.make_table(pdf, "tab-provenance", "Provenance of the robot's numbers"))
    return Section("model", "Model", join(*desc), details=tables,
                   details_summary="DH table, joints and limits, provenance")


def _base_section(res):
    table = res.parameter_table()
    shown = pd.DataFrame({
        "relation": [r.split(" = ", 1)[1] if " = " in r else r for r in table["relation"]],
        "unit": [parameter_unit(n, res._prismatic()) for n in table.index],
        "ols": table["ols"], "ols_rel_std": table["ols_rel_std"],
        "wls": table["wls"], "wls_rel_std": table["wls_rel_std"],
        "essential": table["essential"].astype(bool),
    }, index=table.index)
    labels = {"name": "Parameter", "relation": "Relation (= regrouped standard parameters)",
              "ols": "OLS \u03c7\u0302", "ols_rel_std": "OLS %\u03c3",
              "wls": "WLS \u03c7\u0302", "wls_rel_std": "WLS %\u03c3", "essential": "essential"}
    csv_frame = table.rename(columns={c: f"{c}_percent" for c in table.columns if c.endswith("_rel_std")})
    csv_frame.insert(1 if "relation" in table.columns else 0, "unit", shown["unit"])
    if getattr(res, "truth", None):
        shown.insert(0, "true", [res.truth.get(n, np.nan) for n in table.index])
        labels["true"] = "true value"
        csv_frame = csv_frame.assign(true=[res.truth.get(n, np.nan) for n in table.index])
    tab = T.make_table(shown, "tab-base", "Base parameters: OLS and per-joint WLS estimates",
                       formats={"relation": "code", "essential": "bool", "unit": "text"}, labels=labels,
                       csv_frame=csv_frame, cls="base")
    body = join(
        para(f"{res.base.n_base} base parameters (eq. (4)), {len(res.model.names)} essential. "
             f"Relative error norm \u2016Y \u2212 W\u03c7\u0302\u2016/\u2016Y\u2016: OLS {_pct(res.ols.rel_error)}, "
             f"WLS {_pct(res.wls.rel_error)}, essential model {_pct(res.model.rel_error)}. "
             f"cond(W): OLS {T.format_number(res.ols.cond)}, WLS {T.format_number(res.wls.cond)} "
             f"(unit columns: {T.format_number(res.wls.cond_scaled)})."),
        para("%\u03c3 = 100 \u03c3/|\u03c7\u0302| (eq. (15)); the WLS weights each joint's equations "
             "by 1/\u03c3\u2c7c of its OLS residual (eq. (16)).", cls="hint"),
        para(f"Uncertainty (\u03c3): {res.uncertainty_text}."),
    )
    return Section("base-parameters", "Base parameters", body, tables=[tab])


def _table2_section(res, reference):
    # The papers' Table 2 layout only where a published table exists to set beside it; any other
    # robot gets its essential parameters under their own name (same anchor, same figure).
    m = res.model
    published = reference is not None
    tab = T.table2_layout(m.names, m.chi, m.rel_std.to_numpy(), reference, res.base.names, key="tab-table2",
                          caption=("Essential parameters (WLS) in the layout of Table 2" if published else
                                   "Essential parameters (WLS): value and %\u03c3"),
                          ours_label="dynid WLS", prismatic=res._prismatic())
    ref_map = reference.rel_std_map() if published else None
    fig = F.rel_std_bar_figure(m.names, m.rel_std.to_numpy(), ref_map, key="fig-rel-std",
                               ours_label="dynid WLS")
    if published:
        common = [n for n in m.names if n in reference]
        body = join(
            para(f"The {len(m.names)} essential parameters identified by WLS, beside the published "
                 f"values of {reference.title} ({reference.method}); {len(common)} of the paper's "
                 f"{len(reference)} parameters are in dynid's essential set."),
            para(reference.citation, ". ", reference.note, cls="hint"),
        )
    else:
        body = para(f"The {len(m.names)} essential parameters identified by WLS, with their %\u03c3.")
    return Section("table2", "Essential parameters (Table 2)" if published else "Essential parameters",
                   body, figures=[fig], tables=[tab], tables_first=True)


def _path_section(res):
    ess = res.essential
    crit = ", ".join(f"{k} = {T.format_number(v) if isinstance(v, (int, float)) else v}"
                     for k, v in ess.criteria.items() if v is not None) or "none"
    body = join(
        para(f"Backward elimination (Pham & Gautier 1991) from the {len(ess.essential) + len(ess.removed)} "
             f"WLS base parameters: the parameter with the largest %\u03c3 is removed and the model "
             f"re-estimated, while the relative error norm stays within the criterion. "
             f"{len(ess.removed)} removed, {len(ess.essential)} essential. The elimination ranks by the "
             f"%\u03c3 of each refit (eq. (15), the papers' \u03c3); the parameter tables show the "
             f"{getattr(res, 'uncertainty', 'classic')} \u03c3, which may differ."),
        kv_list([("Criteria", crit), ("Stop rule", ess.stop_rule), ("Stop reason", ess.stop_reason)]),
    )
    g = ess.criteria.get("max_error_growth")
    limit = ess.base.rel_error * (1 + g) if g is not None else None
    fig = F.essential_path_figure(ess.path, base_rel_error=ess.base.rel_error,
                                  base_max_rel_std=_max_finite(ess.base.rel_std.to_numpy()),
                                  error_limit=limit, key="fig-essential-path")
    path = ess.path.set_index("step")
    shown = path.assign(rel_error=100.0 * path["rel_error"])      # in % as everywhere in the report
    tab = T.make_table(shown, "tab-essential-path", "Elimination path",
                       formats={"removed": "text", "rel_std_removed": "pct",
                                "max_rel_std_remaining": "pct", "rel_error": "num",
                                "n_remaining": "int"},
                       labels={"rel_std_removed": "%\u03c3 (eq. 15) of the removed", "max_rel_std_remaining":
                               "max %\u03c3 (eq. 15) remaining", "rel_error": "relative error [%]",
                               "n_remaining": "remaining"}, csv_frame=path)
    return Section("essential-path", "Elimination path", body, figures=[fig], tables=[tab])


def _joint_error_table(key, caption, names, rms, rel, sigma=None, prismatic=False):
    df = pd.DataFrame({"joint": names, "rms": np.asarray(rms, dtype=float),
                       "rel_error_percent": 100 * np.asarray(rel, dtype=float)},
                      index=pd.Index(np.arange(1, len(names) + 1), name="j"))
    labels = {"rms": "RMS residual [N m]", "rel_error_percent": "relative error [%]"}
    if sigma is not None:
        df["wls_sigma"] = np.asarray(sigma, dtype=float)
        labels["wls_sigma"] = "\u03c3\u2c7c (WLS weight 1/\u03c3\u2c7c) [N m]"
    return T.make_table(df, key, caption, formats={"joint": "text", "rel_error_percent": "num"},
                        labels=labels, prismatic=prismatic)


def _torque_section(res, robot, reference):
    obs = res.observation
    names = joint_names_of(robot, obs.tau.shape[1])
    est = res.predict(obs.W)
    mask = np.broadcast_to(np.asarray(obs.row_mask, dtype=bool), obs.tau.shape)
    frac = float(mask.mean())
    fitted = f"fitted (moving) samples, {_pct(frac, 1)} of rows"
    fig = F.torque_figure(obs.t, obs.tau, est, names, key="fig-torque", mask=mask,
                          caption="Identification data, " + fitted + ": measured torque Y(\u03c4) (red) "
                                  "and torque estimated by the essential WLS model W\u03c7\u0302 (blue), "
                                  "per joint, at the decimated rate (layout of Fig. 6 of the paper)")
    m = res.model
    tab = _joint_error_table("tab-torque-errors", "Per-joint residual of the essential model "
                             f"(identification data, {fitted})", names, m.rms,
                             m.joint_rel_error, m.joint_sigma, prismatic=bool(prismatic_of(robot)))
    text = (f"Relative error norm \u2016Y \u2212 W\u03c7\u0302\u2016/\u2016Y\u2016 of the essential model on "
            f"the identification data ({fitted}; the rest is the velocity dead zone, where "
            f"Coulomb friction's sign is undetermined at rest): {_pct(m.rel_error)}.")
    if reference is not None and "rel_error_below" in reference.settings:
        text += f" The paper reports below {_pct(reference.settings['rel_error_below'], 0)} for IDIM-LS and DIDIM."
    return Section("torques", "Measured vs estimated torque", para(text), figures=[fig], tables=[tab])


def _validation_section(res, robot, validation):
    n = validation.tau.shape[1]
    names = joint_names_of(robot, n)
    excl = float(getattr(validation, "excluded_fraction", 0.0))
    t = np.asarray(validation.t, dtype=float)
    same = str(getattr(res, "source", "")) == str(validation.source)
    span = (f"t = {t[0]:.4g} \u2026 {t[-1]:.4g} s" if t.size else T.MISSING) + (
        ": held out from the identification recording (never fitted)" if same else "")
    pairs = [("Validation data", code(validation.source)),
             ("Time span", span),
             ("Samples", f"{len(validation.t)} decimated samples, all of them predicted"),
             ("Relative error \u2016\u03c4 \u2212 \u03c4\u0302\u2016/\u2016\u03c4\u2016, all samples",
              _pct(validation.rel_error)),
             ("Moving samples only", f"{_pct(validation.moving_rel_error)} ({_pct(excl, 1)} of the "
                                     f"equations excluded: {DEAD_ZONE_REASON})")]
    body = kv_list(pairs)
    if validation.notices:
        body = join(body, Markup("<h3>Notices</h3>"), bullets(validation.notices, cls="notices"))
    body = join(body, para("The essential model predicts torques of data it was not fitted to, "
                           "processed with the same filter and decimation. The headline error is over "
                           "ALL held-out samples (\u03c4\u0302 = W\u03c7\u0302, nothing zeroed); the "
                           "moving-sample error leaves out the rows of the velocity dead zone, as the "
                           "fit did. A Gaussian residual (Jarque-Bera and Shapiro-Wilk p not small) "
                           "supports the least-squares assumptions behind %\u03c3.", cls="hint"))
    fig_t = F.torque_figure(validation.t, validation.tau, validation.tau_hat, names,
                            key="fig-validation-torque",
                            shade=None if validation.mask is None else ~np.asarray(validation.mask),
                            shade_label="dead zone: in the all-sample error, not in the moving one",
                            caption="Validation data, all held-out samples: measured torque (red) and "
                                    "torque predicted by the essential model (blue), per joint; grey "
                                    "bands: the velocity dead zone, left out of the moving-sample error")
    fig_p = F.residual_pdf_figure(validation.residual, names,
                                  np.asarray(validation.noise["jarque_bera_p"], dtype=float),
                                  key="fig-residual-pdf",
                                  caption="Validation residual PDF per joint, all held-out samples: "
                                          "histogram, fitted normal density (red), kernel density "
                                          "estimate (blue, dashed); Jarque-Bera p-value in the title")
    tab_e = _joint_error_table("tab-validation-errors", "Per-joint prediction error (validation data, "
                               "all samples)", names, validation.rms, validation.joint_rel_error,
                               prismatic=bool(prismatic_of(robot)))
    mj = getattr(validation, "moving_joint_rel_error", None)
    tab_e_m = None
    if mj is not None:
        df = pd.DataFrame({"joint": names, "rel_error_percent": 100 * np.asarray(mj, dtype=float),
                           "excluded_percent": 100 * np.asarray(validation.excluded_per_joint)},
                          index=pd.Index(np.arange(1, n + 1), name="j"))
        tab_e_m = T.make_table(df, "tab-validation-errors-moving", "Per-joint prediction error on the "
                               "moving samples only (dead-zone rows excluded)",
                               formats={"joint": "text", "rel_error_percent": "num",
                                        "excluded_percent": "num"},
                               labels={"rel_error_percent": "relative error [%]",
                                       "excluded_percent": "excluded, decimated rows [%]"})
    tabs = [tab_e] + ([tab_e_m] if tab_e_m is not None else [])
    for key, caption, frame in (("tab-normality", "Residual noise-PDF checks per joint (all samples)",
                                 validation.noise),
                                ("tab-normality-moving", "Residual noise-PDF checks per joint (moving "
                                 "samples: the rows the diagnosis tests)",
                                 getattr(validation, "noise_moving", None))):
        if frame is None:
            continue
        noise = frame.copy()
        noise.insert(0, "name", names[:len(noise)])
        noise.index.name = "j"
        tabs.append(T.make_table(noise, key, caption, formats={"name": "text", "n": "int",
                                                               "shapiro_n": "int"},
                                 labels={"name": "joint", "mean": "mean [N m]", "std": "std [N m]",
                                         "excess_kurtosis": "excess kurtosis",
                                         "jarque_bera": "Jarque-Bera", "jarque_bera_p": "JB p",
                                         "shapiro": "Shapiro-Wilk W", "shapiro_p": "SW p",
                                         "shapiro_n": "SW samples (evenly spaced)"},
                                 prismatic=bool(prismatic_of(robot))))
    return Section("validation", "Validation", body, figures=[fig_t, fig_p], tables=tabs)



def idim_sections(idim_result, robot, experiment=None, validation=None, *, reference="auto"):
    """The sections of an IDIM report (ids `SECTION_IDS`; `validation` only if given).

    `reference`: a `dynid.reports.paper.ReferenceTable`, `None`, or
    `"auto"` (the published table for this robot, if any).
    """
    if isinstance(reference, str) and reference == "auto":
        reference = reference_for(robot)
    sections = [
        _run_section(idim_result, robot, experiment, reference),
        _model_section(robot, idim_result),
        _base_section(idim_result),
        _table2_section(idim_result, reference),
        _path_section(idim_result),
        _torque_section(idim_result, robot, reference),
    ]
    if validation is not None:
        sections.append(_validation_section(idim_result, robot, validation))
    return sections


#: what a report is, from the sections it carries beyond IDIM's: its title names it
REPORT_TITLES = {
    "identification": "Identification of {robot}",
    "diagnosis": "Residual diagnosis of {robot}",
    "posterior": "Posterior of the parameters of {robot}",
    "didim": "DIDIM identification of {robot}",
    "full": "Full report on {robot}: identification, validation and beyond",
}


def report_kind(extra_sections) -> str:
    """What a report with these extra sections is (a key of `REPORT_TITLES`).

    Returns
    -------
    str
        `"identification"` without extra sections, `"diagnosis"`, `"posterior"` or
        `"didim"` with the sections of one of them, `"full"` with several.
    """
    kinds = set()
    for sec in extra_sections or ():
        sid = getattr(sec, "id", "")
        for kind in ("diagnosis", "posterior", "didim"):
            if sid == kind or sid.startswith(kind + "-"):
                kinds.add(kind)
    if len(kinds) > 1:
        return "full"
    return kinds.pop() if kinds else "identification"


def render_idim_report(idim_result, robot, experiment=None, validation=None, *, title=None,
                       extra_sections=None, reference="auto", verdict=None, kind=None, lead_sections=None,
                       lead_highlights=None) -> str:
    """One self-contained HTML page reporting an IDIM identification.

    `extra_sections` (list of `Section`) are appended after the
    standard ones. `verdict`: a `dynid.analysis.statistics.verdict.Verdict`
    (computed from the result and the validation if not given), shown first.
    `kind`: what the report is (a key of `REPORT_TITLES`: `"full"` for the
    pipeline's report); by default read from the extra sections (`report_kind`).
    The title says it unless `title` is given. `lead_sections` are shown first, above the
    verdict, and `lead_highlights` ((label, value) pairs) first under the title: what the
    report is about when it is not the identification (a diagnosis report leads with the
    diagnosis: `dynid.reports.diagnosis_section.diagnosis_lead`).

    Returns
    -------
    str
        The HTML text; write it with `write_report`.
    """
    if verdict is None:
        verdict = _verdict(idim_result, validation, robot=robot)
    if isinstance(reference, str) and reference == "auto":
        reference = reference_for(robot)
    sections = idim_sections(idim_result, robot, experiment, validation, reference=reference)
    sections += list(extra_sections or [])
    m = idim_result.model
    highlights = [
        ("robot", idim_result.robot_name),
        ("base parameters", str(idim_result.base.n_base)),
        ("essential", str(len(m.names))),
        ("relative error (identification, fitted rows)", _pct(m.rel_error)),
    ]
    if validation is not None:
        highlights.append(("held-out error (all samples)", _pct(validation.rel_error)))
        highlights.append(("held-out error (moving samples)", _pct(validation.moving_rel_error)))
    highlights.insert(0, ("verdict", verdict.status))
    highlights = list(lead_highlights or []) + highlights
    footer = ["Method: IDIM with OLS, per-joint WLS and essential parameters, after section 2 of "
              "Gautier, Janot, Vandanjon (2010)."]
    if reference is not None:
        footer.append(f"Reference values: {reference.citation}, {reference.title}.")
    return render_sections(
        sections,
        title=title or REPORT_TITLES[kind or report_kind(extra_sections)].format(robot=idim_result.robot_name),
        subtitle=str(idim_result.source),
        highlights=highlights,
        footer=footer,
        verdict=verdict_block(verdict),
        lead=lead_sections or (),
    )
