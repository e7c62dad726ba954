"""The effect library: what an identified model may lack, as extra regressor columns.

Every effect of the CONVENTIONS table is a function building *full-rate*
regressor columns from the filtered motion (q_hat, qd_hat, qdd_hat), the time
and, for two of them, the current model's torque. Each is linear in its
parameters, or a small family over one nonlinear parameter that the
diagnosis searches on a grid. The columns then go through the same velocity
dead zone and parallel decimation as W (`dynid.analysis.diagnosis.effect_observation`).

=====================  ===========================================  ====================  ===============
name                   columns (joint j, 1-based in names)          parameters            nonlinear
=====================  ===========================================  ====================  ===============
`offset`             1                                            `Off{j}`            --
`asymmetric_coulomb` abs(sign(qd_j)): Fcp = Fc + dFc, Fcn = Fc - dFc `dFc{j}`          --
`asymmetric_viscous` abs(qd_j): Fvp = Fv + dFv, Fvn = Fv - dFv     `dFv{j}`            --
`stribeck`           sign(qd_j) exp(-(qd_j / v_s)^2)              `Fs{j}`             v_s (log grid)
`position_ripple`    cos(k q_j), sin(k q_j)                       `Rc{j}k{k}`,        order k (grid,
                                                                    `Rs{j}k{k}`         then refined)
`spring`             q_j                                          `Ks{j}`             --
`coupling`           qd_i or qdd_i of another joint i, on j       `Cv{j}_{i}` /       (i, signal)
                                                                    `Ca{j}_{i}`
`time_delay`         none: W(t - d) replaces W(t), all joints     (d)                   d [s] (± log grid)
`drift`              s, s^2 with s = (t - t0) / T  (per joint)    `Dr{j}_1`, ...      order 1 or 2
                       or the friction level: s qd_j, s sign(qd_j)  `Dv{j}`, `Dc{j}` shape "friction"
`load_friction`      abs(tau_load_j) sign(qd_j)                   `Fl{j}`             --
`payload`            standard-regressor columns of the last       `dM{n}`, `dMX{n}`, --
                       link's M, MX, MY, MZ, on every joint         `dMY{n}`, `dMZ{n}`
=====================  ===========================================  ====================  ===============

Notes on the definitions:

* `offset` and `asymmetric_coulomb`: outside the velocity dead zone
  `abs(sign(qd))` is 1, so the two have *the same column* there. A Coulomb
  friction that differs with the sign of the velocity, Fcp for qd > 0 and
  -Fcn for qd < 0, is `(Fcp+Fcn)/2 sign(qd) + (Fcp-Fcn)/2` while the joint
  moves: exactly a symmetric Coulomb term plus an offset. Data of a moving
  joint cannot tell them apart (only data at rest could); the diagnosis
  reports them as aliases of each other.
* `time_delay`: torque samples recorded `d` late (d < 0: early),
  tau_meas(t) = tau(t - d) = W(t - d) chi. Not an added column: the model is
  re-fitted on the base regressor of the motion shifted by d
  (`EffectObservation.shifted_regressor`), one nonlinear degree of
  freedom. (A column built from the current model's torque, d dtau_model/dt,
  does not work: the model identified from delayed data has already absorbed
  part of the delay into biased parameters, measured in the campaign.)
* `load_friction`: a friction proportional to the torque the transmission
  carries, `mu abs(tau_load) sign(qd)`, with tau_load the current model's
  torque without its friction and offset terms.
* `drift`: `t0` and `T` are the start and duration of the identification
  recording, so a validation recording (or a held-out later segment) uses the
  same time scale. `shape="friction"` (nonlinear `{"order": 1, "shape":
  "friction"}`) is a friction whose level changes over the recording (grease
  warm-up, temperature): Fv and Fc scaled by `1 + a s`, i.e. the columns
  `s qd_j` and `s sign(qd_j)` (a first-order drift of the friction
  parameters); an additive drift has zero mean over a back-and-forth motion
  and cannot describe it.
* `payload`: the columns of the standard regressor of the last link's mass
  and first moments (a point-like extra mass); those already in the span of
  the model (regrouped into identified base parameters) are dropped by the
  diagnosis' rank check.
* `spring`: a linear spring k (q_j - q0) is `Ks q_j` plus a constant; the
  constant is an offset (`Off{j}` of the base model, or the `offset`
  effect).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynid.errors import InputError

__all__ = ["EFFECT_NAMES", "EFFECT_DESCRIPTIONS", "EffectSignals", "Candidate", "candidate_set",
           "effect_torque", "signals_from_observation", "STRIBECK_GRID", "RIPPLE_ORDERS",
           "DRIFT_ORDERS", "COUPLING_SIGNALS", "DELAY_GRID", "FRICTION_PREFIXES"]

#: The CONVENTIONS names, in the order of its table (also the tie-break order).
EFFECT_NAMES = ("offset", "asymmetric_coulomb", "asymmetric_viscous", "stribeck",
                "position_ripple", "spring", "coupling", "time_delay", "drift",
                "load_friction", "payload")

EFFECT_DESCRIPTIONS = {
    "offset": "a constant torque offset on a joint",
    "asymmetric_coulomb": "Coulomb friction that differs with the sign of the velocity",
    "asymmetric_viscous": "viscous friction that differs with the sign of the velocity",
    "stribeck": "friction that falls from a static to a Coulomb level at low speed",
    "position_ripple": "a torque periodic in the joint position (cogging, transmission ripple)",
    "spring": "an elastic torque that depends on the joint position (gravity compensator, cable)",
    "coupling": "a torque on one joint driven by the motion of another (transmission coupling)",
    "time_delay": "torque and position samples shifted in time against each other",
    "drift": "a slow change over the recording (warm-up, temperature)",
    "load_friction": "friction that grows with the transmitted torque",
    "payload": "an unmodelled mass on the last link",
}

#: Stribeck velocities searched, as fractions of the joint's peak |qd| (log grid).
STRIBECK_GRID = tuple(np.round(np.geomspace(0.015, 0.3, 7), 5))
#: Ripple orders (periods per turn of the joint: cos(k q_j), q_j in rad) searched.
RIPPLE_ORDERS = (1, 2, 3, 4, 5, 6, 8)
#: Time delays searched, s (both signs).
#: A factor 2 apart: the candidate at the nearest grid point must already beat the model
#: in the held-out blocks (measured: a factor 4 grid missed a 4.8 ms delay scored at 8 ms).
DELAY_GRID = (0.0005, 0.001, 0.002, 0.004, 0.008, 0.016, 0.032)
#: Drift polynomial orders searched.
DRIFT_ORDERS = (1, 2)
#: Coupling signals: velocity (viscous-like) or acceleration (inertia-like) of the other joint.
COUPLING_SIGNALS = ("qd", "qdd")
#: Base parameters that are friction or offset terms (left out of the transmitted torque).
FRICTION_PREFIXES = ("Fvm", "Fcm", "Fv", "Fc", "Off")


@dataclass
class EffectSignals:
    """Full-rate signals effect columns are built from (kept samples of one recording).

    `t` (N,); `q`, `qd`, `qdd` (N, n) filtered motion; `tau_model`
    the current model's torque, `tau_load` the same without friction and
    offset terms, `tau_rate` d tau_model / dt (all (N, n), optional);
    `payload` (N, n, 4) the last link's M, MX, MY, MZ standard columns;
    `t0`, `T`: origin and scale of the drift polynomials; `sigma` the
    joint types (1 = prismatic).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau_model: np.ndarray | None = None
    tau_load: np.ndarray | None = None
    tau_rate: np.ndarray | None = None
    payload: np.ndarray | None = None
    t0: float = 0.0
    T: float = 1.0
    sigma: np.ndarray | None = None
    last_link: int = 0                 # 1-based number of the last link (payload names)
    fs: float | None = None            # sampling rate, Hz

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]


