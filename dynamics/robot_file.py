"""Reading robot descriptions: TOML files, URDF files and bundled robots by name.

TOML schema (see ``dynamics/robots/tx40.toml`` for a complete example)::

    name = "tx40"
    gravity = [0.0, 0.0, -9.81]        # base frame, m/s^2
    urdf = "arm.urdf"                  # optional: kinematics + inertials from a URDF

    [[joints]]                         # one table per joint, base to tip
    name = "j1"
    sigma = 0                          # 0 revolute, 1 prismatic
    alpha = 0.0                        # modified DH (Khalil-Kleinfinger), rad and m
    d = 0.0
    theta = 0.0                        # theta offset (revolute) / theta (prismatic)
    r = 0.0                            # r (revolute) / r offset (prismatic)
    q_limits = [-3.14, 3.14]           # optional limits
    qd_max = 5.0
    qdd_max = 30.0
    tau_max = 130.0
    drive_gain = 1.0                   # torque = drive_gain * control signal

    [[couplings]]                      # a motor turning with several joints
    motor = 6
    joints = [5, 6]
    coefficients = [1.0, 1.0]
    friction = true                    # adds Fvm6, Fcm6

    [controller]                       # needed by closed-loop methods
    kind = "pd"                        # "pd" or "pid"
    rate = 5000.0                      # Hz
    wn = [...]; zeta = [...]; J_ap = [...]; g_ap = [...]

    [apriori]                          # optional a-priori parameter values
    source = "where the numbers come from"
    values = { Fv1 = 8.05, Ia3 = 0.0988 }

    [provenance]                       # free text per topic
    kinematics = "Table 1 of ..."

When ``urdf`` is given, the ``[[joints]]`` tables may only add limits, drive
gains and names of existing joints (matched by order); the kinematics and
inertials come from the URDF.
"""
from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from dynid.errors import RobotFileError
from .robot import Controller, Coupling, Joint, Robot, mdh_placement

_JOINT_KEYS = {"name", "sigma", "alpha", "d", "theta", "r", "q_limits", "qd_max", "qdd_max",
               "tau_max", "drive_gain", "friction"}
_TOP_KEYS = {"name", "description", "gravity", "urdf", "joints", "couplings", "controller",
             "apriori", "provenance"}


def bundled_robots():
    """Names of the robots shipped with dynid."""
    folder = resources.files("dynid.dynamics.robots")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def bundled_path(name):
    return Path(str(resources.files("dynid.dynamics.robots") / f"{name}.toml"))


def load_robot(spec):
    """A robot from a bundled name (``"tx40"``), a ``.toml`` or a ``.urdf`` path."""
    if isinstance(spec, Robot):
        return spec
    spec = str(spec)
    path = Path(spec)
    if path.suffix.lower() in (".toml", ".urdf", ".xml") or path.exists():
        if not path.exists():
            raise RobotFileError(f"robot file '{spec}' does not exist; give a path to a .toml or "
                                 f".urdf file, or one of the bundled robots: {', '.join(bundled_robots())}")
        if path.suffix.lower() == ".toml":
            return read_toml(path)
        if path.suffix.lower() in (".urdf", ".xml"):
            from .urdf import read_urdf
            return read_urdf(path)
        raise RobotFileError(f"robot file '{spec}': unknown extension '{path.suffix}'; use .toml or .urdf")
    if spec in bundled_robots():
        return read_toml(bundled_path(spec))
    raise RobotFileError(f"unknown robot '{spec}': not a file and not a bundled robot; give a path "
                         f"to a .toml or .urdf file or one of: {', '.join(bundled_robots())}")


