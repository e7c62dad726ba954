"""Report sections of the Bona & Curatella (2005) analyses: excitation and noise PDFs.

`excitation_section` shows an optimised excitation
(`dynid.dynamics.excitation.ExcitationResult`): the trajectory over one
period normalised by the limits, its spectrum (lines at `k f0` only, section
3.3), the condition numbers before and after the optimisation (eq. (20)), the
limit margins and the Fourier coefficients. `noise_section` shows the
noise PDFs of period-averaged data (section 3.4, Fig. 5): per joint, the
histogram of the torque noise (and of the position noise, side by side as in
Fig. 5) with the fitted normal density and a KDE, the normality tests, the
torque-vs-position comparison and, when given, the averaging's numbers.

Both return `dynid.reports.html.Section` objects for
`dynid.reports.html.render_sections` or the `extra_sections` of
`dynid.reports.html.render_idim_report`.
"""
from __future__ import annotations

import matplotlib
import numpy as np
import pandas as pd
from markupsafe import Markup

from dynid.analysis.units import prismatic_joints
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import Section, bullets, join, kv_list, para

__all__ = ["excitation_section", "noise_section", "excitation_figures", "noise_pdf_figure"]


def _fmt(x, digits=4):
    return T.format_number(x, digits)


# ------------------------------------------------------------------ excitation
def _trajectory_figure(res, robot, key):
    tr = res.trajectory
    q_min, q_max, qd_max, qdd_max, _ = robot.limits()
    mid, half = 0.5 * (q_min + q_max), 0.5 * (q_max - q_min)
    t = np.linspace(0.0, tr.period, 1001)
    q, qd, qdd = tr.evaluate(t)
    qs, _, _ = res.start_trajectory.evaluate(t)
    n = tr.n_joints
    with np.errstate(invalid="ignore", divide="ignore"):
        uq = (q - mid) / half
        us = (qs - mid) / half
        ud = qd / qd_max
        ua = qdd / qdd_max
    with matplotlib.rc_context(F.STYLE):
        rows, cols = F.grid_shape(n)
        fig = F._new_figure(3.3 * cols, 1.9 * rows + 0.4)
        axes = fig.subplots(rows, cols, squeeze=False, sharex=True, sharey=True)
        for j in range(rows * cols):
            ax = axes.flat[j]
            if j >= n:
                ax.set_visible(False)
                continue
            if np.all(np.isfinite(us[:, j])):
                ax.plot(t, us[:, j], color=F.GREY, lw=0.7, ls=":", label="q, best random start")
            for u, color, label in ((uq, F.BLUE, "q"), (ud, F.RED, "qd"), (ua, F.GREEN, "qdd")):
                if np.all(np.isfinite(u[:, j])):
                    ax.plot(t, u[:, j], color=color, lw=0.9, label=label)
            for y in (-1.0, 1.0):
                ax.axhline(y, color="black", lw=0.6)
            for y in (-res.margin, res.margin):
                ax.axhline(y, color=F.GREY, lw=0.6, ls="--")
            ax.set_ylim(-1.1, 1.1)
            ax.set_title(F._plain(F.joint_label(j, robot.joint_names[j])), loc="left")
            if j % cols == 0:
                ax.set_ylabel("fraction of the limit")
            if j >= n - cols:
                ax.set_xlabel("time [s]")
                ax.tick_params(labelbottom=True)
        handles, texts = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside upper right", ncols=4, frameon=False)
    caption = (f"Optimised excitation over one period ({tr.period:g} s): position about the centre "
               "of the range over the half range (blue), velocity over qd_max (red), acceleration "
               "over qdd_max (green); dashed: the design margin, solid: the limits; dotted grey: "
               "position of the best random start")
    return F.render_figure(fig, key, caption)


