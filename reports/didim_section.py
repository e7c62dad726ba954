"""HTML report sections of a DIDIM identification (section 3 and 5 of the DIDIM paper).

`didim_sections(didim_result, idim_result=None)` returns
`dynid.reports.html.Section` objects to pass as `extra_sections` to
`dynid.reports.html.render_idim_report`, or to
`dynid.reports.html.render_sections` on their own:

* `didim-convergence`: ||rho|| and its relative change per Gauss-Newton
  step, the stop rule, the history table (step length, output error,
  tracking error and derivative-gain factors per joint);
* `didim-table2`: the DIDIM estimate with the %σ bars (in the layout of
  Table 2 beside the paper's values when a published table exists);
* `didim-torques`: actual torque Y(tau) vs the torque of the identified model
  on the simulated motion, W_delta chi_hat, at the decimated rate (Fig. 6);
* `didim-trajectories`: the last simulation's joint positions against the
  reference, and the tracking error (Fig. 7);
* `didim-vs-idim` (with `idim_result`): the two estimates side by side.

All ids are prefixed `didim-` / `fig-didim-` / `tab-didim-` so they never
clash with the IDIM report's.
"""
from __future__ import annotations

import math

import matplotlib
import numpy as np
import pandas as pd
from markupsafe import Markup
from matplotlib.figure import Figure

from dynid.analysis.units import prismatic_of
from dynid.dynamics.robot import joint_names_of
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import Section, bullets, code, join, kv_list, para
from dynid.reports.paper import reference_for

__all__ = ["didim_sections", "SECTION_IDS", "convergence_figure", "convergence_section", "trajectory_figure"]

#: Ids of the DIDIM sections, in order (``didim-vs-idim`` only with an IDIM result).
SECTION_IDS = ("didim-convergence", "didim-table2", "didim-torques", "didim-trajectories",
               "didim-vs-idim")


def _pct(x, digits=2) -> str:
    x = float(x)
    return T.MISSING if not math.isfinite(x) else f"{100 * x:.{digits}f}\u00a0%"


def _figure(width, height):
    return Figure(figsize=(width, height), layout="constrained")


# ----------------------------------------------------------------------------- figures
def convergence_figure(history, tol, *, key="fig-didim-convergence", caption=None, fmt="auto"):
    """||rho_k|| (and the output error at the simulated estimate) and the relative change
    of ||rho|| against the Gauss-Newton step, with tol_I."""
    it = np.asarray(history["iteration"], dtype=float)
    rho = np.asarray(history["rho_norm"], dtype=float)
    out = np.asarray(history["output_error"], dtype=float)
    rel = np.asarray(history["rel_change"], dtype=float)
    with matplotlib.rc_context(F.STYLE):
        fig = _figure(7.6, 3.9)
        ax1, ax2 = fig.subplots(2, 1, sharex=True)
        ax1.plot(it, rho, color=F.BLUE, marker="o", ms=3, lw=1.0,
                 label="\u2016\u03c1\u2096\u2016 = \u2016Y \u2212 W\u2096\u03c7\u0302\u2096\u2016")
        ax1.plot(it, out, color=F.GREY, marker="s", ms=2.5, lw=0.8, ls="--",
                 label="output error \u2016Y \u2212 W\u2096\u03c7\u0302\u2096\u208b\u2081\u2016")
        if np.all(np.isfinite(np.concatenate([rho, out]))) and np.nanmax(out) > 20 * np.nanmin(rho):
            F.log_scale(ax1, minor_labels=False)
        ax1.set_ylabel("norm [N m]")
        ax1.legend(loc="upper right", frameon=False)
        ok = np.isfinite(rel) & (rel > 0)
        if ok.any():
            ax2.plot(it[ok], rel[ok], color=F.RED, marker="o", ms=3, lw=1.0,
                     label="|\u2016\u03c1\u2096\u2016 \u2212 \u2016\u03c1\u2096\u208b\u2081\u2016| / "
                           "\u2016\u03c1\u2096\u208b\u2081\u2016")
            F.log_scale(ax2, minor_labels=False)
        ax2.axhline(tol, color=F.GREEN, ls="--", lw=1.0, label=f"tol_I = {tol:g}")
        ax2.set_ylabel("relative change")
        ax2.set_xlabel("Gauss-Newton step k")
        ax2.set_xticks(it)
        ax2.legend(loc="upper right", frameon=False)
    if caption is None:
        caption = ("DIDIM convergence: residual norm of each step's least squares and output error of "
                   "the estimate that was simulated (top); relative change of the residual norm, "
                   "the stop criterion (bottom, log scale)")
    return F.render_figure(fig, key, caption, fmt=fmt)


