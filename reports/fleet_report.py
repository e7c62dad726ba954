"""The fleet report: which robots alarm and since when, their friction trends, and every result.

One self-contained HTML page through the project's template (`reports/html.py`):
a fleet overview (robots in alarm with the day of onset, failed recordings), the
alarms table, per-robot trend plots (the temperature-compensated parameter, its
±2σ band of day-to-day scatter, the baseline, the alarm's onset and day marked)
and a table of every robot; the tables sort on a click on their header (a few
lines of inline script, no external file). Plus the same as JSON.
"""
from __future__ import annotations

import json
import os

import matplotlib
import pandas as pd
from markupsafe import Markup

from dynid.outputs import write_all
from dynid.provenance import json_safe
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import Section, bullets, para, render_sections

#: most robots drawn in the trends section (alarming ones first)
MAX_TREND_ROBOTS = 12

# click a header to sort its table (numbers as numbers); inline, so the page stays one file
_SORT_SCRIPT = Markup("""<script>
document.querySelectorAll("table.sortable").forEach(function (t) {
  t.querySelectorAll("thead tr:last-child th").forEach(function (th, i) {
    th.style.cursor = "pointer"; th.title = "sort";
    th.addEventListener("click", function () {
      var body = t.tBodies[0], rows = Array.from(body.rows), asc = th.dataset.dir !== "asc";
      th.dataset.dir = asc ? "asc" : "desc";
      function key(r) { var s = r.cells[i].textContent.trim(), v = parseFloat(s.replace(/[^0-9eE+.\\-]/g, ""));
                        return isNaN(v) || /[a-zA-Z]{2}/.test(s.replace(/e[+-]?\\d/, "")) ? s : v; }
      rows.sort(function (a, b) { var x = key(a), y = key(b);
        var c = (typeof x === typeof y) ? (x < y ? -1 : x > y ? 1 : 0) : (typeof x === "number" ? -1 : 1);
        return asc ? c : -c; });
      rows.forEach(function (r) { body.appendChild(r); });
    });
  });
});
</script>""")


def _trend_figure(hist, alarms, robot_id, key):
    names = sorted(hist["parameter"].unique(), key=lambda n: (int("".join(c for c in n if c.isdigit()) or 0), n))
    rows, cols = F.grid_shape(len(names), 2)
    with matplotlib.rc_context(F.STYLE):
        fig = F._new_figure(7.2, 1.9 * rows)
        axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
        for ax, name in zip(axes.flat, names):
            h = hist[hist["parameter"] == name]
            x = pd.to_datetime(h["timestamp"]).dt.tz_convert(None)
            y = h["compensated"].to_numpy()
            band = 2 * h["scatter"].to_numpy()
            ax.fill_between(x, y - band, y + band, color="#9ecae1", alpha=0.5, lw=0, label="±2σ")
            ax.plot(x, y, "o-", ms=2.5, color="#08519c", label="identified (T-compensated)")
            ax.axhline(float(h["baseline_value"].iloc[0]), color="#636363", lw=0.7, ls="--", label="baseline")
            for a in alarms:
                if a.robot_id == robot_id and a.parameter == name:
                    ax.axvline(pd.Timestamp(a.onset_day), color="#e6550d", lw=1.0, label="onset")
                    ax.axvline(pd.Timestamp(a.alarm_day), color="#a50f15", lw=1.0, ls=":", label="alarm")
            ax.set_title(F._plain(name), fontsize=8)
            ax.tick_params(axis="x", labelrotation=30, labelsize=6)
        for ax in list(axes.flat)[len(names):]:
            ax.set_visible(False)
        axes.flat[0].legend(fontsize=6, loc="best")
    return F.render_figure(fig, key, f"Robot {robot_id}: identified friction over time", fmt="svg")


def robot_table(frame: pd.DataFrame, health) -> pd.DataFrame:
    """One row per robot: recordings, failed ones, latest monitored values, alarm and onset."""
    rec = frame.drop_duplicates("key")
    out = rec.groupby("robot_id").agg(recordings=("key", "size"), failed=("status", lambda s: int((s != "ok").sum())),
                                      first_day=("day", "min"), last_day=("day", "max"))
    latest = (health.history.sort_values("timestamp").groupby(["robot_id", "parameter"])["compensated"].last()
              .unstack())
    out = out.join(latest)
    onset = health.alarming_robots()
    out["alarm since"] = [onset.get(r, "") for r in out.index]
    out["alarms"] = [", ".join(f"{a.parameter} {a.direction} {100 * a.rel_size:+.0f} %" for a in health.alarms
                               if a.robot_id == r) for r in out.index]
    return out


