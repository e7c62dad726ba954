"""Health monitoring of a fleet: parameter histories, temperature compensation, change alarms.

From the results store (one identified value and σ per recording and base
parameter) this module builds, per robot and joint, the history of the friction
parameters (`Fv`, `Fc` by default, plus any base parameter named),
compensates the temperature where one was logged, and runs a two-sided CUSUM
(Page 1954) on the standardised parameter. The CUSUM's threshold `h` comes
from the accepted false-alarm rate through Siegmund's approximation of the
in-control average run length (Siegmund 1985, eq. (2.57); Basseville &
Nikiforov 1993, section 5.2); the onset is the last time the statistic left
zero before the alarm, the change's size the mean shift since then (the
maximum-likelihood estimates of Basseville & Nikiforov section 2.2).

Temperature: viscous and Coulomb friction of a gearbox fall as its lubricant
warms (Bittencourt & Gunnarsson 2012, on an industrial arm), which would
hide or mimic wear. The model is `p(T) = p_ref (1 + c (T - T_ref))`
with one coefficient `c` per parameter, identified across the fleet's
history: the within-robot regression of p / mean(p) on T - mean(T) over every
robot's baseline window (where no wear is assumed), whose slope c / (1 + c d)
(d: mean temperature - T_ref) is converted back to c.

Standardisation: z = (p - baseline mean) / s, with s the recording's own σ times
one fleet-wide ratio of day-to-day scatter to σ (pooled over every baseline), or
the robot's own baseline scatter where it is larger. The threshold assumes z is
Gaussian; identified friction has heavier tails, so the measured false-alarm rate
exceeds the nominal one (about 5x on the benchmark's simulated fleet).
"""
from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.fleet.task import UNCERTAINTY as STORED_UNCERTAINTY
from dynid.analysis.results import Result
from dynid.analysis.units import parameter_unit, prismatic_joints
from dynid.dynamics.robot_file import load_robot
from dynid.errors import DynidError, InputError
from dynid.provenance import json_safe

DEFAULT_PARAMETERS = ("Fv", "Fc")
#: reference temperature of the compensated values, degrees Celsius
T_REF = 25.0
#: CUSUM allowance k, in units of the day-to-day scatter: tuned to shifts of 3 sigma (a 20 % friction
#: change is 5-7 sigma of a 9 s production recording), and less sensitive to the baseline's error
DEFAULT_ALLOWANCE = 1.5
#: recordings of each robot that make its baseline (assumed healthy)
DEFAULT_BASELINE = 8
#: false alarms accepted per monitored series and recording (ARL0 = 1 / rate)
DEFAULT_FALSE_ALARM_RATE = 1e-4
#: the largest baseline: 1000 recordings is years of daily logs; beyond it no robot is ever monitored
MAX_BASELINE = 1000
#: the smallest accepted false-alarm rate: below it the threshold exceeds any change a
#: friction parameter can show within a fleet's history
MIN_FALSE_ALARM_RATE = 1e-12


def check_monitor_options(parameters=DEFAULT_PARAMETERS, false_alarm_rate=DEFAULT_FALSE_ALARM_RATE,
                          n_baseline=DEFAULT_BASELINE) -> None:
    """Refuse monitoring options outside their range, before any work.

    Raises
    ------
    InputError
        Naming the option (`false_alarm_rate` / `--false-alarm-rate`, `n_baseline` /
        `--baseline`, `parameters` / `--parameters`) and its range.
    """
    try:
        rate = float(false_alarm_rate)
    except (TypeError, ValueError):
        rate = float("nan")
    if not (MIN_FALSE_ALARM_RATE <= rate < 0.5):
        raise InputError(f"false-alarm rate (--false-alarm-rate, false_alarm_rate=) {false_alarm_rate!r}: "
                         f"give a probability per recording in [{MIN_FALSE_ALARM_RATE:g}, 0.5), "
                         f"default {DEFAULT_FALSE_ALARM_RATE:g}")
    if isinstance(n_baseline, bool) or not isinstance(n_baseline, (int, np.integer, float)) \
            or not (3 <= n_baseline <= MAX_BASELINE) or int(n_baseline) != n_baseline:
        raise InputError(f"baseline (--baseline, n_baseline=) {n_baseline!r}: give a whole number of "
                         f"recordings from 3 to {MAX_BASELINE}, default {DEFAULT_BASELINE}")
    if isinstance(parameters, str) or not list(parameters):
        raise InputError(f"parameters (--parameters, parameters=) {parameters!r}: give a list of "
                         f"base-parameter names (Fv2) or families (Fv)")
    _matcher(parameters)


