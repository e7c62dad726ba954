"""The robot description: kinematic chain, joints, couplings, controller.

A robot is a serial chain of `n` joints. Each joint `j` has a fixed
*placement* (rotation `R` and translation `p`) from frame `j-1` to the
frame of joint `j` at `q_j = 0`, followed by a rotation about (revolute,
`sigma = 0`) or a translation along (prismatic, `sigma = 1`) the local
`z` axis. The modified Denavit-Hartenberg row of Khalil-Kleinfinger,
`Rot(x, alpha) Trans(x, d) Rot(z, theta) Trans(z, r)`, is one way of giving
that placement; a URDF joint origin (with its axis aligned to `z`) another.

Standard parameters (eq. (3) of Gautier, Janot, Vandanjon 2010), per joint::

    XX XY XZ YY YZ ZZ MX MY MZ M Ia Fv Fc Off

followed by the extra parameters of the couplings (`Fvm6`, `Fcm6` for the
TX40 wrist).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

INERTIAL = ("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M")
ACTUATOR = ("Ia", "Fv", "Fc", "Off")
PER_JOINT = INERTIAL + ACTUATOR


def mdh_placement(alpha, d, theta, r):
    """Rotation and translation of `Rot(x,alpha) Trans(x,d) Rot(z,theta) Trans(z,r)`."""
    ca, sa = np.cos(alpha), np.sin(alpha)
    ct, st = np.cos(theta), np.sin(theta)
    R = np.array([[ct, -st, 0.0],
                  [ca * st, ca * ct, -sa],
                  [sa * st, sa * ct, ca]])
    p = np.array([d, -r * sa, r * ca])
    # Exact zeros keep the QR of the base parameters clean of 1e-17 noise.
    R[np.abs(R) < 1e-15] = 0.0
    p[np.abs(p) < 1e-15] = 0.0
    return R, p


def joint_label(k: int, name="", prefix: str = "j") -> str:
    """Joint `k` (0-based) as the tables count it, from 1, with its own name beside it when that
    says something more: `j6 (lwr_5_joint)` (a URDF's names may count from 0), but `j3` for
    `j3`, `joint3`, `Joint_3`, `3` or no name. `prefix="joint "` gives `joint 6 (lwr_5_joint)`."""
    name = "" if name is None else str(name)
    plain = name.lower().replace("_", "").replace(" ", "") in ("", f"j{k + 1}", f"joint{k + 1}", f"{k + 1}")
    label = f"{prefix}{k + 1}"
    return label if plain else f"{label} ({name})"


def joint_names_of(obj, n: int) -> list:
    """The `joint_names` of a robot or result (None: none), padded to `n` with `j1`, `j2`, ..."""
    names = list(getattr(obj, "joint_names", None) or []) if obj is not None else []
    return names[:n] + [f"j{k + 1}" for k in range(len(names), n)]


@dataclass
class Joint:
    """One joint and the link it moves."""

    name: str
    sigma: int = 0                      # 0 revolute, 1 prismatic
    R: np.ndarray = field(default_factory=lambda: np.eye(3))   # placement rotation
    p: np.ndarray = field(default_factory=lambda: np.zeros(3))  # placement translation
    mdh: tuple | None = None         # (alpha, d, theta, r) when given as MDH
    q_limits: tuple = (-np.inf, np.inf)
    qd_max: float = np.inf
    qdd_max: float = np.inf
    tau_max: float = np.inf
    drive_gain: float = 1.0
    friction: str = "viscous_coulomb"

    @property
    def prismatic(self) -> bool:
        return self.sigma == 1


@dataclass
class Coupling:
    """A motor whose rotor turns with several joints (the TX40 wrist).

    The rotor's joint-side velocity is `sum_k c_k qd_k`. Its inertia's diagonal
    terms are absorbed into the joints' own `Ia`; the off-diagonal terms
    `M[k, l] += c_k c_l Ia_motor` use the motor joint's `Ia` (section 4 of the
    DIDIM paper, eq. (33)). Its friction adds the parameters `Fvm<motor>` and
    `Fcm<motor>`: `tau_k += c_k (Fvm w + Fcm sign(w))` with `w` the rotor
    velocity.
    """

    motor: int                          # 1-based joint whose Ia is the rotor's
    joints: tuple                       # 1-based joints the rotor turns with
    coefficients: tuple
    friction: bool = True

    @property
    def parameter_names(self):
        return [f"Fvm{self.motor}", f"Fcm{self.motor}"] if self.friction else []


@dataclass
class Controller:
    """Joint controller of the robot (Figs. 3-4 of the DIDIM paper).

    Per joint: desired closed-loop natural frequency `wn` (rad/s) and damping
    `zeta` give `kp = wn / (2 zeta)` and `kv = 2 zeta wn` (eq. (30)) of the
    normalised double integrator; `J_ap` and `g_ap` are the a-priori inertia
    and drive gain the control signal is scaled with.
    """

    kind: str = "pd"
    rate: float = 1000.0
    wn: np.ndarray = None
    zeta: np.ndarray = None
    J_ap: np.ndarray = None
    g_ap: np.ndarray = None
    ki: np.ndarray = None

    @property
    def kp(self):
        return self.wn / (2.0 * self.zeta)

    @property
    def kv(self):
        return 2.0 * self.zeta * self.wn


@dataclass
class Robot:
    """A serial robot ready for the regressor."""

    name: str
    joints: list
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    couplings: list = field(default_factory=list)
    controller: Controller | None = None
    apriori: dict = field(default_factory=dict)     # parameter name -> value
    # [apriori] mass_tolerance: a physically consistent fit keeps each link mass within this
    # fraction of its a-priori value (None: no bound)
    mass_tolerance: float | None = None
    provenance: dict = field(default_factory=dict)  # what -> where the numbers come from
    source: str = ""                                # file the robot was read from
    description: str = ""
    # what the reader left out or decided that the user should know, one sentence each
    # (e.g. the moving subtrees of a URDF off the selected chain, whose mass is not modelled)
    notices: list = field(default_factory=list)

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self):
        return [j.name for j in self.joints]

    @property
    def drive_gains(self) -> np.ndarray:
        return np.array([j.drive_gain for j in self.joints], dtype=float)

    @property
    def sigma(self) -> np.ndarray:
        return np.array([j.sigma for j in self.joints], dtype=int)

    @property
    def standard_names(self) -> list:
        """Names of the standard parameters chi_st in regressor column order."""
        names = [f"{s}{j}" for j in range(1, self.n_joints + 1) for s in PER_JOINT]
        for c in self.couplings:
            names += c.parameter_names
        return names

    @property
    def n_standard(self) -> int:
        return len(self.standard_names)

    def standard_vector(self, values: dict, default: float = 0.0) -> np.ndarray:
        """Standard-parameter vector from a `{name: value}` mapping.

        Returns
        -------
        numpy.ndarray
            (10 n + extras,) values in the order of `standard_names`, `default` where the
            mapping has none.
        """
        names = self.standard_names
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise KeyError(f"not standard parameters of robot '{self.name}': {', '.join(unknown)}")
        return np.array([values.get(nm, default) for nm in names], dtype=float)

    def limits(self):
        """Arrays (q_min, q_max, qd_max, qdd_max, tau_max), one entry per joint.

        Returns
        -------
        tuple of numpy.ndarray
            `(q_min, q_max, qd_max, qdd_max, tau_max)`, each (n,), in SI units (rad or m, N m or N).
        """
        q_min = np.array([j.q_limits[0] for j in self.joints], dtype=float)
        q_max = np.array([j.q_limits[1] for j in self.joints], dtype=float)
        return (q_min, q_max,
                np.array([j.qd_max for j in self.joints], dtype=float),
                np.array([j.qdd_max for j in self.joints], dtype=float),
                np.array([j.tau_max for j in self.joints], dtype=float))

    def dh_table(self):
        """Rows (j, sigma, alpha, d, theta, r) for joints given in MDH, else None.

        Returns
        -------
        list of tuple or None
            `(j, sigma, alpha, d, theta, r)` per joint (rad, m); None for a URDF robot.
        """
        if any(j.mdh is None for j in self.joints):
            return None
        return [(k + 1, j.sigma) + tuple(j.mdh) for k, j in enumerate(self.joints)]


def model_signature(robot) -> str:
    """A short hash of what an identified model's parameters mean on `robot`.

    The joints' placements, types, friction models and drive gains, gravity and the
    couplings: what the regressor and the torques depend on. Not the name, the limits,
    the controller or the a-priori values, which a model may keep across. Two robot
    files with the same signature take the same identified parameters (`dynid payload
    --model` checks it).

    Returns
    -------
    str
        16 hexadecimal digits.
    """
    h = hashlib.sha256()

    def add(*values):
        for v in values:
            if isinstance(v, str):
                h.update(v.encode() + b"\0")
            else:       # rounded: the same file read on another machine gives the same hash
                h.update((np.round(np.asarray(v, dtype=float), 9) + 0.0).tobytes() + b"\0")   # + 0.0: no -0

    add(len(robot.joints), robot.gravity)
    for j in robot.joints:
        add(j.sigma, j.R, j.p, j.friction, j.drive_gain)
    for c in robot.couplings:
        add(c.motor, c.joints, c.coefficients, float(c.friction))
    return h.hexdigest()[:16]