def trajectory_figure(t, reference, simulated, joint_names, *, key="fig-didim-trajectories",
                      caption=None, fmt="auto", error=False):
    """Reference (red) and simulated (black) joint positions per joint (layout of Fig. 7);
    with `error=True` the tracking error `reference - simulated` instead."""
    t = np.asarray(t, dtype=float)
    reference = np.asarray(reference, dtype=float)
    simulated = np.asarray(simulated, dtype=float)
    n = reference.shape[1]
    idx, step = F.decimate_for_plot(t.size)
    with matplotlib.rc_context(F.STYLE):
        rows, cols = F.grid_shape(n)
        fig = _figure(3.3 * cols, 1.9 * rows + 0.3)
        axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
        for j in range(rows * cols):
            ax = axes.flat[j]
            if j >= n:
                ax.set_visible(False)
                continue
            if error:
                ax.plot(t[idx], 1e3 * (reference[idx, j] - simulated[idx, j]), color=F.BLUE, lw=0.8,
                        label="q\u1d63 \u2212 q_sim")
            else:
                ax.plot(t[idx], reference[idx, j], color=F.RED, lw=1.0, label="reference q\u1d63")
                ax.plot(t[idx], simulated[idx, j], color="black", lw=0.7, ls="--",
                        label="simulated q (DDM)")
            ax.set_title(F._plain(F.joint_label(j, joint_names[j])), loc="left")
            if j % cols == 0:
                ax.set_ylabel("error [mrad]" if error else "position [rad]")
            if j >= n - cols:
                ax.set_xlabel("time [s]")
                ax.tick_params(labelbottom=True)
        handles, texts = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside upper right", ncols=2, frameon=False)
    if caption is None:
        caption = ("Tracking error of the simulated robot, reference minus simulated position, per joint"
                   if error else
                   "Reference trajectory (red) and the closed-loop simulation of the identified robot "
                   "(black dashed), per joint (layout of Fig. 7)")
    if step > 1:
        caption += f" (every {step}th of {t.size} samples plotted)"
    return F.render_figure(fig, key, caption, fmt=fmt)