@dataclass
class Alarm:
    """A detected change of one parameter of one robot's joint."""

    robot_id: str
    joint: int
    parameter: str               # base-parameter name, e.g. "Fv2"
    direction: str               # "increase" or "decrease"
    onset_day: str               # first day of the change (CUSUM estimate)
    alarm_day: str               # day the statistic crossed the threshold
    size: float                  # mean change since the onset, in the parameter's unit
    rel_size: float              # size / baseline value
    baseline: float              # baseline value (temperature-compensated)
    statistic: float             # CUSUM value at the alarm, in units of the scatter
    unit: str = ""               # SI unit of size and baseline ("" when the robot file cannot be read again)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(repr=False)
class FleetHealth(Result):
    """What `monitor` found: the histories, the compensation and the alarms.

    A result like the others: `summary()` (also `str()`), `to_dict()`/`to_json()` (the
    `health` block of `dynid fleet --json`) and `to_frame()`/`to_csv()` (the history).
    """

    history: pd.DataFrame        # one row per (robot, parameter, recording)
    alarms: list                 # Alarm, sorted by robot, joint, parameter
    temperature_coefficients: dict    # parameter -> c (1/K), NaN when not identifiable
    threshold: float             # CUSUM threshold h (units of the scatter)
    settings: dict = field(default_factory=dict)
    scatter_ratio: dict = field(default_factory=dict)   # parameter -> day-to-day scatter / model sigma

    @property
    def n_monitored(self) -> int:
        """Series (robot x parameter) with recordings after their baseline: the ones watched."""
        return int(self.settings.get("n_monitored", 0))

    def status_line(self) -> str:
        """One line for the terminal: the alarms' count, or why there can be none."""
        if self.alarms:
            return f"{len(self.alarms)} alarm(s) on {len(self.alarming_robots())} robot(s)"
        if not self.settings.get("n_identified", 1):
            return "not monitored: no recording was identified, so no alarm can be raised"
        if not self.n_monitored:
            return (f"not monitored: no robot has more than the {self.settings.get('n_baseline')} baseline "
                    f"recordings of an identified parameter (--baseline, n_baseline=), so no alarm can be raised")
        return f"no alarm ({self.n_monitored} series monitored)"

    def alarming_robots(self) -> dict:
        """robot_id -> day of its first alarm onset."""
        out = {}
        for a in self.alarms:
            out[a.robot_id] = min(out.get(a.robot_id, a.onset_day), a.onset_day)
        return dict(sorted(out.items()))

    def summary(self) -> str:
        """The status line, the monitor's settings and one line per alarm, with units."""
        st = self.settings
        lines = [f"Fleet health: {self.status_line()}",
                 f"  CUSUM threshold h = {self.threshold:.3g} (scatter units), false-alarm rate "
                 f"{st.get('false_alarm_rate', float('nan')):g} per recording, baseline "
                 f"{st.get('n_baseline')} recordings, temperature compensation "
                 f"{'on' if st.get('compensate') else 'off'}"]
        for a in self.alarms:
            unit = f" {a.unit}" if a.unit else ""
            lines.append(f"  {a.robot_id} joint {a.joint} {a.parameter}: {a.direction} of {a.size:.4g}{unit} "
                         f"({100 * a.rel_size:+.1f} % of {a.baseline:.4g}{unit}) since {a.onset_day}, "
                         f"alarm on {a.alarm_day} (statistic {a.statistic:.3g})")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"<FleetHealth {self.status_line()}>"

    def to_frame(self) -> pd.DataFrame:
        """The history: one row per (robot, parameter, recording), with the temperature-
        compensated value, its baseline and the CUSUM statistics."""
        return self.history.copy()

    def to_dict(self) -> dict:
        return json_safe({"settings": self.settings, "threshold": self.threshold,
                          "temperature_coefficients": self.temperature_coefficients,
                          "scatter_ratio": self.scatter_ratio,
                          "alarming_robots": self.alarming_robots(),
                          "alarms": [a.to_dict() for a in self.alarms]})


def _arl(h, k, mu=0.0):
    """Siegmund's approximation of a one-sided CUSUM's average run length, N(mu, 1) data."""
    b = h + 1.166
    d = mu - k
    if abs(d) < 1e-9:
        return b * b
    return (math.expm1(-2 * d * b) + 2 * d * b) / (2 * d * d)


