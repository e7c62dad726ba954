"""A named physical hypothesis for every joint the structure tests flag, or no flag.

The structure tests (structure.py) say *that* a joint's residual has structure and
along which variable. A user of a real robot needs *what* it points to (issue 27):

* a spectral line against q_j of period P: at the recorded speeds it is a frequency
  f = median|qd_j| / P. At or above the Nyquist frequency of the data the test ran on
  (the full-rate recording for the line test) it is an alias, not a mechanism: the flag
  is not raised (it is kept in `StructureResult.dropped` with the reason). Below it, the
  order per link turn k = 2 pi / P is compared with the harmonics of the motor turn
  (k / |N_j|, N_j the joint's gear ratio from the data description: `[experiment]
  gear_ratios`, or the `[transmission]` of motor-side data):
  within `HARMONIC_TOL` of an integer h it is "motor-side cogging/gear ripple, h-th
  harmonic of motor j" (real TX40 joint 1: P = 0.00409 rad, k = 1536 = 32 x 48);
  otherwise a position ripple of order k per link turn;
* dependence on another joint's q_i or qd_i: "coupling from q_i" (or qd_i);
* the friction level against time (residual x sign(qd_j) vs t): "drift: friction level
  changes by x N m (y % of Fc_j) over the recording"; against t alone, or a step:
  time dependence;
* q_j, qd_j, qdd_j of the joint itself: a position-dependent torque, a friction law not
  linear in qd_j, an acceleration-dependent torque (inertia or elasticity);
* only the excess over the torque-noise floor: "coloured residual only".

Effect size. A flag is raised only when its structure carries at least `MIN_SHARE`
(one third) of the joint's residual variance, rms^2 / (rms^2 + rest^2) >= 1/3 (ratio
rms / rest >= 0.71), a stricter size than the structure tests' own 0.5 (20 %): on a
held-out case with a ripple on joint 3, joints 1 and 2 were also flagged with a structure
RMS of 0.013 against 0.020 N m of the rest (30 %). A joint whose variable test is too
small but whose residual is far above its noise floor is reported as a coloured residual,
with the small structure named beside it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Hypothesis", "name_flags", "gear_ratios_of", "MIN_SHARE", "HARMONIC_TOL",
           "ordinal", "attach_findings"]

#: least share of the joint's residual variance a flagged structure must carry
MIN_SHARE = 1.0 / 3.0
#: a line is at a motor harmonic when k / |N_j| is within this of an integer
HARMONIC_TOL = 0.1


@dataclass
class Hypothesis:
    """The physical mechanism a flagged joint's structure points to."""

    joint: int
    mechanism: str               # motor_ripple, position_ripple, coupling, drift, time, step,
    #                              position, velocity, acceleration, coloured, alias, small
    text: str
    raised: bool = True
    reason: str = ""             # why it is not raised
    frequency_hz: float | None = None
    nyquist_hz: float | None = None
    harmonic: int | None = None
    gear_ratio: float | None = None

    def to_dict(self):
        return {"joint": self.joint, "mechanism": self.mechanism, "text": self.text,
                "raised": self.raised, "reason": self.reason or None,
                "frequency_hz": self.frequency_hz, "nyquist_hz": self.nyquist_hz,
                "harmonic": self.harmonic, "gear_ratio": self.gear_ratio}


def ordinal(k):
    """1st, 2nd, 3rd, 4th, ..., 11th, 48th."""
    k = int(k)
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def gear_ratios_of(experiment):
    """Gear ratios (n,) of the joints' motors from the data, or None.

    `experiment.meta["gear_ratios"]`: the experiment description's `[experiment]
    gear_ratios`, or the `[transmission] gear_ratios` that converted motor-side signals
    (docs/formats.md). The robot file holds no gear ratio.
    """
    meta = getattr(experiment, "meta", None) or {}
    ratios = meta.get("gear_ratios")
    return None if ratios is None else np.asarray(ratios, dtype=float)