# ----------------------------------------------------------------------------- sections
def convergence_section(res):
    """The report section of DIDIM's Gauss-Newton steps: the convergence figure and the tables.

    Parameters
    ----------
    res : DIDIMResult

    Returns
    -------
    Section
    """
    h = res.history
    s = res.settings
    state = "converged" if res.converged else "did NOT converge"
    pairs = [
        ("Result", f"{state} after {res.iterations} Gauss-Newton step(s)"),
        ("Stop", res.stop_reason),
        ("Criterion", f"|\u2016\u03c1\u2096\u2016 \u2212 \u2016\u03c1\u2096\u208b\u2081\u2016| / "
                      f"\u2016\u03c1\u2096\u208b\u2081\u2016 \u2264 tol_I = {T.format_number(s['tol'])}, "
                      f"at most {s['max_iter']} steps"),
        ("Initialisation", str(s.get("initialisation", ""))),
        ("Gain update", {True: "J\u0302\u2c7c / J_ap\u2c7c at every step (section 3.2)",
                         "initial": "J\u0302\u2c7c / J_ap\u2c7c for the simulation of \u03c7\u2070 only",
                         False: "none (kd_scale = 1)"}.get(s.get("update_gains"), str(s.get("update_gains")))),
        ("Simulation", f"controller at {T.format_number(s['rate'])} Hz"
                       f"{', velocity feedforward' if s['feedforward'] else ''}, Coulomb friction "
                       f"smoothed over v_s = {T.format_number(s['v_s'])} rad/s "
                       f"({s.get('v_s_choice', 'given')}), "
                       f"{'torque saturated' if s['saturate'] else 'no torque saturation'}; first "
                       f"{res.transient_samples} samples ({T.format_number(s['transient'])} s) dropped"),
        ("Decimation", f"nd = {s['nd']}, low-pass {T.format_number(s['f_decimation_cutoff'])} Hz; "
                       f"{res.t_dec.size} decimated samples"),
        ("Uncertainty (σ)", _uncertainty_label(res)),
        ("Data hash (SHA-256)", code(res.data_hash or "\u2014")),
    ]
    body = join(
        para("DIDIM (section 3 of the paper) simulates the robot in closed loop with the current "
             "estimate, builds the inverse-dynamics regressor from the simulated motion and solves the "
             "IDIM least squares for the next estimate (Gauss-Newton with the approximate Jacobian of "
             "eq. (21)); no joint position measurement is used."),
        kv_list(pairs),
    )
    if res.notices:
        body = join(body, Markup("<h3>Notices</h3>"), bullets(res.notices, cls="notices"))
    fig = convergence_figure(h, float(s["tol"]))
    n = res.q_sim.shape[1]
    # one step index everywhere: the history's own "iteration" column (1, 2, ...), which the
    # plot, the terminal summary, the JSON and the notices ("step k") use. The columns are
    # taken as plain arrays: Series keep their 0-based RangeIndex, and pandas would align
    # them to the new 1-based index (row k showing step k + 1, step 1 lost, last row empty).
    steps = pd.Index(h["iteration"].to_numpy().astype(int), name="step")

    def col(c, scale=1.0):
        return scale * h[c].to_numpy(dtype=float)

    shown = pd.DataFrame({
        **({"v_s": col("v_s")} if "v_s" in h else {}),
        "step_length": col("step_length"), "rho_norm": col("rho_norm"),
        "rel_change": col("rel_change"), "output_error": col("output_error"),
        "rel_error_percent": col("rel_error", 100.0),
        "max_rel_param_change": col("max_rel_param_change", 100.0),
        "max_change_sigma": col("max_change_sigma"),
    }, index=steps)
    labels = {"v_s": "v_s [rad/s]", "step_length": "step length", "rho_norm": "\u2016\u03c1\u2016 [N m]",
              "rel_change": "relative change of \u2016\u03c1\u2016", "output_error": "output error [N m]",
              "rel_error_percent": "relative error [%]",
              "max_rel_param_change": "max relative parameter change [%]",
              "max_change_sigma": "max change [\u03c3]"}
    # the CSV keeps every column of the history, in SI units named in the header (fractions as
    # fractions, docs/formats.md), where the tracking table shows mrad
    length = "m or rad" if prismatic_of(res) else "rad"
    history_csv = h.set_index("iteration").rename(columns={
        **{f"track_rms_{j + 1}": f"track_rms_{j + 1} [{length}]" for j in range(n)},
        "v_s": "v_s [rad/s]", "rho_norm": "rho_norm [N m]", "output_error": "output_error [N m]"})
    tab = T.make_table(shown, "tab-didim-history", "Gauss-Newton steps", labels=labels,
                       formats={"rel_error_percent": "num", "max_rel_param_change": "num"},
                       csv_frame=history_csv)
    track = pd.DataFrame({f"track_rms_{j + 1}": col(f"track_rms_{j + 1}", 1e3) for j in range(n)},
                         index=steps)
    kd = pd.DataFrame({f"kd_scale_{j + 1}": col(f"kd_scale_{j + 1}") for j in range(n)}, index=steps)
    tab_track = T.make_table(track, "tab-didim-tracking",
                             "RMS tracking error of each step's simulation, q\u1d63 \u2212 q_sim [mrad]",
                             labels={f"track_rms_{j + 1}": f"j{j + 1} [mrad]" for j in range(n)},
                             prismatic=bool(prismatic_of(res)))
    tab_kd = T.make_table(kd, "tab-didim-kd-scale",
                          "Derivative-gain factors kd_scale = J\u0302\u2c7c / J_ap\u2c7c of each step's "
                          "simulation", labels={f"kd_scale_{j + 1}": f"j{j + 1}" for j in range(n)})
    return Section("didim-convergence", "DIDIM convergence", body, figures=[fig],
                   tables=[tab, tab_track, tab_kd])