def cusum_threshold(false_alarm_rate: float, allowance: float = DEFAULT_ALLOWANCE,
                    n_baseline: int | None = None) -> float:
    """One-sided CUSUM threshold h whose false-alarm rate per recording is `false_alarm_rate`.

    Siegmund's approximation ARL(mu) = (exp(-2 D b) + 2 D b - 1) / (2 D^2), D = mu - k,
    b = h + 1.166 (Siegmund 1985; Basseville & Nikiforov 1993, eq. (5.2.44)). With
    `n_baseline` the reference value is a mean of that many recordings, so the
    in-control data are N(e, 1) with a persistent error e ~ N(0, 1/n): the rate
    1/ARL is averaged over e (Gauss-Hermite), which is what makes a baseline of a
    week safe (Jones, Champ & Rigdon 2004 show the ARL0 collapsing otherwise).
    """
    if not (0 < false_alarm_rate < 0.5):
        raise InputError(f"the false-alarm rate is a probability per recording in (0, 0.5), got {false_alarm_rate!r}")
    k = float(allowance)
    if not k > 0:
        raise InputError(f"the CUSUM allowance k must be positive, got {allowance!r}")
    if n_baseline:
        nodes, weights = np.polynomial.hermite_e.hermegauss(31)
        nodes, weights = nodes / math.sqrt(n_baseline), weights / weights.sum()
    else:
        nodes, weights = np.zeros(1), np.ones(1)

    def rate(h):
        return float(sum(w / _arl(h, k, e) for e, w in zip(nodes, weights)))

    lo, hi = 0.0, 1.0
    while rate(hi) > false_alarm_rate:
        hi *= 2
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if rate(mid) > false_alarm_rate else (lo, mid)
    return 0.5 * (lo + hi)


def cusum(z, allowance: float, threshold: float):
    """Two-sided CUSUM of standardised values `z` (Page 1954).

    Returns (s_up, s_down, alarm) with alarm = None or (index, side, onset index):
    the first index where one side exceeds `threshold`, `side` +1 or -1, and the
    onset, the index after the last time that side was zero.
    """
    z = np.asarray(z, dtype=float)
    up, down = np.zeros(z.size), np.zeros(z.size)
    s_u = s_d = 0.0
    start_u = start_d = 0
    alarm = None
    for t, v in enumerate(z):
        if not np.isfinite(v):       # a failed recording: the statistic holds
            up[t], down[t] = s_u, s_d
            continue
        s_u, s_d = max(0.0, s_u + v - allowance), max(0.0, s_d - v - allowance)
        if s_u == 0.0:
            start_u = t + 1
        if s_d == 0.0:
            start_d = t + 1
        up[t], down[t] = s_u, s_d
        if alarm is None and s_u > threshold:
            alarm = (t, 1, start_u)
        elif alarm is None and s_d > threshold:
            alarm = (t, -1, start_d)
    return up, down, alarm


def _matcher(parameters):
    pats = []
    for p in parameters:
        if not re.match(r"^[A-Za-z][A-Za-z0-9]*$", str(p)):
            raise InputError(f"parameter {p!r}: give a base-parameter name (Fv2) or its family (Fv)")
        pats.append(re.compile(rf"^{re.escape(p)}\d+$") if not re.search(r"\d$", p) else re.compile(rf"^{p}$"))
    return lambda name: any(pt.match(name) for pt in pats)


def _unit(robot_file, name, cache) -> str:
    """The SI unit of parameter `name` of the robot file the task identified with ("" when it
    cannot be read again: a unit guessed for the wrong joint type would be a wrong unit)."""
    if robot_file not in cache:
        try:
            cache[robot_file] = prismatic_joints(load_robot(robot_file))
        except (DynidError, OSError, TypeError):
            cache[robot_file] = None
    return "" if cache[robot_file] is None else parameter_unit(name, cache[robot_file])


def parameter_history(frame: pd.DataFrame, parameters=DEFAULT_PARAMETERS) -> pd.DataFrame:
    """The rows of the store (`ResultStore.read`) of the monitored parameters, by robot and time."""
    match = _matcher(parameters)
    ok = frame[(frame["status"] == "ok") & frame["parameter"].map(lambda n: bool(n) and match(n))]
    cols = ["robot_id", "joint", "parameter", "timestamp", "day", "recording", "value", "sigma", "temperature"]
    return ok[cols].sort_values(["robot_id", "parameter", "timestamp"], kind="stable").reset_index(drop=True)


def _baseline_mask(history, n_baseline):
    rank = history.groupby(["robot_id", "parameter"]).cumcount()
    return (rank < n_baseline).to_numpy()