def name_flags(structure, eobs, *, gear_ratios=None, model_names=(), model_values=(),
               edge_factor=3.0):
    """Attach a `Hypothesis` to each flagged joint of `structure` (in place); drop the flags
    that have none or are too small (kept in `structure.dropped`).

    Parameters
    ----------
    structure : StructureResult of the final residual.
    eobs : EffectObservation of the identification data (full-rate qd and fs).
    gear_ratios : (n,) gear ratios of the joints' motors, or None.
    model_names, model_values : the final model's parameters (for Fc_j in drift sizes).
    edge_factor : rows with |qd_j| below this many dead-zone widths are left out (as the tests).

    Returns
    -------
    list of Hypothesis, one per joint flagged by the structure tests.
    """
    values = dict(zip(model_names, np.asarray(model_values, dtype=float)))
    qd = np.asarray(eobs.qd, dtype=float)
    thr = np.atleast_1d(np.asarray(eobs.obs.settings.get("qd_threshold") or 0.0, dtype=float))
    thr = np.broadcast_to(thr if thr.size == qd.shape[1] else thr[:1], (qd.shape[1],))
    out, kept, dropped = [], [], list(getattr(structure, "dropped", []) or [])
    for u in structure.unexplained:
        j = u.joint - 1
        moving = np.abs(qd[:, j]) >= edge_factor * thr[j]
        speed = float(np.median(np.abs(qd[moving, j]))) if moving.any() else 0.0
        tests = [t for t in structure.tests if t.joint == u.joint and t.flagged]
        h = _hypothesis(u, tests, speed, float(eobs.fs), gear_ratios, values)
        u.hypothesis, u.mechanism = h.text, h.mechanism
        out.append(h)
        (kept if h.raised else dropped).append(u)
        if not h.raised:
            u.reason = h.reason
    structure.unexplained = kept
    structure.dropped = dropped
    return out


def _share(t):
    return t.rms ** 2 / max(t.rms ** 2 + t.noise_rms ** 2, 1e-300)


def _hypothesis(u, tests, speed, fs, gear_ratios, values):
    """The hypothesis of one flagged joint from its flagged tests (largest first)."""
    j = u.joint
    variable = sorted((t for t in tests if t.test != "noise_floor"), key=lambda t: -t.rms)
    floor = next((t for t in tests if t.test == "noise_floor"), None)
    minor = []
    for t in variable:
        h = _from_test(j, t, speed, fs, gear_ratios, values)
        if h.mechanism == "alias":
            minor.append(h)
            continue
        if _share(t) >= MIN_SHARE:
            return h
        minor.append(h)
    aside = "; ".join(f"{m.text} ({'not a mechanism: ' + m.reason if m.mechanism == 'alias' else 'small'})"
                      for m in minor[:2])
    if floor is not None:
        text = (f"coloured residual only: {math.hypot(floor.rms, floor.noise_rms):.3g} N m RMS, "
                f"{floor.ratio:.2g} x the torque-noise floor, no tested variable carries a third of it")
        return Hypothesis(j, "coloured", text + (f" (also: {aside})" if aside else ""))
    if minor and minor[0].mechanism == "alias":
        return Hypothesis(j, "alias", minor[0].text, raised=False, reason=minor[0].reason,
                          frequency_hz=minor[0].frequency_hz, nyquist_hz=minor[0].nyquist_hz)
    return Hypothesis(j, "small", aside or "structure too small", raised=False,
                      reason=f"the structure carries less than {100 * MIN_SHARE:.0f} % of the joint's "
                             f"residual variance")