def _model_of(res):
    return res.essential.result if res.essential is not None else res.result


def _table2_section(res, reference):
    m = _model_of(res)
    which = "essential" if res.essential is not None else "base"
    published = reference is not None      # the Table 2 layout only beside a published table
    tab = T.table2_layout(m.names, m.chi, m.rel_std.to_numpy(), reference, res.base.names,
                          key="tab-didim-table2",
                          caption=(f"DIDIM {which} parameters in the layout of Table 2" if published else
                                   f"DIDIM {which} parameters: value and %\u03c3"),
                          ours_label="dynid DIDIM", prismatic=prismatic_of(res))
    ref_map = reference.rel_std_map() if reference is not None else None
    fig = F.rel_std_bar_figure(m.names, m.rel_std.to_numpy(), ref_map, key="fig-didim-rel-std",
                               ours_label="dynid DIDIM")
    if reference is not None:
        body = join(
            para(f"The {len(m.names)} {which} parameters of the last DIDIM step (per-joint WLS), beside "
                 f"{reference.title} ({reference.method})."),
            para(reference.citation, ". ", reference.note, cls="hint"),
        )
    else:
        body = para(f"The {len(m.names)} {which} parameters of the last DIDIM step (per-joint WLS).")
    return Section("didim-table2", "DIDIM parameters (Table 2)" if published else "DIDIM parameters", body,
                   figures=[fig], tables=[tab], tables_first=True)


def _torque_section(res, reference):
    n = res.tau_dec.shape[1]
    names = joint_names_of(res, n)
    fig = F.torque_figure(res.t_dec, res.tau_dec, res.tau_est_dec, names, key="fig-didim-torque",
                          caption="Actual torque Y(\u03c4) (red) and the torque of the identified model "
                                  "on the simulated motion, W\u03b4(q_ddm, q\u0307_ddm, q\u0308_ddm, "
                                  "\u03c7\u0302)\u03c7\u0302 (blue), at the decimated rate (Fig. 6)",
                          labels=("actual Y(\u03c4)", "DIDIM W\u03b4\u03c7\u0302"),
                          mask=res.row_mask)
    r = res.result
    df = pd.DataFrame({"rms": np.asarray(r.rms, dtype=float),
                       "rel_error_percent": 100 * np.asarray(r.joint_rel_error, dtype=float)},
                      index=pd.Index(np.arange(1, n + 1), name="j"))
    tab = T.make_table(df, "tab-didim-torque-errors", "Per-joint residual of the DIDIM estimate "
                       "(last step, equations used)",
                       labels={"rms": "RMS residual [N m]", "rel_error_percent": "relative error [%]"},
                       prismatic=bool(prismatic_of(res)),
                       formats={"rel_error_percent": "num"})
    text = (f"Relative error norm \u2016Y \u2212 W\u03b4\u03c7\u0302\u2016/\u2016Y\u2016 of the last step: "
            f"{_pct(r.rel_error)}"
            + (f" (essential model {_pct(res.essential.result.rel_error)})" if res.essential else "")
            + ".")
    if reference is not None and "rel_error_below" in reference.settings:
        text += (f" The paper reports below {_pct(reference.settings['rel_error_below'], 0)} for "
                 "IDIM-LS and DIDIM.")
    return Section("didim-torques", "DIDIM: actual vs estimated torque", para(text), figures=[fig],
                   tables=[tab])


def _trajectory_section(res):
    n = res.q_sim.shape[1]
    names = joint_names_of(res, n)
    fig_q = trajectory_figure(res.t, res.qr, res.q_sim, names, key="fig-didim-trajectories")
    fig_e = trajectory_figure(res.t, res.qr, res.q_sim, names, key="fig-didim-tracking", error=True)
    rms = res.tracking_rms
    body = para("The last closed-loop simulation (with the estimate of the step before the last) against "
                "the reference it tracked. DIDIM's Jacobian approximation (eq. (21)) holds when this "
                "simulated motion is close to the actual one; the tracking error RMS per joint, over the "
                "identification samples, is "
                + ", ".join(f"j{j + 1} {1e3 * v:.3g}" for j, v in enumerate(rms)) + " mrad.")
    return Section("didim-trajectories", "DIDIM: simulated vs reference trajectory", body,
                   figures=[fig_q, fig_e])