def _spectrum_figure(res, robot, key):
    sp = res.spectrum
    freqs, amp = sp["freqs"], sp["amplitude"]
    n = amp.shape[0]
    kmax = min(amp.shape[1], 2 * res.harmonics + 2)
    with matplotlib.rc_context(F.STYLE):
        fig = F._new_figure(7.6, 2.8)
        ax = fig.subplots()
        width = 0.8 * res.f0 / max(n, 1)
        floor = max(float(amp.max()) * 1e-12, 1e-300) if amp.size else 1e-12
        colors = matplotlib.colormaps["tab10"]
        for j in range(n):
            a = np.maximum(amp[j, :kmax], floor)
            ax.bar(freqs[:kmax] + (j - (n - 1) / 2) * width, a, width=width, color=colors(j % 10),
                   label=F._plain(F.joint_label(j, robot.joint_names[j])), bottom=0)
        F.log_scale(ax)
        ax.set_ylim(floor, float(amp.max()) * 3 if amp.size else 1)
        ax.axvline(sp["bandwidth"], color=F.GREY, ls="--", lw=0.8)
        ax.annotate(f"bandwidth N f0 = {sp['bandwidth']:g} Hz", xy=(sp["bandwidth"], 1.0),
                    xycoords=("data", "axes fraction"), xytext=(4, -2), textcoords="offset points",
                    va="top", fontsize=7, color=F.GREY)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("amplitude of q [rad]")
        ax.legend(loc="upper right", frameon=False, ncols=3)
    caption = (f"Amplitude spectrum of the reference positions over one period (FFT bin k = k f0): "
               f"lines at {', '.join(_fmt(f, 3) for f in sp['lines'])} Hz; largest component off "
               f"the lines {sp['off_grid']:.1e} of the largest line (log scale)")
    return F.render_figure(fig, key, caption)


def _cond_figure(res, key):
    c, cs = res.conditioning, res.start_conditioning
    labels = ["envelope-scaled", "raw (SI)", "unit columns"]
    keys = ["cond", "cond_raw", "cond_unit"]
    with matplotlib.rc_context(F.STYLE):
        fig = F._new_figure(7.6, 2.8)
        ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.2, 1])
        x = np.arange(len(keys))
        ax1.bar(x - 0.2, [cs[k] for k in keys], width=0.4, color=F.GREY, label="best random start")
        ax1.bar(x + 0.2, [c[k] for k in keys], width=0.4, color=F.BLUE, label="optimised")
        ax1.set_xticks(x, labels)
        F.log_scale(ax1)
        ax1.set_ylabel("condition number")
        ax1.legend(loc="upper left", frameon=False)
        ax1.grid(axis="x", visible=False)
        runs = res.runs
        xr = np.arange(len(runs))
        ax2.bar(xr - 0.2, [r["cond_start"] for r in runs], width=0.4, color=F.GREY, label="start")
        ax2.bar(xr + 0.2, [r["cond_result"] for r in runs], width=0.4,
                color=[F.BLUE if r["feasible"] else F.RED for r in runs], label="after SLSQP")
        ax2.set_xticks(xr, [str(r["start"] + 1) for r in runs])
        ax2.set_xlabel("random start")
        F.log_scale(ax2)
        ax2.set_title(F._plain(res.cond_name), loc="left")
        ax2.legend(loc="upper right", frameon=False)
        ax2.grid(axis="x", visible=False)
    caption = (f"Condition number of the base regressor over one period ({res.n_samples} samples): "
               f"best random start vs optimised excitation for the three scalings (left, log scale), "
               f"and every start before and after the optimisation (right; red: failed the dense "
               f"limit check)")
    return F.render_figure(fig, key, caption)


def excitation_figures(res, robot, *, prefix="fig-excitation"):
    """The three figures of `excitation_section` (trajectory, spectrum, cond)."""
    return [_trajectory_figure(res, robot, f"{prefix}-trajectory"),
            _spectrum_figure(res, robot, f"{prefix}-spectrum"),
            _cond_figure(res, f"{prefix}-cond")]