def temperature_coefficients(history: pd.DataFrame, n_baseline: int = DEFAULT_BASELINE) -> dict:
    """c (1/K) per parameter, pooled within-robot regression over the baseline windows."""
    out = {}
    base = history[_baseline_mask(history, n_baseline)]
    for name, g in base.groupby("parameter"):
        g = g[np.isfinite(g["temperature"]) & np.isfinite(g["value"])]
        if g.empty:
            out[name] = float("nan")
            continue
        mean_v = g.groupby("robot_id")["value"].transform("mean")
        mean_t = g.groupby("robot_id")["temperature"].transform("mean")
        y = (g["value"] / mean_v - 1.0).to_numpy()
        x = (g["temperature"] - mean_t).to_numpy()
        sxx = float(x @ x)
        # fewer than a few kelvin of spread in total: the slope is noise
        if sxx <= 10.0 or g["robot_id"].nunique() < 2:
            out[name] = float("nan")
            continue
        # the slope s of p / mean(p) is c / (1 + c d), d = mean(T) - T_ref: relative to the mean
        # value, not to p(T_ref); undo that (exact for the linear model when d is common)
        slope = float(x @ y / sxx)
        d = float((mean_t - T_REF).mean())
        out[name] = slope / (1.0 - slope * d)
    return out


def _empty_history(hist):
    extra = ["compensated", "compensated_sigma", "baseline", "baseline_value", "baseline_count", "scatter", "z",
             "cusum_up", "cusum_down"]
    return hist.assign(**{c: pd.Series(dtype=float) for c in extra})