def signals_from_observation(eobs, model_columns=None, chi=None, model_names=None, *, t0=None,
                             T=None, robot=None):
    """`EffectSignals` of an `EffectObservation`.

    `model_columns` (indices into the base parameters) and `chi` give the
    current model, whose full-rate torque feeds `time_delay` and
    `load_friction` (`model_names` tells its friction terms apart).
    `t0`/`T` default to this recording's start and duration (the drift
    polynomials of a validation recording must use the identification's).
    """
    fs = eobs.fs
    tau_model = tau_load = tau_rate = None
    if model_columns is not None and chi is not None:
        names = list(model_names) if model_names is not None else [eobs.bp.names[c] for c in model_columns]
        friction = np.array([_is_friction(nm) for nm in names], dtype=bool)
        tau_model, tau_load = eobs.model_torques(model_columns, [(chi, None), (chi, friction)])
        tau_rate = np.gradient(tau_model, 1.0 / fs, axis=0)
    robot = robot if robot is not None else eobs.robot
    sigma = None if robot is None else robot.sigma
    t = eobs.t
    if t0 is None:
        t0 = eobs.t_start
    if T is None:
        T = eobs.duration
    return EffectSignals(t=t, q=eobs.q, qd=eobs.qd, qdd=eobs.qdd, tau_model=tau_model,
                         tau_load=tau_load, tau_rate=tau_rate, payload=eobs.payload, t0=float(t0),
                         T=float(T), sigma=sigma, last_link=eobs.n_joints, fs=float(fs))