def excitation_section(res, robot, *, id="excitation", title="Optimal excitation (Bona & Curatella 2005)"):
    """A `Section` for an `ExcitationResult`."""
    tr = res.trajectory
    pairs = [
        ("Trajectory", f"finite Fourier series, eqs. (17)\u2013(19): f0 = {_fmt(tr.f0)} Hz, "
                       f"{tr.harmonics} harmonics, period {_fmt(tr.period)} s, bandwidth "
                       f"{_fmt(tr.bandwidth)} Hz"),
        ("Criterion", f"{res.criterion} of the base regressor (eq. (20)); reported: {res.cond_name}"),
        ("Result", f"{_fmt(res.cond_result)} vs {_fmt(res.cond_start)} for the best of "
                   f"{len(res.cond_starts)} random feasible starts ({res.improvement_text()})"),
        ("Limits", f"{'all respected' if res.feasible else 'VIOLATED'} on {res.n_check} points per "
                   f"period (design margin {res.margin:g}); {res.torque_text()}"),
        ("Spectrum", f"lines only at k f0, k \u2264 {tr.harmonics}" if res.spectrum["ok"]
         else "components outside k f0, k \u2264 N"),
        ("Time", f"{res.elapsed:.1f} s"),
    ]
    body = [kv_list(pairs),
            para("cond(W S\u207b\u00b9): the base regressor with every column divided by its RMS over "
                 "states drawn uniformly in the robot's limit box (a fixed scaling: independent of "
                 "the parameters' units); raw: W in SI units, as in the paper; unit columns: W with "
                 "columns of unit norm for this trajectory (collinearity only).", cls="hint")]
    if res.notices:
        body += [Markup("<h3>Notices</h3>"), bullets(res.notices, cls="notices")]
    m = res.margins.copy()
    prismatic = bool(prismatic_joints(robot))
    labels = {"q_low": "q min margin", "q_high": "q max margin", "qd": "qd margin",
              "qdd": "qdd margin", "tau": "\u03c4 margin", "q_min_reached": "min q [rad]",
              "q_max_reached": "max q [rad]", "qd_peak": "max |qd| [rad/s]", "qdd_peak": "max |qdd| [rad/s\u00b2]",
              "tau_peak": "max |\u03c4| [N m]"}
    t_marg = T.make_table(m, f"tab-{id}-margins",
                          "Relative margin to each limit on the dense grid (1 \u2212 peak / limit, "
                          "dimensionless; for q: distance to the bound over the half range; negative = "
                          "violated)", labels=labels, prismatic=prismatic)
    names = list(res.joint_names)
    coef = {"q0": tr.q0}
    for k in range(tr.harmonics):
        coef[f"a{k + 1}"] = tr.a[:, k]
    for k in range(tr.harmonics):
        coef[f"b{k + 1}"] = tr.b[:, k]
    cdf = pd.DataFrame(coef, index=pd.Index(names, name="joint"))
    t_coef = T.make_table(cdf, f"tab-{id}-coefficients",
                          "Fourier coefficients (eq. (17): a_k, b_k velocity amplitudes in rad/s, "
                          "q0 in rad)",
                          csv_frame=cdf.rename(columns=lambda c: f"{c} [rad]" if c == "q0" else f"{c} [rad/s]"))
    runs = pd.DataFrame(res.runs).set_index("start")
    runs.index = pd.Index(runs.index + 1, name="start (1-based; JSON 0-based)")
    t_runs = T.make_table(runs, f"tab-{id}-runs", "Optimisation runs (one per random start)",
                          formats={"message": "text", "feasible": "bool", "iterations": "int",
                                   "evaluations": "int"},
                          labels={"cond_start": "cond start", "cond_result": "cond result",
                                  "criterion_value": "objective minimised", "start_shrink": "start shrink",
                                  "seconds": "time [s]"})
    return Section(id, title, join(*body), figures=excitation_figures(res, robot, prefix=f"fig-{id}"),
                   tables=[t_marg, t_coef, t_runs])


