"""Per-joint (decoupled) identification of Bona & Curatella (2005), section 3.

One joint moves at a time, the others are still; each joint follows eq. (21)::

    tau = M qdd + g(q) + f(qd),   g(q) = k sin(q + q_off) (eq. 23),   f: eq. (2)

Three steps, each repeated over n experiments and summarised by
`dynid.analysis.decoupled.repeated.RepeatedEstimate` (mean, σ, 99.9 % Student half-width):

`estimate_gravity` (Table 1)
    Two constant-velocity slopes of the same speed and opposite sign. On them
    the inertia torque vanishes and friction is a constant c+ (up) or c-
    (down), so `tau = a sin q + b cos q + c±`. The least-squares fit of that
    model is the paper's half-sum / half-difference: (c+ + c-)/2 is the offset
    left in the half-sum, (c+ - c-)/2 the friction at the sweep speed, and
    `a = k cos q_off`, `b = k sin q_off`. `q_off` is reported in
    (-π/2, π/2] with the sign of `k` following (Table 1: k2 < 0).
`estimate_friction` (Table 2, Fig. 3)
    Bang-bang accelerations after gravity compensation with the *mean*
    gravity parameters (as the paper uses Table 1). The inertia ("hysteresis"
    of Fig. 3: +M A accelerating, -M A decelerating at the same speed) is a
    nuisance column, so `tau - g(q) = M qdd + Fv± qd ± Fc±` gives
    `Fv+, Fv-, Fc+, Fc-` by least squares on the samples with
    `|qd| > v_min` away from the acceleration switches.
`estimate_inertia` (Table 3)
    On the excitation, after friction compensation with the mean Table 2
    values (section 3.4): `tau - f(qd) = ZZ qdd + MX g0 cos q - MY g0 sin q`
    (`[qdd]` only for a joint with a vertical axis).

Velocity and acceleration come from the measured position by a
Savitzky-Golay filter (cubic, `window` s); the torque is smoothed by the
same filter so that both sides of the regression see the same filtering.
`zoh=True` (default) takes the logged torque for a command held over the
next sample period, as a controller's log (and dynid's simulator) has it, and
centres it on the position samples (`_centred_torque`); pass
`zoh=False` for torques sampled at the position instants.

Chaining. The gravity compensation of the friction step and the friction
compensation of the inertia step use, for repetition k, the previous step's
estimate from repetition k (`per_repetition=True`, default, when both have
the same number of repetitions): each repetition is then a complete
gravity -> friction -> inertia chain, and the spread over repetitions, hence
the Student interval, includes the uncertainty the previous step passes on.
With the means of the previous table (`per_repetition=False`, the paper's
literal "using the friction parameters in Table 2") that uncertainty is
common to all repetitions and not in the interval: on the simulated COMAU it
put MX3 1.2 half-widths from its true value.
Arrays: `t` (N,), `q`, `tau` (R, N, n) (repetitions, samples, joints),
`qr` (N, n) the reference; joints are numbered from 1.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

from dynid.analysis.decoupled.repeated import DEFAULT_CONFIDENCE, MIN_REPETITIONS, RepeatedEstimate
from dynid.dynamics.joint_model import G0, JointModel
from dynid.errors import InputError

__all__ = ["estimate_gravity", "estimate_friction", "estimate_inertia", "gravity_coefficients",
           "identified_model", "FRICTION_SYMBOLS"]

FRICTION_SYMBOLS = ("Fv+", "Fv-", "Fc+", "Fc-")
_PAPER = {"Fv+": "β^v+", "Fv-": "β^v−", "Fc+": "β^c+", "Fc-": "β^c−", "k": "k", "qoff": "q^off",
          "ZZ": "Γ^zz", "MX": "mx", "MY": "my"}
_UNITS = {"Fv+": "N m s/rad", "Fv-": "N m s/rad", "Fc+": "N m", "Fc-": "N m", "k": "N m",
          "qoff": "rad", "ZZ": "kg m^2", "MX": "kg m", "MY": "kg m"}
MIN_SEGMENT_SAMPLES = 20
#: Friction: accelerating and decelerating samples must each be at least this fraction of the
#: samples of a velocity sign, or the inertia column is nearly collinear with the Coulomb one.
MIN_PHASE_FRACTION = 0.1
#: Savitzky-Golay window, s. On the simulated COMAU (1 kHz, encoder noise 2e-6 rad) 21 ms lets
#: the acceleration noise attenuate ZZ1, ZZ2 by ~3 half-widths, 51 ms biases ZZ2 by +0.04 %
#: (~1 half-width) through the filter's own error; 31 ms keeps both well inside.
WINDOW = 0.031


# ------------------------------------------------------------------ inputs
def _inputs(t, q, tau, qr=None, what=""):
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if q.ndim == 2:
        q, tau = q[None], tau[None]
    if q.ndim != 3 or q.shape != tau.shape or t.ndim != 1 or t.size != q.shape[1]:
        raise InputError(f"{what}: expected t (N,), q and tau (repetitions, N, joints); got t "
                         f"{t.shape}, q {q.shape}, tau {tau.shape}")
    if q.shape[0] < MIN_REPETITIONS:
        raise InputError(f"{what}: {q.shape[0]} repetition(s); the 99.9 % Student interval needs at "
                         f"least {MIN_REPETITIONS} repeated experiments (the paper uses 25)")
    dt = np.diff(t)
    if np.any(dt <= 0) or np.ptp(dt) > 1e-6 * dt.mean():
        raise InputError(f"{what}: t must be increasing and uniformly sampled")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(tau))):
        raise InputError(f"{what}: q and tau must be finite (NaN or inf found)")
    if qr is not None:
        qr = np.asarray(qr, dtype=float)
        if qr.ndim == 1:
            qr = qr[:, None]
        if qr.shape != q.shape[1:]:
            raise InputError(f"{what}: qr must be (N, joints) = {q.shape[1:]}, got {qr.shape}")
    return t, q, tau, qr


def _joints(joints, n, what):
    js = list(range(1, n + 1)) if joints is None else [int(j) for j in joints]
    bad = [j for j in js if not 1 <= j <= n]
    if bad or not js:
        raise InputError(f"{what}: joints must be numbers 1..{n}, got {joints!r}")
    return js


def _smooth(t, x, window, deriv=0):
    fs = 1.0 / (t[1] - t[0])
    w = max(5, int(round(window * fs)) | 1)
    if w >= x.shape[1]:
        raise InputError(f"the recording ({x.shape[1]} samples) is shorter than the smoothing window")
    return savgol_filter(x, w, 3, deriv=deriv, delta=1.0 / fs, axis=1)


def _reference_derivatives(t, qr):
    qdr = np.gradient(qr, t, axis=0)
    return qdr, np.gradient(qdr, t, axis=0)


def _since_change(t, changed):
    """Time since the last True of `changed` (N, n) (inf before the first)."""
    idx = np.where(changed, np.arange(t.size)[:, None], -1)
    last = np.maximum.accumulate(idx, axis=0)
    return np.where(last >= 0, t[:, None] - t[np.maximum(last, 0)], np.inf)


def _away_from_reversals(t, v, vlim, guard):
    """`|v| > vlim` and at least `guard` s from any sample with `|v| <= vlim`; v (R, N).

    At a velocity reversal a joint with Coulomb friction sticks until its
    controller builds up the break-away torque, then jumps: a transient at the
    loop's bandwidth that the smoothed derivatives do not follow. Measured on
    the simulated COMAU without noise, keeping those samples biases the wrist
    inertias by ~1 %.
    """
    slow = (np.abs(v) <= vlim).T                      # (N, R): time on axis 0
    after = _since_change(t, slow)
    before = _since_change(-t[::-1], slow[::-1])[::-1]
    return (~slow & (after >= guard) & (before >= guard)).T


def _centred_torque(tau, zoh):
    """The torque acting around each position sample.

    A controller log holds the command `tau_k` over `[t_k, t_k + T)`, half a
    sample after the position `q_k`; the mean of `tau_k-1` and `tau_k` is
    centred on `t_k`. Uncorrected, the friction slope times T/2 leaks into the
    inertia (Fv T / 2 = 0.0015 kg m^2 = 0.5 % of ZZ4 of the COMAU at 1 kHz).
    """
    if not zoh:
        return tau
    out = tau.copy()
    out[:, 1:] = 0.5 * (tau[:, 1:] + tau[:, :-1])
    return out


def _batched_lstsq(X, y, w):
    """Least squares per repetition: X (R, N, p), y (R, N), w (R, N) 0/1 weights -> (R, p), cond."""
    Xw = X * w[..., None]
    A = np.einsum("rni,rnj->rij", Xw, X)
    b = np.einsum("rni,rn->ri", Xw, y)
    scale = np.sqrt(np.einsum("rii->ri", A))
    scale[scale == 0] = 1.0
    An = A / scale[:, :, None] / scale[:, None, :]
    cond = float(np.max(np.linalg.cond(An)))
    return np.linalg.solve(A, b[..., None])[..., 0], cond


# ------------------------------------------------------------------ Table 1
def estimate_gravity(t, q, tau, qr, *, joints=(2, 3), settle=0.5, confidence=DEFAULT_CONFIDENCE,
                     truth=None) -> RepeatedEstimate:
    """Table 1: `k`, `q_off` of eq. (23) per repetition from two constant-velocity slopes.

    `settle` s after the reference reaches its constant speed are skipped
    (the loop's transient). `truth`: optional dict name -> true value.
    """
    what = "gravity (Table 1)"
    t, q, tau, qr = _inputs(t, q, tau, qr, what)
    if qr is None:
        raise InputError(f"{what}: the reference qr is needed to find the constant-velocity slopes")
    js = _joints(joints, q.shape[2], what)
    qdr, qddr = _reference_derivatives(t, qr)
    vmax = np.abs(qdr).max(axis=0)
    const = np.abs(qddr) <= 1e-6 * np.maximum(1.0, np.abs(qddr).max(axis=0))
    const &= np.abs(qdr) > 1e-3 * np.maximum(vmax, 1e-12)
    settled = const & (_since_change(t, ~const) >= settle)
    est, names, extra = [], [], {}
    for j in js:
        c = j - 1
        up = settled[:, c] & (qdr[:, c] > 0)
        down = settled[:, c] & (qdr[:, c] < 0)
        if up.sum() < MIN_SEGMENT_SAMPLES or down.sum() < MIN_SEGMENT_SAMPLES:
            raise InputError(
                f"{what}: joint {j} needs a constant-velocity segment of each sign lasting more "
                f"than settle = {settle:g} s; the reference has {up.sum()} settled samples going up "
                f"and {down.sum()} going down (use dynid.dynamics.joint_trajectories.sweep_reference)")
        qj = q[:, :, c]
        X = np.stack([np.sin(qj), np.cos(qj), np.broadcast_to(up, qj.shape),
                      np.broadcast_to(down, qj.shape)], axis=-1).astype(float)
        w = np.broadcast_to(up | down, qj.shape).astype(float)
        p, cond = _batched_lstsq(X, tau[:, :, c], w)
        a, b = p[:, 0], p[:, 1]
        k = np.where(a >= 0, 1.0, -1.0) * np.hypot(a, b)
        qoff = np.arctan(b / a)
        est += [k, qoff]
        names += [f"k{j}", f"qoff{j}"]
        extra[f"joint{j}"] = {"offset_half_sum": 0.5 * (p[:, 2] + p[:, 3]),
                              "friction_half_difference": 0.5 * (p[:, 2] - p[:, 3]),
                              "speed": float(np.abs(qdr[up, c]).mean()), "cond": cond,
                              "samples_up": int(up.sum()), "samples_down": int(down.sum())}
    return _result("gravity", "Table 1 (gravity, eq. (23))", names, np.column_stack(est),
                   confidence, truth, {"joints": js, "settle": settle}, extra)


def _values(result: RepeatedEstimate | None, names, R, per_repetition):
    """(R, len(names)): each repetition's own estimates when `per_repetition` and the result
    has R repetitions, else the means repeated; 0 for names the result lacks."""
    out = np.zeros((R, len(names)))
    if result is None:
        return out
    own = per_repetition and result.n_repetitions == R
    for i, nm in enumerate(names):
        if nm in result.names:
            k = result.names.index(nm)
            out[:, i] = result.estimates[:, k] if own else result.mean[k]
    return out


def gravity_coefficients(gravity: RepeatedEstimate | None, n: int, R=1, per_repetition=False):
    """`(gs, gc)` (R, n) of the gravity parameters (zero for joints without); see `_values`."""
    k = _values(gravity, [f"k{j}" for j in range(1, n + 1)], R, per_repetition)
    qoff = _values(gravity, [f"qoff{j}" for j in range(1, n + 1)], R, per_repetition)
    return JointModel.gravity_from_sinusoid(k, qoff)


# ------------------------------------------------------------------ Table 2
def estimate_friction(t, q, tau, qr, *, gravity=None, joints=None, settle=0.3, v_min=0.05,
                      guard=0.2, window=WINDOW, zoh=True, per_repetition=True,
                      confidence=DEFAULT_CONFIDENCE, truth=None) -> RepeatedEstimate:
    """Table 2: `Fv+, Fv-, Fc+, Fc-` per joint and repetition from bang-bang accelerations.

    `gravity`: the Table 1 result used for gravity compensation (module doc: chaining).
    Samples with `|qd| <= v_min` times the joint's peak reference speed, closer
    than `guard` s to such a sample, or within `settle` s of an acceleration
    switch of the reference, are left out.
    """
    what = "friction (Table 2)"
    t, q, tau, qr = _inputs(t, q, tau, qr, what)
    if qr is None:
        raise InputError(f"{what}: the reference qr is needed to find the acceleration switches")
    n = q.shape[2]
    js = _joints(joints, n, what)
    qd = _smooth(t, q, window, 1)
    qdd = _smooth(t, q, window, 2)
    tau_s = _smooth(t, _centred_torque(tau, zoh), window, 0)
    gs, gc = gravity_coefficients(gravity, n, q.shape[0], per_repetition)
    tau_s = tau_s - (gs[:, None] * np.sin(q) + gc[:, None] * np.cos(q))
    qdr, qddr = _reference_derivatives(t, qr)
    # differencing an exact reference twice leaves ~1e-10 rad/s^2 of rounding where it is 0
    atol = 1e-6 * np.maximum(1.0, np.abs(qddr).max(axis=0))
    switch = np.vstack([np.zeros((1, n), bool), np.abs(np.diff(qddr, axis=0)) > atol])
    calm = _since_change(t, switch) >= settle
    calm &= _since_change(-t[::-1], switch[::-1])[::-1] >= 0.5 * window
    est, names, extra = [], [], {}
    for j in js:
        c = j - 1
        vlim = v_min * np.abs(qdr[:, c]).max()
        v = qd[:, :, c]
        keep = calm[:, c] & _away_from_reversals(t, v, vlim, guard)
        pos = keep & (v > 0)
        neg = keep & (v < 0)
        # both signs must be seen accelerating and decelerating, or M and Fc are confounded
        for name, m in (("positive", pos), ("negative", neg)):
            acc = (m & (qddr[None, :, c] > atol[c])).sum(axis=1).min()
            dec = (m & (qddr[None, :, c] < -atol[c])).sum(axis=1).min()
            total = m.sum(axis=1).min()
            if min(acc, dec) < max(MIN_SEGMENT_SAMPLES, MIN_PHASE_FRACTION * total):
                raise InputError(
                    f"{what}: joint {j} has too few {name}-velocity samples accelerating ({acc}) or "
                    f"decelerating ({dec}) of {total}, away from the switches and from zero "
                    "velocity; the friction needs "
                    "bang-bang accelerations with velocities of both signs "
                    "(dynid.dynamics.joint_trajectories.bang_bang_reference)")
        X = np.stack([qdd[:, :, c], v * pos, pos.astype(float), v * neg, -neg.astype(float)], axis=-1)
        p, cond = _batched_lstsq(X, tau_s[:, :, c], (pos | neg).astype(float))
        est += [p[:, 1], p[:, 3], p[:, 2], p[:, 4]]
        names += [f"{s}{j}" for s in FRICTION_SYMBOLS]
        extra[f"joint{j}"] = {"inertia_nuisance": p[:, 0], "cond": cond,
                              "samples": int((pos | neg).sum(axis=1).min())}
    return _result("friction", "Table 2 (friction, eq. (2))", names, np.column_stack(est),
                   confidence, truth, {"joints": js, "settle": settle, "v_min": v_min, "guard": guard,
                                       "window": window, "zoh": zoh,
                                       "per_repetition": per_repetition, "gravity_compensation": gravity is not None}, extra)


def _friction_arrays(friction: RepeatedEstimate | None, n: int, R=1, per_repetition=False):
    """[Fv+, Fv-, Fc+, Fc-], each (R, n); see `_values`."""
    return [_values(friction, [f"{s}{j}" for j in range(1, n + 1)], R, per_repetition)
            for s in FRICTION_SYMBOLS]


# ------------------------------------------------------------------ Table 3
def estimate_inertia(t, q, tau, *, friction=None, first_moments=(2, 3, 4, 5, 6), joints=None,
                     skip=1.0, v_min=0.05, guard=0.2, window=WINDOW, g0=G0, zoh=True,
                     per_repetition=True, confidence=DEFAULT_CONFIDENCE,
                     truth=None) -> RepeatedEstimate:
    """Table 3: `ZZ` and, for the joints in `first_moments`, `MX`, `MY` per repetition.

    `friction`: the Table 2 result that compensates the friction (module doc: chaining).
    The first `skip` s (the loop's start-up transient), the samples with
    `|qd| <= v_min` times the joint's peak speed and those closer than
    `guard` s to one (see `_away_from_reversals`) are left out.
    """
    what = "inertia (Table 3)"
    t, q, tau, _ = _inputs(t, q, tau, None, what)
    n = q.shape[2]
    js = _joints(joints, n, what)
    fm = set(int(j) for j in (first_moments or ()))
    qd = _smooth(t, q, window, 1)
    qdd = _smooth(t, q, window, 2)
    fvp, fvm, fcp, fcm = (a[:, None, :] for a in _friction_arrays(friction, n, q.shape[0], per_repetition))
    fric = np.where(qd > 0, fvp * qd + fcp, np.where(qd < 0, fvm * qd - fcm, 0.0))   # eq. (2)
    y_all = _smooth(t, _centred_torque(tau, zoh), window, 0) - fric
    late = (t - t[0] >= skip)[None, :]
    if late.sum() < MIN_SEGMENT_SAMPLES:
        raise InputError(f"{what}: nothing left after skipping the first {skip:g} s")
    est, names, extra = [], [], {}
    for j in js:
        c = j - 1
        v = qd[:, :, c]
        w = (late & _away_from_reversals(t, v, v_min * np.abs(v).max(), guard)).astype(float)
        cols = [qdd[:, :, c]]
        if j in fm:
            cols += [g0 * np.cos(q[:, :, c]), -g0 * np.sin(q[:, :, c])]
        p, cond = _batched_lstsq(np.stack(cols, axis=-1), y_all[:, :, c], w)
        if cond > 1e8:
            raise InputError(f"{what}: joint {j}: the excitation does not separate the inertia from "
                             f"the first moments (condition number {cond:.3g}); move the joint over a "
                             "wider range with varying acceleration")
        est += [p[:, i] for i in range(p.shape[1])]
        names += [f"ZZ{j}"] + ([f"MX{j}", f"MY{j}"] if j in fm else [])
        extra[f"joint{j}"] = {"cond": cond, "samples": int(w.sum(axis=1).min())}
    return _result("inertia", "Table 3 (robot model, eq. (21))", names, np.column_stack(est),
                   confidence, truth, {"joints": js, "first_moments": sorted(fm), "skip": skip,
                                       "v_min": v_min, "guard": guard, "window": window, "g0": g0, "zoh": zoh,
                                       "per_repetition": per_repetition,
                                       "friction_compensation": friction is not None}, extra)


def identified_model(friction: RepeatedEstimate, inertia: RepeatedEstimate, n: int, *, g0=G0,
                     name="identified") -> JointModel:
    """The `JointModel` of the mean Table 2 and Table 3 values (for validation, sec. 3.5)."""
    zz = np.array([inertia.value(f"ZZ{j}", np.nan) for j in range(1, n + 1)])
    if np.any(~np.isfinite(zz)):
        raise InputError(f"the inertia result has no ZZ for joint(s) "
                         f"{[j + 1 for j in np.flatnonzero(~np.isfinite(zz))]}")
    mx = np.array([inertia.value(f"MX{j}") for j in range(1, n + 1)])
    my = np.array([inertia.value(f"MY{j}") for j in range(1, n + 1)])
    gs, gc = JointModel.gravity_from_first_moments(mx, my, g0)
    return JointModel(zz, *(a[0] for a in _friction_arrays(friction, n)), gs, gc, name=name)


# ------------------------------------------------------------------ result
def _result(kind, table, names, estimates, confidence, truth, settings, extra):
    syms, units, joints = [], [], []
    for nm in names:
        base = nm.rstrip("0123456789")
        syms.append(f"{_PAPER[base]}_{nm[len(base):]}")
        units.append(_UNITS[base])
        joints.append(int(nm[len(base):]))
    tv = None
    if truth is not None:
        tv = np.array([truth.get(nm, np.nan) for nm in names], dtype=float)
    return RepeatedEstimate(kind=kind, names=names, estimates=estimates, joints=joints, symbols=syms,
                            units=units, confidence=confidence, truth=tv, table=table,
                            settings=settings, extra=extra)