def _is_friction(name):
    import re
    m = re.match(r"^([A-Za-z]+)\d", name)
    return bool(m) and m.group(1) in FRICTION_PREFIXES


# ----------------------------------------------------------------- columns
def offset_columns(s, j):
    return np.ones((s.t.shape[0], 1))


def asymmetric_coulomb_columns(s, j):
    return np.abs(np.sign(s.qd[:, j]))[:, None]


def asymmetric_viscous_columns(s, j):
    return np.abs(s.qd[:, j])[:, None]


def stribeck_columns(s, j, vs):
    v = s.qd[:, j]
    return (np.sign(v) * np.exp(-(v / vs) ** 2))[:, None]


def ripple_columns(s, j, order):
    x = order * s.q[:, j]
    return np.column_stack([np.cos(x), np.sin(x)])


def spring_columns(s, j):
    return s.q[:, j][:, None]


def coupling_columns(s, j, source, sig):
    x = s.qd if sig == "qd" else s.qdd
    return x[:, source][:, None]


def drift_columns(s, j, order, shape=None):
    x = (s.t - s.t0) / s.T
    if shape == "friction":
        v = s.qd[:, j]
        return np.column_stack([x * v, x * np.sign(v)])
    return np.column_stack([x ** p for p in range(1, order + 1)])


def load_friction_columns(s, j):
    if s.tau_load is None:
        raise InputError("load_friction needs the model torque (EffectSignals.tau_load)")
    return (np.abs(s.tau_load[:, j]) * np.sign(s.qd[:, j]))[:, None]


def payload_columns(s):
    if s.payload is None:
        raise InputError("payload needs the last link's standard-regressor columns (EffectSignals.payload)")
    return s.payload


