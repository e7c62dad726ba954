"""The report section of a payload or drive-gain identification (issue 28).

`payload_report_section(result)` is a `dynid.reports.html.Section` for the full report
(`dynid report --payload`, `dynid.report(..., payload=...)`) and for the page of
`dynid payload --report` (`payload_html`): a verdict (identified / with reservations / not
identified, and why), the parameter table with units and 95 % intervals and, for a payload,
the constrained fit beside the free one. A payload the recording does not identify is a
section too (`payload_refusal_section`): what is not identifiable and why, instead of no
section at all.
"""
from __future__ import annotations

import html

import numpy as np
import pandas as pd
from markupsafe import Markup

from dynid.analysis.estimators.payload import UNITS
from dynid.dynamics.urdf_writer import link_consistency
from dynid.reports import tables as T
from dynid.reports.html import Section, para, render_sections

__all__ = ["payload_status", "payload_section", "payload_tables", "payload_report_section", "payload_refusal_section",
           "payload_html"]

#: the three verdicts, as the identification's (dynid.reports.html.STATUS_LEVEL)
IDENTIFIED, RESERVATIONS, NOT_IDENTIFIED = "identified", "identified with reservations", "not identified"


def _num(x, digits=6):
    x = float(x)
    return "n/a" if not np.isfinite(x) else f"{x:.{digits}g}"


def payload_status(result) -> tuple[str, list]:
    """(verdict, reasons) of a PayloadResult or DriveGainResult.

    A payload is `not identified` when the robot model does not describe the loaded recording
    (`PayloadResult.model_misfit`); `identified` when every parameter passed the identifiability checks and its
    estimate is physically consistent; `identified with reservations` when the free estimate
    is not physically consistent (the constrained one is the one to use) or a 95 % interval of
    the mass or centre of mass reaches past 10 % of the value. Drive gains are `identified` when
    every gain's 95 % half-width is below 2 % of it.
    """
    reasons = []
    if result.method == "drive-gains":
        half = 1.959963984540054 * np.asarray(result.factor_std) / np.abs(result.factor)
        for j, h in zip(result.joints, half):
            if not h < 0.02:
                reasons.append(f"gain of joint {j}: 95 % half-width {100 * h:.2g} % of its value")
        return (RESERVATIONS if reasons else IDENTIFIED), reasons
    if getattr(result, "model_misfit", False):
        return NOT_IDENTIFIED, [f"the robot model leaves {100 * result.loaded_error:.3g} % of the loaded "
                                f"recording unexplained against {100 * result.model_error:.3g} % of its own data"]
    if not link_consistency(result.chi)["consistent"]:
        reasons.append("the free estimate is not physically consistent (pseudo-inertia not positive "
                       "semidefinite): use the constrained fit" + ("" if result.physical is not None
                                                                   else " (--physical)"))
    m, sm = result.mass
    if not 1.959963984540054 * sm < 0.1 * abs(m):
        reasons.append(f"mass known to +- {1.96 * sm:.2g} kg only (95 %)")
    c, sc = result.com, result.com_std
    if not 1.959963984540054 * sc.max() < max(0.1 * float(np.linalg.norm(c)), 0.002):
        reasons.append(f"centre of mass known to +- {1e3 * 1.96 * sc.max():.2g} mm only (95 %)")
    return (RESERVATIONS if reasons else IDENTIFIED), reasons


def payload_section(result) -> str:
    """The text (an HTML fragment) of a payload or drive-gain result: the verdict and its
    reasons, the centre of mass and principal moments, the check on the loaded recording, the
    notices. The tables, with their CSV downloads, are `payload_tables`."""
    status, reasons = payload_status(result)
    parts = [f"<p><b>Verdict: {html.escape(status)}.</b> {html.escape(result.verdict())}</p>"]
    if reasons:
        parts.append("<ul>" + "".join(f"<li>{html.escape(r)}</li>" for r in reasons) + "</ul>")
    if result.method != "drive-gains":
        c, sc = result.com, result.com_std
        Ic = result.inertia_com
        parts.append("<p>Centre of mass (m): " + ", ".join(
            f"{_num(x, 5)} &plusmn; {_num(s, 2)}" for x, s in zip(c, sc))
            + f" in frame {html.escape(result.frame)} (link {result.link + 1}). Inertia about the centre "
            "of mass, principal moments (kg m&sup2;): "
            + ", ".join(_num(x, 4) for x in np.linalg.eigvalsh(0.5 * (Ic + Ic.T))) + ".</p>")
        if np.isfinite(getattr(result, "loaded_error", np.nan)):
            # the robot-fixed route's check (docs/payload.md): the robot model with the payload on the
            # loaded recording against the model on its own data
            parts.append(f"<p>Relative error of the robot model with the payload on the loaded recording "
                         f"{_num(100 * result.loaded_error, 3)} %, of the model on its own data "
                         f"{_num(100 * result.model_error, 3)} %.</p>")
    if result.notices:
        parts.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in result.notices) + "</ul>")
    return "\n".join(parts)


