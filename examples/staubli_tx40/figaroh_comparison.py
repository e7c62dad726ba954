"""dynid's TX40 estimates beside FIGAROH's published results and Table 2 of the DIDIM paper.

Part of this example, not of the dynid package (run.py imports it from beside
itself; tests/integration/test_comparison.py and benchmarks/real_data.py from this folder).

``comparison_frame(idim, reference_dir, didim=None)`` returns one row per
compared quantity, every value with its %σ in each source:

* dynid IDIM: OLS, per-joint WLS, and the essential WLS model;
* dynid DIDIM (optional): the last Gauss-Newton step's WLS on all base parameters;
* FIGAROH (``reference_results/TX40_bp_5.csv``: OLS and WLS of the 60 base
  parameters; ``TX40_ep_5.csv``: WLS of their 25 essential ones), the FIGAROH
  authors' identification on the same recording;
* Table 2 of Gautier, Janot, Vandanjon (2010), :data:`dynid.reports.paper.DIDIM_TX40_TABLE2`:
  DIDIM on another recording of a TX40 (section 5 of the paper).

Mapping. FIGAROH's base parameters have the same regrouping relations as
dynid's (checked in ``tests/dynamics/test_base_parameters.py``) except at the coupled
wrist, which FIGAROH parametrises differently: its ``fv5``, ``fv6`` include
the diagonal part of the motor-6 viscous friction, so they are compared with
dynid's ``Fv5 + Fvm6`` and ``Fv6 + Fvm6`` (value and σ of the sum, from the
covariance); its ``Iam6`` is only the off-diagonal part of dynid's ``Ia6`` and
has no counterpart. Table 2 uses dynid's (the paper's) parametrisation:
``Fv5``, ``Fv6``, ``Fvm6`` separately.

``comparison_section(frame, reading=...)`` makes a report Section of it
with counts of agreement computed from the numbers; ``reading`` is the
hand-written interpretation (a list of paragraphs).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from dynid.reports.paper import DIDIM_TX40_TABLE2

__all__ = ["comparison_frame", "comparison_summary", "comparison_section", "figaroh_to_dynid",
           "WELL_IDENTIFIED"]

#: %σ below which a parameter counts as well identified (in the agreement counts)
WELL_IDENTIFIED = 5.0

_FIGAROH = {"Izz": "ZZ", "Ixx": "XX", "Iyy": "YY", "Ixz": "XZ", "Ixy": "XY", "Iyz": "YZ",
            "mx": "MX", "my": "MY", "mz": "MZ", "m": "M", "fv": "Fv", "fs": "Fc", "off": "Off",
            "Ia": "Ia", "Iam": "Iam", "fvm": "Fvm", "fsm": "Fcm"}


def figaroh_to_dynid(expr, base):
    """(label, {dynid base name: coefficient}) of a FIGAROH base parameter, or (label, None)."""
    head = expr.split(" ")[0]
    sym, num = re.match(r"([A-Za-z]+?)(\d+)$", head).groups()
    name = _FIGAROH[sym] + num
    if name == "Iam6":
        return "Iam6 (FIGAROH only)", None
    lead = {base.standard_names[i]: base.names[k] for k, i in enumerate(base.independent)}
    dyn = lead.get(name, name)
    if name in ("Fv5", "Fv6"):
        return f"{dyn} + Fvm6", {dyn: 1.0, "Fvm6": 1.0}
    return dyn, {dyn: 1.0}


def _combo(res, combo):
    """Value, std and %σ of sum_k c_k chi_k in an IdentificationResult (NaN if a name is missing)."""
    if res is None or combo is None or any(n not in res.names for n in combo):
        return np.nan, np.nan, np.nan
    c = np.zeros(len(res.names))
    for n, k in combo.items():
        c[res.names.index(n)] = k
    v = float(c @ res.chi)
    s = float(np.sqrt(max(c @ res.cov @ c, 0.0)))
    return v, s, 100 * s / abs(v) if v != 0 else np.inf


def _read_figaroh(path):
    if not Path(path).exists():
        return None
    df = pd.read_csv(path, header=None, names=["expr", "ols", "ols_rel_std", "wls", "wls_rel_std"])
    return df.set_index("expr")


def comparison_frame(idim, reference_dir, didim=None, table2=DIDIM_TX40_TABLE2) -> pd.DataFrame:
    """One row per compared quantity (see the module docstring); index = dynid quantity."""
    ref = Path(reference_dir)
    bp_df = _read_figaroh(ref / "TX40_bp_5.csv")
    ep_df = _read_figaroh(ref / "TX40_ep_5.csv")
    didim_res = getattr(didim, "result", None)
    ess = idim.model
    rows = []

    def row(label, combo, fig_expr=None):
        r = {"quantity": label, "figaroh": fig_expr or ""}
        for key, res in (("ols", idim.ols), ("wls", idim.wls), ("ess", ess), ("didim", didim_res)):
            v, s, p = _combo(res, combo)
            if key == "ess" and combo is not None and all(n not in ess.names for n in combo):
                v, s, p = np.nan, np.nan, np.nan
            r[f"dynid_{key}"], r[f"dynid_{key}_std"], r[f"dynid_{key}_rel_std"] = v, s, p
        for key, df in (("fig_ols", bp_df), ("fig_wls", bp_df), ("fig_ess", ep_df)):
            col = "wls" if key != "fig_ols" else "ols"
            if fig_expr is not None and df is not None and fig_expr in df.index:
                r[key], r[f"{key}_rel_std"] = float(df.at[fig_expr, col]), float(df.at[fig_expr, f"{col}_rel_std"])
            else:
                r[key], r[f"{key}_rel_std"] = np.nan, np.nan
        pub = table2.get(label) if table2 is not None else None
        r["table2"] = pub.value if pub else np.nan
        r["table2_rel_std"] = pub.rel_std_percent if pub else np.nan
        rows.append(r)

    seen = set()
    if bp_df is not None:
        for expr in bp_df.index:
            label, combo = figaroh_to_dynid(expr, idim.base)
            row(label, combo, expr)
            seen.add(label)
    # dynid parameters FIGAROH has only in another combination (Fv5, Fv6, Ia6) or not at all
    for name in idim.base.names:
        if name not in seen:
            row(name, {name: 1.0})
    df = pd.DataFrame(rows).set_index("quantity")
    # agreement: dynid WLS vs FIGAROH WLS in combined sigma; dynid vs Table 2 in %
    fig_std = df["fig_wls_rel_std"] / 100 * df["fig_wls"].abs()
    df["wls_diff_sigma"] = (df["dynid_wls"] - df["fig_wls"]) / np.hypot(df["dynid_wls_std"], fig_std)
    df["wls_diff_percent"] = 100 * (df["dynid_wls"] - df["fig_wls"]) / df["fig_wls"].abs()
    df["table2_diff_percent"] = 100 * (df["dynid_wls"] - df["table2"]) / df["table2"].abs()
    df["didim_vs_idim_sigma"] = (df["dynid_didim"] - df["dynid_wls"]) / np.hypot(df["dynid_didim_std"],
                                                                               df["dynid_wls_std"])
    return df


def comparison_summary(df, well=WELL_IDENTIFIED) -> dict:
    """Counts of agreement computed from :func:`comparison_frame` (JSON-safe numbers)."""
    both = df[(df["dynid_wls_rel_std"] < well) & (df["fig_wls_rel_std"] < well)]
    agree = both[(both["wls_diff_sigma"].abs() <= 3) | (both["wls_diff_percent"].abs() <= 5)]
    t2 = df[df["table2"].notna()]
    t2_within10 = t2[t2["table2_diff_percent"].abs() <= 10]
    t2_within20 = t2[t2["table2_diff_percent"].abs() <= 20]
    single = [q for q in df.index if " + " not in q]       # sums like Fv5 + Fvm6 are not parameters
    ess_dyn = set(q for q in single if pd.notna(df.at[q, "dynid_ess"]))
    ess_fig = set(df.index[df["fig_ess"].notna()])
    ess_t2 = set(df.index[df["table2"].notna()])
    didim = df[df["dynid_didim"].notna() & (df["dynid_wls_rel_std"] < well)]
    return {
        "well_identified_percent": well,
        "both_well_identified": int(len(both)),
        "agree_within_3sigma_or_5percent": int(len(agree)),
        "disagree": sorted(set(both.index) - set(agree.index)),
        "table2_parameters": int(len(t2)),
        "table2_within_10_percent": int(len(t2_within10)),
        "table2_within_20_percent": int(len(t2_within20)),
        "table2_beyond_20_percent": sorted(set(t2.index) - set(t2_within20.index)),
        "essential_dynid": int(len(ess_dyn)), "essential_figaroh": int(len(ess_fig)),
        "essential_table2": int(len(ess_t2)),
        "essential_common_all_three": int(len(ess_dyn & ess_fig & ess_t2)),
        "didim_compared": int(len(didim)),
        "didim_within_3sigma_of_idim": int((didim["didim_vs_idim_sigma"].abs() <= 3).sum()),
    }


_LABELS = {
    "figaroh": "FIGAROH expression",
    "dynid_ols": "dynid OLS", "dynid_ols_rel_std": "%\u03c3",
    "dynid_wls": "dynid WLS", "dynid_wls_rel_std": "%\u03c3",
    "dynid_ess": "dynid essential", "dynid_ess_rel_std": "%\u03c3",
    "dynid_didim": "dynid DIDIM", "dynid_didim_rel_std": "%\u03c3",
    "fig_ols": "FIGAROH OLS", "fig_ols_rel_std": "%\u03c3",
    "fig_wls": "FIGAROH WLS", "fig_wls_rel_std": "%\u03c3",
    "fig_ess": "FIGAROH essential", "fig_ess_rel_std": "%\u03c3",
    "table2": "Table 2 (DIDIM)", "table2_rel_std": "%\u03c3",
    "wls_diff_sigma": "dynid\u2212FIGAROH WLS [\u03c3]",
    "table2_diff_percent": "dynid WLS\u2212Table 2 [%]",
}


def comparison_section(df, *, reading=(), id="comparison",
                       title="Comparison with FIGAROH and Table 2 of the DIDIM paper"):
    """A report Section of :func:`comparison_frame` with the agreement counts and ``reading``."""
    from dynid.reports import tables as T
    from dynid.reports.html import Section, bullets, join, para
    s = comparison_summary(df)
    cols = [c for c in _LABELS if c in df.columns and c != "figaroh"]
    if df["dynid_didim"].isna().all():
        cols = [c for c in cols if not c.startswith("dynid_didim")]
    shown = df[cols]
    formats = {c: ("pct" if c.endswith("rel_std") else "num") for c in cols}
    tab = T.make_table(shown, f"tab-{id}", "Every compared parameter with its %\u03c3 in each source "
                       "(\u2014: not in that source's set)", formats=formats, labels=_LABELS,
                       csv_frame=df)
    facts = [
        f"{s['both_well_identified']} quantities have %\u03c3 < {s['well_identified_percent']:g} in both "
        f"dynid's and FIGAROH's WLS; {s['agree_within_3sigma_or_5percent']} of them agree within 3 "
        f"combined \u03c3 or 5 %" + (f" (not: {', '.join(s['disagree'])})." if s["disagree"] else "."),
        f"Table 2: {s['table2_within_10_percent']} of its {s['table2_parameters']} parameters are within "
        f"10 % of dynid's WLS value, {s['table2_within_20_percent']} within 20 %"
        + (f" (beyond 20 %: {', '.join(s['table2_beyond_20_percent'])})." if s["table2_beyond_20_percent"] else "."),
        f"Essential sets: dynid {s['essential_dynid']}, FIGAROH {s['essential_figaroh']}, Table 2 "
        f"{s['essential_table2']} parameters; {s['essential_common_all_three']} in all three.",
    ]
    if s["didim_compared"]:
        facts.append(f"DIDIM (measured q as reference) vs IDIM WLS: {s['didim_within_3sigma_of_idim']} of "
                     f"{s['didim_compared']} well-identified parameters within 3 combined \u03c3.")
    body = join(
        para("FIGAROH: the FIGAROH authors' OLS/WLS identification of this same recording "
             "(reference_results/). Table 2: DIDIM estimates of Gautier, Janot, Vandanjon (2010) "
             "on their own recording of a TX40. FIGAROH's fv5 and fv6 are compared with dynid's "
             "Fv5 + Fvm6 and Fv6 + Fvm6; its Iam6 has no dynid counterpart."),
        bullets(facts),
        *[para(p) for p in reading],
    )
    return Section(id, title, body, tables=[tab])