# ----------------------------------------------------------------- candidates
@dataclass
class Candidate:
    """One effect on one joint (or on all: `joint=None`) at one value of its nonlinear parameter.

    `joint` is 1-based as in the CONVENTIONS. `params` names its linear
    parameters, `nonlinear` its nonlinear parameter (`{}` if none, e.g.
    `{"vs": 0.12}` rad/s, `{"order": 3}`, `{"source": 2, "signal": "qd"}`).
    `active` (set by the diagnosis' rank check) lists the columns kept.
    """

    name: str
    joint: int | None
    params: list
    nonlinear: dict = field(default_factory=dict)
    active: list | None = None

    @property
    def family(self):
        """Candidates of one family are alternatives (one of them at most is added)."""
        if self.name in ("position_ripple", "coupling"):
            return (self.name, self.joint, tuple(sorted(self.nonlinear.items())))
        if self.name == "drift" and self.nonlinear.get("shape") == "friction":
            return (self.name, self.joint, "friction")
        return (self.name, self.joint)

    @property
    def key(self):
        return (self.name, self.joint, tuple(sorted(self.nonlinear.items())))

    @property
    def n_params(self) -> int:
        """Degrees of freedom: linear parameters (time_delay: its one nonlinear parameter)."""
        return 1 if self.name == "time_delay" else len(self.active_params)

    @property
    def active_params(self):
        return list(self.params) if self.active is None else [self.params[i] for i in self.active]

    @property
    def label(self):
        where = "all joints" if self.joint is None else f"joint {self.joint}"
        nl = ""
        if self.name == "stribeck":
            nl = f", v_s = {self.nonlinear['vs']:.3g} rad/s"
        elif self.name == "position_ripple":
            nl = f", order {order_text(self.nonlinear['order'])}"
        elif self.name == "drift":
            nl = (", friction level" if self.nonlinear.get("shape") == "friction"
                  else f", order {self.nonlinear['order']}")
        elif self.name == "coupling":
            nl = f", from {self.nonlinear['signal']}{self.nonlinear['source']}"
        elif self.name == "time_delay":
            nl = f", d = {1e3 * self.nonlinear['d']:.3g} ms"
        return f"{self.name} ({where}{nl})"

    def columns(self, s: EffectSignals):
        """Full-rate columns: (N, k) for a one-joint effect, (N, n, k) for `joint=None`."""
        j = None if self.joint is None else self.joint - 1
        nl = self.nonlinear
        name = self.name
        if name == "offset":
            C = offset_columns(s, j)
        elif name == "asymmetric_coulomb":
            C = asymmetric_coulomb_columns(s, j)
        elif name == "asymmetric_viscous":
            C = asymmetric_viscous_columns(s, j)
        elif name == "stribeck":
            C = stribeck_columns(s, j, nl["vs"])
        elif name == "position_ripple":
            C = ripple_columns(s, j, nl["order"])
        elif name == "spring":
            C = spring_columns(s, j)
        elif name == "coupling":
            C = coupling_columns(s, j, nl["source"] - 1, nl["signal"])
        elif name == "drift":
            C = drift_columns(s, j, nl["order"], nl.get("shape"))
        elif name == "load_friction":
            C = load_friction_columns(s, j)
        elif name == "time_delay":
            raise InputError("time_delay adds no column: it shifts the model's regressor "
                             "(EffectObservation.shifted_regressor)")
        elif name == "payload":
            C = payload_columns(s)
        else:  # pragma: no cover - names are checked on construction
            raise InputError(f"unknown effect {name!r}")
        if self.active is not None:
            C = C[..., self.active]
        return C

    def full_columns(self, s: EffectSignals):
        """Full-rate columns as (N, n, k), zero on the joints the effect does not act on."""
        C = self.columns(s)
        if self.joint is None:
            return C
        out = np.zeros((C.shape[0], s.n_joints, C.shape[1]))
        out[:, self.joint - 1, :] = C
        return out

    def with_nonlinear(self, **values):
        """A copy at another value of the nonlinear parameter (same names, but a ripple's
        names carry its order)."""
        nl = dict(self.nonlinear)
        nl.update(values)
        params = (_params(self.name, self.joint, nl, None) if self.name == "position_ripple"
                  else list(self.params))
        return Candidate(self.name, self.joint, params, nl,
                         None if self.active is None else list(self.active))

    def to_dict(self):
        return {"name": self.name, "joint": self.joint, "parameters": self.active_params,
                "nonlinear": dict(self.nonlinear)}


def _params(name, j, nl, last_link):
    if name == "offset":
        return [f"Off{j}"]
    if name == "asymmetric_coulomb":
        return [f"dFc{j}"]
    if name == "asymmetric_viscous":
        return [f"dFv{j}"]
    if name == "stribeck":
        return [f"Fs{j}"]
    if name == "position_ripple":
        k = order_text(nl["order"])
        return [f"Rc{j}k{k}", f"Rs{j}k{k}"]
    if name == "spring":
        return [f"Ks{j}"]
    if name == "coupling":
        return [f"{'Cv' if nl['signal'] == 'qd' else 'Ca'}{j}_{nl['source']}"]
    if name == "drift":
        if nl.get("shape") == "friction":
            return [f"Dv{j}", f"Dc{j}"]
        return [f"Dr{j}_{p}" for p in range(1, nl["order"] + 1)]
    if name == "load_friction":
        return [f"Fl{j}"]
    if name == "time_delay":
        return []
    if name == "payload":
        return [f"d{sym}{last_link}" for sym in ("M", "MX", "MY", "MZ")]
    raise InputError(f"unknown effect {name!r}")