# ------------------------------------------------------------------ noise
def _pdf_axes(ax, pdf, color, unit):
    if pdf["density"].size == 0:
        ax.text(0.5, 0.5, "no spread", ha="center", va="center", transform=ax.transAxes)
        return
    edges = pdf["edges"]
    ax.stairs(pdf["density"], edges, fill=True, color="#c8d3e8", label="histogram")
    ax.plot(pdf["x"], pdf["normal"], color=F.RED, lw=1.0, label="normal fit")
    if pdf["kde"] is not None:
        ax.plot(pdf["x"], pdf["kde"], color=color, lw=1.0, ls="--", label="KDE")
    ax.set_yticks([])
    ax.grid(False)
    ax.set_xlabel(f"noise [{unit}]" if unit else "noise")


def noise_pdf_figure(tau_tests, q_tests=None, *, joint_names=None, key="fig-noise-pdf", caption=None):
    """Fig. 5 layout: per joint a row, torque noise PDF left and position noise PDF right.

    Without `q_tests`, a grid of torque-noise panels. Each panel: histogram,
    fitted normal (red), KDE (blue dashed); the primary test's p-value in the title.
    """
    names = joint_names or tau_tests.names
    n = len(tau_tests.names)
    pdf_t = tau_tests.pdf()
    pdf_q = q_tests.pdf() if q_tests is not None else None
    prim = tau_tests.primary
    with matplotlib.rc_context(F.STYLE):
        if pdf_q is not None:
            fig = F._new_figure(7.2, 1.55 * n + 0.4)
            axes = fig.subplots(n, 2, squeeze=False)
            for j in range(n):
                for c, (tests, pdf, what) in enumerate(((tau_tests, pdf_t, "torque"),
                                                       (q_tests, pdf_q, "position"))):
                    ax = axes[j, c]
                    _pdf_axes(ax, pdf[j], F.BLUE, tests.unit)
                    p = tests.table[f"{prim}_p"].iloc[j]
                    verdict = "Gaussian" if tests.table["gaussian"].iloc[j] else "not Gaussian"
                    ax.set_title(F._plain(f"{F.joint_label(j, names[j])}, {what}: "
                                          f"{F.p_equals(p)} ({verdict})"), loc="left")
        else:
            rows, cols = F.grid_shape(n)
            fig = F._new_figure(3.3 * cols, 1.9 * rows + 0.4)
            axes = fig.subplots(rows, cols, squeeze=False)
            for j in range(rows * cols):
                ax = axes.flat[j]
                if j >= n:
                    ax.set_visible(False)
                    continue
                _pdf_axes(ax, pdf_t[j], F.BLUE, tau_tests.unit)
                p = tau_tests.table[f"{prim}_p"].iloc[j]
                ax.set_title(F._plain(f"{F.joint_label(j, names[j])}: {F.p_equals(p)}"), loc="left")
        handles, texts = fig.axes[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="outside upper right", ncols=3, frameon=False)
    if caption is None:
        caption = ("PDF of the measurement noise per joint (layout of Fig. 5 of Bona & Curatella "
                   "2005" + (": torque left, position right" if pdf_q is not None else "") +
                   "): histogram, fitted normal density (red), Gaussian KDE (blue, dashed); "
                   f"{prim.replace('_', '-')} p-value and verdict in the titles")
    return F.render_figure(fig, key, caption)


def _tests_table(tests, key):
    tab = tests.table.copy()
    cols = ["n", "mean", "std", "skew", "excess_kurtosis", "jarque_bera_p", "shapiro_p", "anderson_p",
            "lilliefors_p", "gaussian"]
    tab = tab[[c for c in cols if c in tab.columns]]
    unit = f" [{tests.unit}]" if tests.unit else ""
    return T.make_table(tab, key, f"Normality tests of the {tests.label} ({tests.rule_text()})",
                        formats={"gaussian": "bool", "n": "int"},
                        labels={"mean": f"mean{unit}", "std": f"\u03c3{unit}", "excess_kurtosis": "excess kurtosis",
                                "jarque_bera_p": "Jarque-Bera p", "shapiro_p": "Shapiro-Wilk p",
                                "anderson_p": "Anderson-Darling p", "lilliefors_p": "Lilliefors p"},
                        csv_frame=tests.table)