def _num(value, where, path, *, positive=False, allow_inf=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RobotFileError(f"{path}: {where} must be a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:   # fix: a huge integer crashed with OverflowError
        raise RobotFileError(f"{path}: {where} must be a finite number, got an integer too large "
                             f"for a float") from None
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise RobotFileError(f"{path}: {where} must be a finite number, got {value!r}")
    if positive and v <= 0:
        raise RobotFileError(f"{path}: {where} must be positive, got {value!r}")
    return v


def _vector(value, n, where, path, *, positive=False):
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * n
    if not isinstance(value, list) or len(value) != n:
        raise RobotFileError(f"{path}: {where} must be a list of {n} numbers (one per joint), got {value!r}")
    return np.array([_num(v, f"{where}[{k + 1}]", path, positive=positive) for k, v in enumerate(value)])


def read_toml(path):
    """Read and validate a robot description in TOML."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RobotFileError(f"cannot read robot file '{path}': {exc.strerror}; check the path and "
                             f"that it is a readable file") from None
    except UnicodeDecodeError:
        raise RobotFileError(f"robot file '{path}' is not UTF-8 text; save it as UTF-8 TOML") from None
    except ValueError:      # fix: a path with a NUL byte raised ValueError
        raise RobotFileError(f"cannot read robot file {str(path)!r}: the path is not valid; "
                             f"check the path") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(f"robot file '{path}' is not valid TOML: {exc}; fix the syntax "
                             f"there (see dynamics/robots/tx40.toml for an example)") from None
    return robot_from_dict(doc, path)


def robot_from_dict(doc, path="<robot>"):
    """Build a Robot from a parsed TOML document, validating every field."""
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise RobotFileError(f"{path}: unknown top-level key(s) {', '.join(unknown)}; "
                             f"allowed: {', '.join(sorted(_TOP_KEYS))}")
    name = doc.get("name")
    if not isinstance(name, str) or not name.strip():
        raise RobotFileError(f"{path}: 'name' (a non-empty string) is required")
    gravity = doc.get("gravity", [0.0, 0.0, -9.81])
    if not isinstance(gravity, list) or len(gravity) != 3:
        raise RobotFileError(f"{path}: 'gravity' must be a list of 3 numbers in the base frame, got {gravity!r}")
    gravity = np.array([_num(g, f"gravity[{k}]", path) for k, g in enumerate(gravity)])

    if "urdf" in doc:
        from .urdf import read_urdf
        # fix: a non-string 'urdf' was turned into a path, non-list/non-table
        # [[joints]] overrides crashed with TypeError
        if not isinstance(doc["urdf"], str) or not doc["urdf"].strip():
            raise RobotFileError(f"{path}: 'urdf' must be the path of a URDF file (a string), "
                                 f"got {doc['urdf']!r}")
        urdf_path = Path(path).parent / doc["urdf"]
        base = read_urdf(urdf_path)
        joints = base.joints
        overrides = doc.get("joints", [])
        if not isinstance(overrides, list) or not all(isinstance(t, dict) for t in overrides):
            raise RobotFileError(f"{path}: 'joints' must be a list of [[joints]] tables")
        if overrides and len(overrides) != len(joints):
            raise RobotFileError(f"{path}: {len(overrides)} [[joints]] tables but the URDF "
                                 f"'{urdf_path.name}' has {len(joints)} moving joints")
        for k, (joint, tab) in enumerate(zip(joints, overrides)):
            _apply_joint_options(joint, tab, k, path, kinematics=False)
        apriori = dict(base.apriori)
        provenance = dict(base.provenance)
    else:
        tables = doc.get("joints")
        if not isinstance(tables, list) or not tables:
            raise RobotFileError(f"{path}: at least one [[joints]] table is required")
        joints = []
        for k, tab in enumerate(tables):
            if not isinstance(tab, dict):
                raise RobotFileError(f"{path}: joints[{k + 1}] must be a table")
            joint = Joint(name=f"j{k + 1}")
            _apply_joint_options(joint, tab, k, path, kinematics=True)
            joints.append(joint)
        apriori, provenance = {}, {}

    names = [j.name for j in joints]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise RobotFileError(f"{path}: duplicated joint name(s) {', '.join(dup)}; give every "
                             f"joint a unique name")
    n = len(joints)

    couplings = []
    tabs = doc.get("couplings", [])
    if not isinstance(tabs, list):      # fix: a non-list crashed with TypeError
        raise RobotFileError(f"{path}: 'couplings' must be a list of [[couplings]] tables")
    for k, tab in enumerate(tabs):
        couplings.append(_coupling(tab, k, n, path))
    motors = [c.motor for c in couplings]
    if len(set(motors)) != len(motors):  # fix: duplicated parameter names Fvm<j>, Fcm<j>
        raise RobotFileError(f"{path}: two [[couplings]] have the same motor; give each motor "
                             f"one coupling table")

    controller = _controller(doc["controller"], n, path) if "controller" in doc else None

    robot = Robot(name=name, joints=joints, gravity=gravity, couplings=couplings,
                  controller=controller, source=str(path),
                  description=str(doc.get("description", "")))
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise RobotFileError(f"{path}: [provenance] must be a table of texts")
    provenance.update({str(k): str(v) for k, v in prov.items()})
    robot.provenance = provenance

    ap = doc.get("apriori", {})
    if not isinstance(ap, dict):
        raise RobotFileError(f"{path}: [apriori] must be a table with 'source' and 'values'")
    values = ap.get("values", {})
    if not isinstance(values, dict):
        raise RobotFileError(f"{path}: apriori.values must be a table of name = number")
    for key, v in values.items():
        apriori[str(key)] = _num(v, f"apriori.values.{key}", path)
    if "source" in ap:
        robot.provenance["apriori"] = str(ap["source"])
    standard = set(robot.standard_names)
    bad = [k for k in apriori if k not in standard and not _looks_like_base(k)]
    if bad:
        raise RobotFileError(f"{path}: apriori value(s) for unknown parameter(s) {', '.join(sorted(bad))}; "
                             f"use standard names such as ZZ1, MX2, Ia3, Fv4 or base names with R (ZZ1R)")
    robot.apriori = apriori
    return robot


def _looks_like_base(name):
    return name.endswith("R") or "R" in name


def _apply_joint_options(joint, tab, k, path, *, kinematics):
    where = f"joints[{k + 1}]"
    unknown = sorted(set(tab) - _JOINT_KEYS)
    if unknown:
        raise RobotFileError(f"{path}: {where} has unknown key(s) {', '.join(unknown)}; "
                             f"allowed: {', '.join(sorted(_JOINT_KEYS))}")
    if "name" in tab:
        if not isinstance(tab["name"], str) or not tab["name"]:
            raise RobotFileError(f"{path}: {where}.name must be a non-empty string")
        joint.name = tab["name"]
    if kinematics:
        sigma = tab.get("sigma", 0)
        if sigma not in (0, 1) or isinstance(sigma, bool):
            raise RobotFileError(f"{path}: {where}.sigma must be 0 (revolute) or 1 (prismatic), got {sigma!r}")
        vals = [_num(tab.get(key, 0.0), f"{where}.{key}", path) for key in ("alpha", "d", "theta", "r")]
        joint.sigma = int(sigma)
        joint.mdh = tuple(vals)
        joint.R, joint.p = mdh_placement(*vals)
    elif any(key in tab for key in ("sigma", "alpha", "d", "theta", "r")):
        raise RobotFileError(f"{path}: {where} gives kinematics, but they come from the URDF; remove "
                             f"sigma/alpha/d/theta/r there")
    if "q_limits" in tab:
        lim = tab["q_limits"]
        if not isinstance(lim, list) or len(lim) != 2:
            raise RobotFileError(f"{path}: {where}.q_limits must be [lower, upper]")
        lo, hi = (_num(v, f"{where}.q_limits", path, allow_inf=True) for v in lim)
        if not lo < hi:
            raise RobotFileError(f"{path}: {where}.q_limits lower {lo} must be below upper {hi}")
        joint.q_limits = (lo, hi)
    for key in ("qd_max", "qdd_max", "tau_max"):
        if key in tab:
            setattr(joint, key, _num(tab[key], f"{where}.{key}", path, positive=True, allow_inf=True))
    if "drive_gain" in tab:
        joint.drive_gain = _num(tab["drive_gain"], f"{where}.drive_gain", path)
        if joint.drive_gain == 0:
            raise RobotFileError(f"{path}: {where}.drive_gain must not be 0")
    if "friction" in tab:
        if tab["friction"] not in ("viscous_coulomb",):
            raise RobotFileError(f"{path}: {where}.friction must be 'viscous_coulomb', got {tab['friction']!r}")
        joint.friction = tab["friction"]


def _no_unknown_keys(tab, allowed, where, path):
    unknown = sorted(set(tab) - set(allowed))
    if unknown:
        raise RobotFileError(f"{path}: {where} has unknown key(s) {', '.join(map(str, unknown))}; "
                             f"allowed: {', '.join(sorted(allowed))}. Check the spelling.")


def _coupling(tab, k, n, path):
    where = f"couplings[{k + 1}]"
    if not isinstance(tab, dict):
        raise RobotFileError(f"{path}: {where} must be a table")
    _no_unknown_keys(tab, ("motor", "joints", "coefficients", "friction"), where, path)
    for key in ("motor", "joints", "coefficients"):
        if key not in tab:
            raise RobotFileError(f"{path}: {where} needs '{key}'")
    joints = tab["joints"]
    coef = tab["coefficients"]
    # fix: booleans passed as joint numbers and repeated joints were accepted
    if (not isinstance(joints, list) or len(set(map(repr, joints))) != len(joints)
            or not all(isinstance(j, int) and not isinstance(j, bool) and 1 <= j <= n for j in joints)):
        raise RobotFileError(f"{path}: {where}.joints must be a list of distinct joint numbers "
                             f"1..{n}, got {joints!r}")
    if not isinstance(coef, list) or len(coef) != len(joints):
        raise RobotFileError(f"{path}: {where}.coefficients must have one number per joint in 'joints'")
    coef = [_num(c, f"{where}.coefficients", path) for c in coef]
    motor = tab["motor"]
    if not isinstance(motor, int) or isinstance(motor, bool) or motor not in joints:
        raise RobotFileError(f"{path}: {where}.motor must be one of its joints {joints}, got {motor!r}")
    if coef[joints.index(motor)] == 0.0:   # fix: divided by zero in the regressor (NaN columns)
        raise RobotFileError(f"{path}: {where}.coefficients: the motor joint's coefficient must not be 0")
    friction = tab.get("friction", True)
    if not isinstance(friction, bool):     # fix: any value was taken as a truth value
        raise RobotFileError(f"{path}: {where}.friction must be true or false, got {friction!r}")
    return Coupling(motor=motor, joints=tuple(joints), coefficients=tuple(coef), friction=friction)


def _controller(tab, n, path):
    if not isinstance(tab, dict):
        raise RobotFileError(f"{path}: [controller] must be a table")
    _no_unknown_keys(tab, ("kind", "rate", "wn", "zeta", "J_ap", "g_ap", "ki"), "[controller]", path)
    kind = tab.get("kind", "pd")
    if kind not in ("pd", "pid"):
        raise RobotFileError(f"{path}: controller.kind must be 'pd' or 'pid', got {kind!r}")
    rate = _num(tab.get("rate", 1000.0), "controller.rate", path, positive=True)
    for key in ("wn", "zeta", "J_ap"):
        if key not in tab:
            raise RobotFileError(f"{path}: controller.{key} is required (one value per joint)")
    c = Controller(kind=kind, rate=rate,
                   wn=_vector(tab["wn"], n, "controller.wn", path, positive=True),
                   zeta=_vector(tab["zeta"], n, "controller.zeta", path, positive=True),
                   J_ap=_vector(tab["J_ap"], n, "controller.J_ap", path, positive=True),
                   g_ap=_vector(tab.get("g_ap", 1.0), n, "controller.g_ap", path, positive=True))
    if kind == "pid":
        c.ki = _vector(tab.get("ki", 0.0), n, "controller.ki", path)
    return c