def order_text(k):
    """A ripple order as written in names and labels: 7, or 7.02 once refined."""
    k = float(k)
    return f"{int(round(k))}" if abs(k - round(k)) < 1e-9 else f"{k:.3g}"


def make_candidate(name, joint=None, last_link=6, **nonlinear):
    """One `Candidate` (parameter names from the effect table)."""
    if name not in EFFECT_NAMES:
        raise InputError(f"unknown effect {name!r}; the effects are {', '.join(EFFECT_NAMES)}")
    if name in ("time_delay", "payload"):
        joint = None
    elif joint is None:
        raise InputError(f"effect {name!r} acts on one joint: give joint= (1-based)")
    return Candidate(name, joint, _params(name, joint, nonlinear, last_link), dict(nonlinear))


def check_effect_names(effects):
    if effects is None:
        return list(EFFECT_NAMES)
    if isinstance(effects, str):
        effects = [effects]
    effects = list(effects)
    bad = [e for e in effects if e not in EFFECT_NAMES]
    if bad:
        raise InputError(f"unknown effect name(s) {', '.join(map(repr, bad))}; the effects are "
                         + ", ".join(EFFECT_NAMES))
    return effects


def candidate_set(s: EffectSignals, effects=None, *, joints=None, qd_peak=None,
                  stribeck_grid=STRIBECK_GRID, ripple_orders=RIPPLE_ORDERS,
                  drift_orders=DRIFT_ORDERS, coupling_signals=COUPLING_SIGNALS,
                  delay_grid=DELAY_GRID, friction_drift=True):
    """All candidates: every effect x joint x value of its nonlinear parameter.

    `effects`: names (default all); `joints`: 1-based joints (default
    all); `qd_peak` (n,): peak |qd_j| the Stribeck grid scales with (default
    from `s`). Position ripple is skipped on prismatic joints (an order in
    periods per turn means nothing there); `time_delay` and
    `load_friction` need the model torque in `s`. `friction_drift`: also the
    friction-level drift (`drift` with `shape="friction"`) on every joint.
    """
    effects = check_effect_names(effects)
    n = s.n_joints
    joints = list(range(1, n + 1)) if joints is None else [int(j) for j in joints]
    peak = np.abs(s.qd).max(axis=0) if qd_peak is None else np.asarray(qd_peak, dtype=float)
    sigma = np.zeros(n, dtype=int) if s.sigma is None else np.asarray(s.sigma)
    last = s.last_link or n
    out = []
    for name in effects:
        if name == "time_delay":
            for d in delay_grid:
                for sgn in (1.0, -1.0):
                    out.append(make_candidate(name, last_link=last, d=sgn * float(d)))
            continue
        if name == "payload":
            if s.payload is not None:
                out.append(make_candidate(name, last_link=last))
            continue
        if name == "load_friction" and s.tau_load is None:
            continue
        for j in joints:
            if name == "stribeck":
                for f in stribeck_grid:
                    vs = float(f * peak[j - 1])
                    if vs > 0:
                        out.append(make_candidate(name, j, last, vs=vs))
            elif name == "position_ripple":
                if sigma[j - 1] == 1:
                    continue
                for k in ripple_orders:
                    out.append(make_candidate(name, j, last, order=int(k)))
            elif name == "drift":
                for p in drift_orders:
                    out.append(make_candidate(name, j, last, order=int(p)))
                if friction_drift:
                    out.append(make_candidate(name, j, last, order=1, shape="friction"))
            elif name == "coupling":
                for i in range(1, n + 1):
                    if i == j:
                        continue
                    for sig in coupling_signals:
                        out.append(make_candidate(name, j, last, source=i, signal=sig))
            else:
                out.append(make_candidate(name, j, last))
    return out


def effect_torque(candidate: Candidate, s: EffectSignals, values):
    """Torque (N, n) of an effect with parameter `values` along the signals `s`.

    The same columns as the diagnosis fits, so injecting `effect_torque` into
    a recording tests exactly the shape the diagnosis looks for.
    """
    values = np.asarray(values, dtype=float).reshape(-1)
    return candidate.full_columns(s) @ values