def _comparison_section(res, idim):
    dm, im = _model_of(res), idim.model
    order = list(res.base.names)
    names = [n for n in order if n in dm.names or n in im.names]
    rows = []
    for name in names:
        d = dm[name] if name in dm.names else (math.nan, math.nan)
        i = im[name] if name in im.names else (math.nan, math.nan)
        diff = d[0] - i[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = 100 * diff / abs(i[0]) if i[0] else math.nan
            in_sigma = diff / math.hypot(d[1], i[1]) if (d[1] > 0 or i[1] > 0) else math.nan
        rows.append({"parameter": name, "idim": i[0], "idim_rel_std": 100 * i[1] / abs(i[0]) if i[0] else math.nan,
                     "didim": d[0], "didim_rel_std": 100 * d[1] / abs(d[0]) if d[0] else math.nan,
                     "difference_percent": rel, "difference_sigma": in_sigma})
    df = pd.DataFrame(rows).set_index("parameter")
    tab = T.make_table(df, "tab-didim-vs-idim", "DIDIM and IDIM estimates (essential models)",
                       labels={"idim": "IDIM \u03c7\u0302", "idim_rel_std": "IDIM %\u03c3",
                               "didim": "DIDIM \u03c7\u0302", "didim_rel_std": "DIDIM %\u03c3",
                               "difference_percent": "DIDIM \u2212 IDIM [% of IDIM]",
                               "difference_sigma": "difference [\u03c3 combined]"},
                       formats={"difference_percent": "num", "difference_sigma": "num"})
    both = df.dropna(subset=["idim", "didim"])
    worst = both["difference_sigma"].abs().max() if len(both) else math.nan
    body = join(
        para(f"{len(both)} parameters are in both essential sets, {int(df['idim'].isna().sum())} only in "
             f"DIDIM's, {int(df['didim'].isna().sum())} only in IDIM's. Relative error norm: DIDIM "
             f"{_pct(dm.rel_error)}, IDIM {_pct(im.rel_error)}. Largest difference "
             f"{T.format_number(worst, 3)} combined standard deviations."),
        para("IDIM uses the measured positions (filtered and differentiated); DIDIM only the torques, the "
             "reference and the controller. The paper finds both very close (section 5). A difference "
             "many \u03c3 wide means one of the two models of the data is wrong: for DIDIM, typically "
             "a simulated loop that does not reproduce the actual one (controller gains, a-priori "
             "inertia J_ap, gain update), for IDIM the filtering of q.", cls="hint"),
    )
    return Section("didim-vs-idim", "DIDIM vs IDIM", body, tables=[tab])


def didim_sections(didim_result, idim_result=None, *, reference="auto"):
    """Report sections of a `dynid.analysis.estimators.didim.DIDIMResult` (ids `SECTION_IDS`).

    `idim_result` (an `dynid.analysis.estimators.idim.IDIMResult` of the same recording) adds
    the DIDIM-vs-IDIM table. `reference`: a `dynid.reports.paper.ReferenceTable`,
    `None`, or `"auto"` (the published table for the robot, if any).
    """
    if isinstance(reference, str) and reference == "auto":
        reference = reference_for(didim_result.robot_name)
    sections = [
        convergence_section(didim_result),
        _table2_section(didim_result, reference),
        _torque_section(didim_result, reference),
        _trajectory_section(didim_result),
    ]
    if idim_result is not None:
        sections.append(_comparison_section(didim_result, idim_result))
    return sections


def _uncertainty_label(res):
    """Which covariance the DIDIM sigma is (the last step's WLS), and whether the gains' is in it."""
    settings = getattr(getattr(res, "result", None), "settings", None) or {}
    unc = settings.get("least_squares", {}).get("uncertainty", {})
    label = unc.get("covariance") or "classic, eq. (14)"
    if "controller_gains" in unc:
        label += "; with the identified controller gains' covariance propagated through the loop"
    return label