def noise_section(tau_tests, q_tests=None, *, comparison=None, averaging=None, joint_names=None,
                  id="noise", title="Measurement noise PDFs (Bona & Curatella 2005, Fig. 5)"):
    """A `Section` for `NoiseTests` of torque (and position) noise.

    `comparison`: `NoiseComparison`; `averaging`:
    `AveragedPeriods` (its M, P and sigma table are shown).
    """
    names = joint_names or tau_tests.names
    body = []
    if averaging is not None:
        pairs = [("Periods averaged", f"{averaging.n_periods} of {_fmt(averaging.period)} s "
                                      f"({averaging.samples_per_period} samples at {_fmt(averaging.fs)} Hz)"),
                 ("Noise samples", "each period minus the average, \u00d7 \u221a(M/(M\u22121)): "
                                   "their \u03c3 estimates the single-measurement noise; the average's "
                                   "noise is \u03c3/\u221aM")]
        body.append(kv_list(pairs))
        if averaging.notices:
            body.append(bullets(averaging.notices, cls="notices"))
    gauss = int(np.sum(tau_tests.gaussian == True))  # noqa: E712  (None for untestable joints)
    text = (f"{tau_tests.label.capitalize()}: {gauss} of {len(tau_tests.names)} joints Gaussian "
            f"({tau_tests.rule_text()}).")
    if q_tests is not None:
        gq = int(np.sum(q_tests.gaussian == True))  # noqa: E712
        text += f" {q_tests.label.capitalize()}: {gq} of {len(q_tests.names)}."
    body.append(para(text))
    if comparison is not None:
        dom = comparison.dominant
        nt = sum(d == "torque" for d in dom)
        how = ("in torque units (position noise times the sensitivity)" if comparison.mode == "sensitivity"
               else "as signal-to-noise ratios (the noise of the lower SNR dominates)")
        body.append(para(f"Torque noise dominates on {nt} of {len(dom)} joints, compared {how}"
                         + ("; the position noise can be neglected, as in the paper." if nt == len(dom)
                            else ".")))
    figs = [noise_pdf_figure(tau_tests, q_tests, joint_names=names, key=f"fig-{id}-pdf")]
    tables = [_tests_table(tau_tests, f"tab-{id}-tau-tests")]
    if q_tests is not None:
        tables.append(_tests_table(q_tests, f"tab-{id}-q-tests"))
    if comparison is not None:
        labels = {"sigma_tau": "\u03c3 \u03c4", "sigma_q": "\u03c3 q", "sensitivity": "sensitivity",
                  "sigma_q_equiv": "\u03c3 q \u00d7 sensitivity", "ratio": "\u03c3 \u03c4 / (\u03c3 q \u00d7 s)",
                  "snr_tau": "SNR \u03c4", "snr_q": "SNR q", "snr_tau_db": "SNR \u03c4 [dB]",
                  "snr_q_db": "SNR q [dB]"}
        tables.append(T.make_table(comparison.table, f"tab-{id}-comparison",
                                   "Torque noise vs position noise per joint",
                                   formats={"dominant": "text"}, labels=labels))
    if averaging is not None:
        rows = {}
        for k in averaging.sigma:
            rows[f"sigma_{k}"] = averaging.sigma[k]
            rows[f"sigma_mean_{k}"] = averaging.sigma_mean[k]
        n = len(next(iter(averaging.sigma.values())))
        idx = names if len(names) == n else [f"j{k + 1}" for k in range(n)]
        tables.append(T.make_table(pd.DataFrame(rows, index=pd.Index(idx, name="joint")),
                                   f"tab-{id}-averaging",
                                   f"Noise \u03c3 of one measurement and of the average of "
                                   f"{averaging.n_periods} periods (\u03c3/\u221aM)"))
    return Section(id, title, join(*body), figures=figs, tables=tables)