def monitor(frame: pd.DataFrame, parameters=DEFAULT_PARAMETERS, *, false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
            allowance: float = DEFAULT_ALLOWANCE, n_baseline: int = DEFAULT_BASELINE,
            compensate: bool = True) -> FleetHealth:
    """Histories, temperature compensation and CUSUM alarms of the store's rows `frame`.

    Parameters
    ----------
    frame : pandas.DataFrame
        The store's rows (`read_store`).
    parameters : sequence of str
        The base parameters to monitor, by family (`Fv`: every joint's) or by name (`Fv2`).
    false_alarm_rate : float
        Accepted probability of a false alarm per monitored series (robot x parameter)
        and recording, split over the two sides of the CUSUM.
    allowance : float
        The CUSUM's k in units of the scatter (tuned to shifts of 2 k).
    n_baseline : int
        The first recordings of each robot, taken as healthy, that fix its reference value
        and (pooled over the fleet) the scatter and the temperature coefficient. Series with
        fewer recordings are reported without alarms.
    compensate : bool
        Remove the fitted temperature dependence before the CUSUM.

    Returns
    -------
    FleetHealth
        Per robot and parameter: the history, the compensated series and the alarms.
    """
    check_monitor_options(parameters, false_alarm_rate, n_baseline)
    n_baseline = int(n_baseline)
    h = cusum_threshold(false_alarm_rate / 2, allowance, n_baseline)
    settings = {"parameters": list(parameters), "false_alarm_rate": false_alarm_rate, "allowance": allowance,
                "n_baseline": n_baseline, "compensate": compensate, "T_ref": T_REF,
                "uncertainty": STORED_UNCERTAINTY}     # the covariance of the store's sigma
    hist = parameter_history(frame, parameters)
    names = sorted(set(frame.loc[frame["status"] == "ok", "parameter"]) - {""})
    unknown = [p for p in parameters if names and not any(_matcher([p])(n) for n in names)]
    # a family the model lacks (Fc of a robot with viscous friction only) is fine beside others;
    # a parameter named in full, or nothing at all to watch, is a mistake
    if unknown and (len(unknown) == len(parameters) or any(re.search(r"\d$", str(p)) for p in unknown)):
        raise InputError(f"parameters (--parameters, parameters=): {', '.join(map(str, unknown))} is not a base "
                         f"parameter of the identified recordings; they have {', '.join(names)}")
    ok_rows = frame[frame["status"] == "ok"]
    by = next((c for c in ("key", "recording") if c in frame), None)
    settings["n_identified"] = int(ok_rows[by].nunique()) if by else len(ok_rows)
    if hist.empty:              # every recording failed: nothing to watch
        settings["n_monitored"] = 0
        return FleetHealth(history=_empty_history(hist), alarms=[], temperature_coefficients={}, threshold=h,
                           settings=settings, scatter_ratio={})
    coeffs = temperature_coefficients(hist, n_baseline) if compensate else {}
    c = hist["parameter"].map(lambda n: coeffs.get(n, float("nan"))).to_numpy(dtype=float)
    T = hist["temperature"].to_numpy(dtype=float)
    factor = np.where(np.isfinite(c) & np.isfinite(T), 1.0 + c * (T - T_REF), 1.0)
    hist["compensated"] = hist["value"].to_numpy() / factor
    hist["compensated_sigma"] = hist["sigma"].to_numpy() / factor
    base = _baseline_mask(hist, n_baseline)
    hist["baseline"] = base
    g = hist.groupby(["robot_id", "parameter"])["compensated"]
    mu = hist[base].groupby(["robot_id", "parameter"])["compensated"].agg(["mean", "count"])
    hist = hist.join(mu, on=["robot_id", "parameter"])
    # the day-to-day scatter: model sigma x one fleet-wide ratio per parameter (pooled over
    # every robot's baseline, so that 8 points per robot do not have to estimate a variance)
    ratios = {}
    for name, gb in hist[base].groupby("parameter"):
        dev = (gb["compensated"] - gb["mean"]).to_numpy()
        n = gb["count"].to_numpy(dtype=float)
        sig = gb["compensated_sigma"].to_numpy()
        ok = (n > 1) & (sig > 0)
        ratios[name] = float(np.sqrt(np.mean((dev[ok] / sig[ok]) ** 2 * n[ok] / (n[ok] - 1)))) if ok.any() else 1.0
    del g
    sig_ref = hist[base].groupby(["robot_id", "parameter"])["compensated_sigma"].median().rename("sigma_ref")
    hist = hist.join(sig_ref, on=["robot_id", "parameter"])
    # (the baseline mean's own error is a persistent offset, not more scatter: the threshold
    # accounts for it, see cusum_threshold)
    # each recording's own sigma (never below the robot's typical one): a recording whose
    # motion separates Fv from Fc poorly says so through its sigma and weighs less
    scale = np.maximum(hist["compensated_sigma"], hist["sigma_ref"]) * hist["parameter"].map(ratios)
    # a robot whose own baseline scatters more than the fleet's (a cell whose motion identifies
    # its friction badly, unmodelled effects) gets its own, larger scale: never a smaller one,
    # which 8 points could underestimate
    dev = (hist["compensated"] - hist["mean"]) / scale
    own = (dev.where(base) ** 2).groupby([hist["robot_id"], hist["parameter"]]).transform("mean")
    own = np.sqrt(own * hist["count"] / np.maximum(hist["count"] - 1, 1))
    scale = scale * np.maximum(1.0, own.fillna(1.0))
    hist["scatter"] = scale
    hist["z"] = (hist["compensated"] - hist["mean"]) / scale
    hist["cusum_up"] = np.nan
    hist["cusum_down"] = np.nan
    alarms = []
    n_monitored = 0
    robot_files = frame.groupby("robot_id")["robot"].first().to_dict() if "robot" in frame else {}
    prismatic = {}
    for (rid, name), idx in hist.groupby(["robot_id", "parameter"]).groups.items():
        sub = hist.loc[idx]
        if int(sub["count"].iloc[0]) < n_baseline or len(sub) <= n_baseline:
            continue                # no recording after the baseline: nothing to watch yet
        n_monitored += 1
        z = np.where(sub["baseline"].to_numpy(), 0.0, sub["z"].to_numpy())
        up, down, alarm = cusum(z, allowance, h)
        hist.loc[idx, "cusum_up"], hist.loc[idx, "cusum_down"] = up, down
        if alarm is None:
            continue
        t, side, onset = alarm
        since = sub.iloc[onset:t + 1]
        size = float((since["compensated"] - since["mean"]).mean())
        mean0 = float(sub["mean"].iloc[0])
        alarms.append(Alarm(robot_id=str(rid), joint=int(sub["joint"].iloc[0]), parameter=str(name),
                            direction="increase" if side > 0 else "decrease",
                            onset_day=str(sub["day"].iloc[onset]), alarm_day=str(sub["day"].iloc[t]),
                            size=size, rel_size=size / mean0 if mean0 else float("nan"), baseline=mean0,
                            statistic=float(up[t] if side > 0 else down[t]),
                            unit=_unit(robot_files.get(rid), str(name), prismatic)))
    hist = hist.rename(columns={"mean": "baseline_value", "count": "baseline_count"}).drop(columns="sigma_ref")
    alarms.sort(key=lambda a: (a.robot_id, a.joint, a.parameter))
    settings["n_monitored"] = n_monitored
    return FleetHealth(history=hist, alarms=alarms, temperature_coefficients=coeffs, threshold=h,
                       settings=settings, scatter_ratio=ratios)