def _from_test(j, t, speed, fs, gear_ratios, values):
    if t.test == "line":
        return _line(j, t, speed, fs, gear_ratios)
    if t.test == "step":
        return Hypothesis(j, "step", f"step in time at t = {t.detail.get('t_step', float('nan')):.3g} s "
                                     f"({t.detail.get('step_nm', float('nan')):.3g} N m): the torque level "
                                     f"changed during the recording (contact, payload or warm-up)")
    key = t.depends_on
    if key.startswith("t*sign"):
        return _drift(j, t, values)
    if key == "t":
        return Hypothesis(j, "time", "drift: the torque level changes over the recording")
    name = key.rstrip("0123456789")
    src = int(key[len(name):]) if key[len(name):] else j
    if src != j:
        return Hypothesis(j, "coupling", f"coupling from {key} (the motion of joint {src})")
    return Hypothesis(j, {"q": "position", "qd": "velocity", "qdd": "acceleration"}[name], {
        "q": f"position-dependent torque on q{j} the model lacks (cable, spring, gravity error)",
        "qd": f"friction law not linear in qd{j} (the residual depends on the speed)",
        "qdd": f"acceleration-dependent torque on joint {j} (inertia error or elasticity)"}[name])


def _line(j, t, speed, fs, gear_ratios):
    period = float(t.detail["period_rad"])
    order = 2.0 * math.pi / period
    f = speed / period
    nyq = 0.5 * fs
    if f >= nyq:
        return Hypothesis(j, "alias", f"line of period {period:.3g} rad in q{j}", raised=False,
                          reason=f"at the recorded speeds (median |qd{j}| {speed:.3g} rad/s) it is "
                                 f"{f:.0f} Hz, at or above the Nyquist frequency {nyq:.0f} Hz: an alias",
                          frequency_hz=f, nyquist_hz=nyq)
    base = f"period {period:.3g} rad in q{j}, order {order:.0f} per link turn, ~{f:.0f} Hz at the median speed"
    if gear_ratios is not None and len(gear_ratios) >= j and gear_ratios[j - 1]:
        n_gear = abs(float(gear_ratios[j - 1]))
        h = order / n_gear
        if round(h) >= 1 and abs(h - round(h)) <= HARMONIC_TOL:
            return Hypothesis(j, "motor_ripple",
                              f"motor-side cogging/gear ripple, {ordinal(round(h))} harmonic of motor {j} "
                              f"(gear ratio {n_gear:g}: {base})", frequency_hz=f, nyquist_hz=nyq,
                              harmonic=int(round(h)), gear_ratio=n_gear)
        return Hypothesis(j, "position_ripple",
                          f"position ripple ({base}; {h:.2f} motor turns per period, not a harmonic "
                          f"of motor {j}: link-side transmission or load)", frequency_hz=f,
                          nyquist_hz=nyq, gear_ratio=n_gear)
    return Hypothesis(j, "position_ripple", f"position ripple ({base}; gear ratio unknown)",
                      frequency_hz=f, nyquist_hz=nyq)


def _drift(j, t, values):
    fc = values.get(f"Fc{j}")
    size = f"{t.rms:.3g} N m RMS"
    if fc:
        size += f", {100 * t.rms / abs(fc):.0f} % of Fc{j} = {fc:.3g} N m"
    return Hypothesis(j, "drift", f"drift: the friction level of joint {j} changes over the recording ({size})")


def attach_findings(structure, findings):
    """Name the drift a finding found on a flagged joint in that joint's hypothesis (in place).

    A drift is never added to the model (findings.py), so its torque stays in the residual
    the structure tests examine: the joint is flagged, along t x sign(qd_j) (named a drift
    already) or as a coloured residual whose cause the finding names.

    Parameters
    ----------
    structure : StructureResult with hypotheses attached (`name_flags`), or None.
    findings : list of Finding.

    Returns
    -------
    None
    """
    if structure is None:
        return
    by_joint = {f.joint: f for f in findings if f.name == "drift"}
    for u in structure.unexplained:
        f = by_joint.get(u.joint)
        if f is None or getattr(u, "mechanism", None) in ("drift", "time"):
            continue
        u.hypothesis = f"drift (named as a finding, not added: {f.size}); the structure tests: {u.hypothesis}"
        u.mechanism = "drift"