def fleet_sections(run, frame, health):
    alarms = health.alarms
    onset = health.alarming_robots()
    errors = frame[frame["status"] != "ok"].drop_duplicates("key")
    n_rec = frame["key"].nunique()
    overview = [para(f"{frame['robot_id'].nunique()} robots, {n_rec} recordings in the store "
                     f"({len(errors)} failed). This run computed {run.n_computed} and reused {run.n_skipped}."),
                para(f"{len(onset)} robot(s) in alarm: " + (", ".join(f"{r} since {d}" for r, d in onset.items())
                                                           or "none") + ".")] + [para(n) for n in run.notices]
    overview.append(para(f"Monitored: {', '.join(health.settings['parameters'])}; two-sided CUSUM (Page 1954), "
                         f"threshold h = {health.threshold:.2f} for a false-alarm rate of "
                         f"{health.settings['false_alarm_rate']:.2g} per series and recording; baseline: the first "
                         f"{health.settings['n_baseline']} recordings of each robot. Temperature coefficients (1/K): "
                         + ", ".join(f"{k} {v:.4f}" for k, v in health.temperature_coefficients.items()) + "."))
    tables = []
    if onset:
        df = pd.DataFrame([a.to_dict() for a in alarms]).set_index("robot_id")
        df["rel_size"] = 100 * df["rel_size"]
        tables.append(T.make_table(df[["joint", "parameter", "direction", "onset_day", "alarm_day", "size", "unit",
                                       "rel_size", "baseline", "statistic"]],
                                   "tab-alarms", "Alarms (one per robot, joint and parameter; size and baseline "
                                   "in the unit given, statistic in units of the scatter)",
                                   labels={"rel_size": "size, %"}, formats={"unit": "text"}, cls="sortable"))
    if len(errors):
        e = errors[["robot_id", "day", "recording", "error"]].set_index("robot_id")
        tables.append(T.make_table(e, "tab-errors", "Recordings that failed (the rest of the fleet went on)",
                                   cls="sortable"))
    sections = [Section(id="fleet-overview", title="Fleet overview", html_body=Markup("").join(overview),
                        tables=tables, tables_first=True)]
    hist = health.history
    order = list(onset) + [r for r in sorted(hist["robot_id"].unique()) if r not in onset]
    figs = [_trend_figure(hist[hist["robot_id"] == r], alarms, r, f"fig-trend-{T.slug(r)}")
            for r in order[:MAX_TREND_ROBOTS]]
    note = (f"The first {MAX_TREND_ROBOTS} robots (alarming ones first); the JSON and the store hold every one."
            if len(order) > MAX_TREND_ROBOTS else "")
    sections.append(Section(id="trends", title="Trends", figures=figs,
                            html_body=bullets(["the band is ±2σ of the day-to-day scatter (model σ × the fleet's "
                                               "scatter ratio)", "orange: onset of the change; dotted: alarm"] +
                                              ([note] if note else []))))
    sections.append(Section(id="robots", title="Robots", tables=[
        T.make_table(robot_table(frame, health), "tab-robots", "Every robot (click a header to sort)",
                     cls="sortable")]))
    return sections


def fleet_json(run, frame, health) -> dict:
    frame = run.current(frame)
    out = run.to_dict()
    out["robots"] = json_safe(robot_table(frame, health).reset_index().to_dict("records"))
    return out


def write_fleet_outputs(run, frame, *, html=None, json_path=None) -> list:
    """Write the fleet report (`html`) and/or its JSON (`json_path`) atomically; returns the paths."""
    health = run.health
    frame = run.current(frame)
    outputs = []
    if html is not None:
        page = render_sections(fleet_sections(run, frame, health), title="dynid fleet report",
                               subtitle=f"store {run.store}",
                               highlights=[("robots", str(frame["robot_id"].nunique())),
                                           ("recordings", str(frame["key"].nunique())),
                                           ("in alarm", str(len(health.alarming_robots())))])
        page = page.replace("</body>", _SORT_SCRIPT + "\n</body>", 1)
        outputs.append((os.fspath(html), page.encode("utf-8")))
    if json_path is not None:
        text = json.dumps(fleet_json(run, frame, health), indent=1, allow_nan=False)
        outputs.append((os.fspath(json_path), text.encode("utf-8")))
    write_all(outputs)
    return [p for p, _ in outputs]