def payload_tables(result) -> list:
    """The `Table`s of a payload or drive-gain result, each with its CSV download: the
    parameters (value, sigma, %sigma, 95 % interval, unit) and, for a payload fitted with
    `physical=True`, the constrained fit beside the free one."""
    ci = result.conf_int().to_numpy()
    bse = result.bse.to_numpy()
    if result.method == "drive-gains":
        frame = pd.DataFrame({"file_gain": result.g_file, "gain": result.chi, "std": bse,
                              "moved_percent": result.moved_percent, "ci_lower": ci[:, 0], "ci_upper": ci[:, 1]},
                             index=pd.Index([f"g{j}" for j in result.joints], name="name"))
        labels = {"name": "gain", "file_gain": "file gain", "gain": "identified gain", "std": "\u03c3",
                  "moved_percent": "moved (%)", "ci_lower": "95 % lower", "ci_upper": "95 % upper"}
        return [T.make_table(frame, "tab-drive-gains", "Drive gains (N m per unit of the logged signal)",
                             labels=labels, formats={"moved_percent": "pct"})]
    frame = result.to_frame().assign(ci_lower=ci[:, 0], ci_upper=ci[:, 1])[
        ["value", "std", "rel_std_percent", "ci_lower", "ci_upper", "unit"]]
    labels = {frame.index.name: "parameter", "value": "value", "std": "\u03c3", "rel_std_percent": "%\u03c3",
              "ci_lower": "95 % lower", "ci_upper": "95 % upper"}
    tables = [T.make_table(frame, "tab-payload", f"Payload parameters about frame {result.frame}",
                           labels=labels, formats={"unit": "text", "rel_std_percent": "pct"})]
    if result.physical is not None:
        both = pd.DataFrame({"unit": list(UNITS), "constrained": result.physical.chi, "free": result.chi},
                            index=pd.Index(list(result.names), name="name"))
        note = (f"chi^2 distance {_num(result.physical.delta, 3)}; active constraints: "
                + (", ".join(result.physical.active) or "none"))
        tables.append(T.make_table(both, "tab-payload-physical", "Physically consistent (SDP) vs free",
                                   labels={"name": "parameter"}, formats={"unit": "text"}, note=note))
    return tables


def _title(result) -> str:
    if result.method == "drive-gains":
        return f"Drive gains of {result.robot_name} (known payload)"
    route = "robot fixed" if result.method == "payload-robot-fixed" else "global"
    return f"Payload on link {result.link + 1} ({route})"


def payload_report_section(result) -> Section:
    """The `Section` of a PayloadResult or DriveGainResult (id `payload` / `drive-gains`)."""
    sid = "drive-gains" if result.method == "drive-gains" else "payload"
    return Section(sid, _title(result), Markup(payload_section(result)), tables=payload_tables(result))


def payload_refusal_section(message, sources=()) -> Section:
    """The `Section` of a payload the recordings do not identify: the refusal, verbatim."""
    src = f" ({', '.join(map(str, sources))})" if sources else ""
    return Section("payload", "Payload", Markup(
        para(Markup("<b>Verdict: {}.</b> ").format(NOT_IDENTIFIED),
             f"The payload recording{src} does not identify the payload: {message}")))


def payload_html(result) -> str:
    """`dynid payload --report`: a page holding `payload_report_section`."""
    status, _ = payload_status(result)
    return render_sections([payload_report_section(result)], title=_title(result),
                           highlights=[("verdict", status), ("robot", result.robot_name)])
