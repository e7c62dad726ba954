"""The HTML section of a payload identification or a drive-gain identification (issue 28).

`payload_html(result)` turns a PayloadResult or a DriveGainResult into one standalone HTML
page holding one section: the verdict, the parameter table with units and 95 % intervals and,
for a payload, the constrained fit beside the free one.
"""
from __future__ import annotations

import html

import numpy as np

__all__ = ["payload_section", "payload_html"]


def _num(x, digits=6):
    x = float(x)
    return "n/a" if not np.isfinite(x) else f"{x:.{digits}g}"


def _table(head, rows):
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def payload_section(result) -> str:
    """The section (an HTML fragment) of a payload or drive-gain result."""
    ci = result.conf_int().to_numpy()
    bse = result.bse.to_numpy()
    parts = [f"<section class='payload'><h2>{html.escape(result.method)}</h2>",
             f"<p><b>Verdict:</b> {html.escape(result.verdict())}</p>"]
    if result.method == "drive-gains":
        rows = [(j, _num(gf), _num(v), _num(s, 3), f"{m:+.3f}", _num(lo), _num(hi))
                for j, gf, v, s, m, (lo, hi) in zip(result.joints, result.g_file, result.chi, bse,
                                                    result.moved_percent, ci)]
        parts.append(_table(["joint", "file gain", "identified gain", "sigma", "moved (%)", "95 % lower",
                             "95 % upper"], rows))
    else:
        from dynid.analysis.estimators.payload import UNITS
        rows = [(nm, _num(v), _num(s, 3), _num(lo), _num(hi), u)
                for nm, v, s, (lo, hi), u in zip(result.names, result.chi, bse, ci, UNITS)]
        parts.append(_table(["parameter", "value", "sigma", "95 % lower", "95 % upper", "unit"], rows))
        c, sc = result.com, result.com_std
        parts.append("<p>Centre of mass (m): " + html.escape(", ".join(
            f"{_num(x, 5)} &plusmn; {_num(s, 2)}" for x, s in zip(c, sc))).replace("&amp;plusmn;", "&plusmn;")
            + f" in frame {html.escape(result.frame)} (link {result.link + 1})</p>")
        if result.physical is not None:
            rows = [(nm, _num(a), _num(b)) for nm, a, b in zip(result.names, result.physical.chi, result.chi)]
            parts.append("<h3>Physically consistent (SDP) vs free</h3>"
                         + _table(["parameter", "constrained", "free"], rows)
                         + f"<p>chi^2 distance {_num(result.physical.delta, 3)}; active constraints: "
                         + html.escape(", ".join(result.physical.active) or "none") + "</p>")
    if result.notices:
        parts.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in result.notices) + "</ul>")
    parts.append("</section>")
    return "\n".join(parts)


def payload_html(result) -> str:
    """A standalone HTML page with `payload_section`."""
    return ("<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>dynid payload</title>"
            "<style>body{font-family:sans-serif;max-width:60em;margin:auto}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}</style></head><body>\n"
            + payload_section(result) + "\n</body></html>\n")
