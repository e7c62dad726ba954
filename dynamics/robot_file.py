"""Reading robot descriptions: TOML files, URDF files and bundled robots by name.

TOML schema (see `dynamics/robots/tx40.toml` for a complete example)::

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

When `urdf` is given, the `[[joints]]` tables may only add limits, drive
gains and names of existing joints (matched by order); the kinematics and
inertials come from the URDF. `base = "link"` and `tip = "link"` beside
`urdf` select one chain of a branched URDF (see `dynid.dynamics.urdf.read_urdf`).

Every value is checked against the bounds below; names (robot, joints) must
not hold control characters (they are printed on terminals); a-priori names
must be standard parameters of this robot or base names (a standard name
followed by `R`); a-priori masses and inertia diagonals must not be negative.
"""
from __future__ import annotations

import math
import os
import re
import stat
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from dynid.errors import RobotFileError

from .robot import Controller, Coupling, Joint, Robot, mdh_placement

# ----------------------------------------------------------------- bounds
# Limits on what a robot description may say. Each is far beyond any real robot arm
# (the largest industrial arms weigh a few tonnes, reach under 5 m, have under 10
# joints and run their controllers at 1-10 kHz), so they only refuse typing slips and
# unit mix-ups (1e300, a ratio of 1.6e154 that overflowed the regressor, 1e-300 that
# gave NaN base-parameter relations) and inputs that would take minutes and gigabytes
# (a 1000-joint URDF took 6.5 GiB, a 400-joint TOML 3 minutes). Every message says
# the bound and what to do.
MAX_FILE_BYTES = 16 * 2 ** 20     # a robot file; a detailed humanoid URDF is under 1 MiB
MAX_JOINTS = 64                   # moving joints of a robot (a humanoid has ~40)
MAX_URDF_LINKS = 10_000           # links of a URDF, chain or not (a humanoid has ~100)
MAX_LENGTH = 100.0                # m: |d|, |r| of an MDH row, each URDF origin coordinate
MAX_GRAVITY = 100.0               # m/s^2: norm of gravity (10 g; the Earth's is 9.81)
MAX_MASS = 1e5                    # kg: one link's mass (100 t)
MAX_INERTIA = 1e5                 # kg m^2: inertia entries, rotor inertia Ia, controller J_ap
MIN_RATIO, MAX_RATIO = 1e-6, 1e6  # |coupling coefficient|, |its ratio to the motor's|, |drive gain|,
                                  # controller wn (rad/s), zeta, g_ap, ki
MIN_RATE, MAX_RATE = 1.0, 1e6     # Hz: controller rate
MIN_J_AP = 1e-9                   # kg m^2: smallest a-priori joint inertia of the controller
MAX_APRIORI = 1e9                 # |any other a-priori value| (friction, offsets, base parameters)
MAX_NESTING = 32                  # depth of TOML tables/arrays (tx40.toml uses 4)

# C0 and C1 control characters, DEL, and the bidirectional overrides that reorder text on screen
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")
_TEXT_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def shown(text):
    """`text` with its control characters escaped, safe to print in a message."""
    return _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), str(text))


def check_name(name, where, path):
    """Refuse a name with control characters (it would be printed on a terminal as is)."""
    m = _CONTROL.search(name)
    if m:
        raise RobotFileError(f"{path}: {where} '{shown(name)}' holds the control character "
                             f"{shown(m.group())} (at position {m.start() + 1}); names are printed on "
                             f"terminals: remove it")


def _check_text(text, where, path):
    """Free text (descriptions, provenance) may hold tabs and newlines, no other control characters."""
    m = _TEXT_CONTROL.search(text)
    if m:
        raise RobotFileError(f"{path}: {where} holds the control character {shown(m.group())} (at "
                             f"position {m.start() + 1}); it is printed on terminals: remove it")


def read_limited(path, what="robot file"):
    """The bytes of a robot file: a regular file of at most `MAX_FILE_BYTES`, checked before reading."""
    path = Path(path)
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            kind = ("a folder" if stat.S_ISDIR(st.st_mode) else
                    "a named pipe (FIFO)" if stat.S_ISFIFO(st.st_mode) else
                    "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else
                    "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
            raise RobotFileError(f"cannot read {what} '{path}': it is {kind}, not a regular file; "
                                 f"give the path of a .toml or .urdf file")
        if st.st_size > MAX_FILE_BYTES:
            raise RobotFileError(_too_big(path, what))
        # O_NONBLOCK: should the path become a FIFO after the check, opening does not hang
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise RobotFileError(f"cannot read {what} '{path}': it is not a regular file; give "
                                     f"the path of a .toml or .urdf file")
            data = fh.read(MAX_FILE_BYTES + 1)
    except RobotFileError:
        raise
    except OSError as exc:
        raise RobotFileError(f"cannot read {what} '{path}': {exc.strerror}; check the path and that "
                             f"it is a readable file") from None
    except ValueError:      # a path with a NUL byte
        raise RobotFileError(f"cannot read {what} {str(path)!r}: the path is not valid; "
                             f"check the path") from None
    if len(data) > MAX_FILE_BYTES:
        raise RobotFileError(_too_big(path, what))
    return data


def _too_big(path, what):
    return (f"cannot read {what} '{path}': it is larger than {MAX_FILE_BYTES // 2 ** 20} MiB, more "
            f"than any robot description; check that it is the right file")

_JOINT_KEYS = {"name", "sigma", "alpha", "d", "theta", "r", "q_limits", "qd_max", "qdd_max",
               "tau_max", "drive_gain", "friction"}
_TOP_KEYS = {"name", "description", "gravity", "urdf", "base", "tip", "joints", "couplings",
             "controller", "apriori", "provenance"}


def bundled_robots():
    """Names of the robots shipped with dynid."""
    folder = resources.files("dynid.dynamics.robots")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def bundled_path(name):
    return Path(str(resources.files("dynid.dynamics.robots") / f"{name}.toml"))


def load_robot(spec, base=None, tip=None):
    """A robot from a bundled name (`"tx40"`), a `.toml` or a `.urdf` path.

    `base`, `tip`: link names selecting one chain of a URDF (the `.urdf`
    given, or the `urdf` of a TOML file); see `dynid.dynamics.urdf.read_urdf`.

    Returns
    -------
    Robot
        The robot: kinematics, the standard parameter names and a-priori values, the
        controller, drive gains and limits the file gives.
    """
    if isinstance(spec, Robot):
        if base is not None or tip is not None:
            raise RobotFileError(f"robot '{spec.name}': base/tip select a chain when reading a URDF; "
                                 f"give the URDF path instead of a Robot")
        return spec
    spec = str(spec)
    path = Path(spec)
    known = path.suffix.lower() in (".toml", ".urdf", ".xml")
    # A folder or file called "panda" in the working directory must not hide the bundled robot.
    if not known and spec in bundled_robots():
        return read_toml(bundled_path(spec), base=base, tip=tip)
    if known or path.exists():
        if not path.exists():
            raise RobotFileError(f"robot file '{spec}' does not exist; give a path to a .toml or "
                                 f".urdf file, or one of the bundled robots: {', '.join(bundled_robots())}")
        if path.suffix.lower() == ".toml":
            return read_toml(path, base=base, tip=tip)
        if path.suffix.lower() in (".urdf", ".xml"):
            from .urdf import read_urdf
            return read_urdf(path, base=base, tip=tip)
        raise RobotFileError(f"robot file '{spec}': unknown extension '{path.suffix}'; use .toml or .urdf")
    if spec in bundled_robots():
        return read_toml(bundled_path(spec), base=base, tip=tip)
    raise RobotFileError(f"unknown robot '{spec}': not a file and not a bundled robot; give a path "
                         f"to a .toml or .urdf file or one of: {', '.join(bundled_robots())}")


def _num(value, where, path, *, positive=False, allow_inf=False, bounds=None, unit=""):
    """A finite float (`allow_inf`: or +-inf); `bounds=(lo, hi)` on `|value|` (lo: nonzero)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RobotFileError(f"{path}: {where} must be a number, got {_short(value)}")
    try:
        v = float(value)
    except OverflowError:   # an integer beyond float range
        raise RobotFileError(f"{path}: {where} must be a finite number, got an integer too large "
                             f"for a float") from None
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise RobotFileError(f"{path}: {where} must be a finite number, got {value!r}")
    if positive and v <= 0:
        raise RobotFileError(f"{path}: {where} must be positive, got {value!r}")
    if bounds is not None:
        lo, hi = bounds
        if lo and abs(v) < lo:
            raise RobotFileError(f"{path}: {where} = {v:g} is {'0' if v == 0 else 'too small'}; its size "
                                 f"must be at least {lo:g}{unit} (at most {hi:g}{unit}): check the number "
                                 f"and its unit")
        if abs(v) > hi:
            raise RobotFileError(f"{path}: {where} = {v:g} is beyond the {hi:g}{unit} dynid accepts, far "
                                 f"more than a real robot needs; check the number and its unit")
    return v


def _short(value, limit=80):
    """A value's repr, cut short and with control characters escaped, for a message."""
    text = shown(repr(value))
    return text if len(text) <= limit else text[:limit] + "..."


def _vector(value, n, where, path, *, positive=False, bounds=None, unit=""):
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * n
    if not isinstance(value, list) or len(value) != n:
        raise RobotFileError(f"{path}: {where} must be a list of {n} numbers (one per joint), "
                             f"got {_short(value)}")
    return np.array([_num(v, f"{where}[{k + 1}]", path, positive=positive, bounds=bounds, unit=unit)
                     for k, v in enumerate(value)])


def _nesting(doc):
    """Depth of nested tables/arrays of a document, counted without recursion."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        obj, depth = stack.pop()
        deepest = max(deepest, depth)
        if depth > MAX_NESTING:
            return depth
        if isinstance(obj, dict):
            stack.extend((v, depth + 1) for v in obj.values() if isinstance(v, (dict, list)))
        elif isinstance(obj, list):
            stack.extend((v, depth + 1) for v in obj if isinstance(v, (dict, list)))
    return deepest


def read_toml(path, base=None, tip=None):
    """Read and validate a robot description in TOML (`base`/`tip`: chain of its URDF)."""
    path = Path(path)
    data = read_limited(path, "robot file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise RobotFileError(f"robot file '{path}' is not UTF-8 text; save it as UTF-8 TOML") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(f"robot file '{path}' is not valid TOML: {exc}; fix the syntax "
                             f"there (see dynamics/robots/tx40.toml for an example)") from None
    except RecursionError:      # tomllib recurses: arrays nested 500 deep
        raise RobotFileError(f"robot file '{path}': tables or arrays are nested too deeply to read "
                             f"(a robot file needs {MAX_NESTING} levels at most); fix the file") from None
    return robot_from_dict(doc, path, base=base, tip=tip)


def robot_from_dict(doc, path="<robot>", base=None, tip=None):
    """Build a Robot from a parsed TOML document, validating every field."""
    if not isinstance(doc, dict):
        raise RobotFileError(f"{path}: a robot description must be a table of keys, got {_short(doc)}")
    if _nesting(doc) > MAX_NESTING:
        raise RobotFileError(f"{path}: tables or arrays are nested more than {MAX_NESTING} deep; a "
                             f"robot file needs 4 levels: fix the file")
    unknown = sorted(map(str, set(doc) - _TOP_KEYS))
    if unknown:
        raise RobotFileError(f"{path}: unknown top-level key(s) {', '.join(map(shown, unknown))}; "
                             f"allowed: {', '.join(sorted(_TOP_KEYS))}")
    name = doc.get("name")
    if not isinstance(name, str) or not name.strip():
        raise RobotFileError(f"{path}: 'name' (a non-empty string) is required")
    check_name(name, "robot name", path)
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise RobotFileError(f"{path}: 'description' must be a text (a string), got {_short(description)}")
    _check_text(description, "'description'", path)
    gravity = doc.get("gravity", [0.0, 0.0, -9.81])
    if not isinstance(gravity, list) or len(gravity) != 3:
        raise RobotFileError(f"{path}: 'gravity' must be a list of 3 numbers in the base frame, "
                             f"got {_short(gravity)}")
    gravity = np.array([_num(g, f"gravity[{k}]", path, bounds=(0, MAX_GRAVITY), unit=" m/s^2")
                        for k, g in enumerate(gravity)])
    if np.linalg.norm(gravity) > MAX_GRAVITY:
        raise RobotFileError(f"{path}: 'gravity' has norm {np.linalg.norm(gravity):g} m/s^2, beyond the "
                             f"{MAX_GRAVITY:g} m/s^2 dynid accepts (the Earth's is 9.81); check the "
                             f"numbers and their unit (m/s^2)")
    chain = {}
    for key, given in (("base", base), ("tip", tip)):
        in_file = doc.get(key)
        if in_file is not None and "urdf" not in doc:
            raise RobotFileError(f"{path}: '{key}' selects a chain of a URDF, but there is no 'urdf'; "
                                 f"remove '{key}' or add urdf = \"<file>.urdf\"")
        if in_file is not None and (not isinstance(in_file, str) or not in_file):
            raise RobotFileError(f"{path}: '{key}' must be a link name of the URDF (a string), "
                                 f"got {_short(in_file)}")
        if given is not None and in_file is not None and given != in_file:
            raise RobotFileError(f"{path}: {key} {_short(given)} was asked for, but the file says "
                                 f"{key} = {_short(in_file)}; give one of them only")
        chain[key] = given if given is not None else in_file

    if "urdf" in doc:
        from .urdf import read_urdf
        # a non-string 'urdf' is no path, and [[joints]] overrides must be tables
        if not isinstance(doc["urdf"], str) or not doc["urdf"].strip():
            raise RobotFileError(f"{path}: 'urdf' must be the path of a URDF file (a string), "
                                 f"got {_short(doc['urdf'])}")
        urdf_path = Path(path).parent / doc["urdf"]
        from_urdf = read_urdf(urdf_path, base=chain["base"], tip=chain["tip"])
        joints = from_urdf.joints
        overrides = doc.get("joints", [])
        if not isinstance(overrides, list) or not all(isinstance(t, dict) for t in overrides):
            raise RobotFileError(f"{path}: 'joints' must be a list of [[joints]] tables")
        if overrides and len(overrides) != len(joints):
            raise RobotFileError(f"{path}: {len(overrides)} [[joints]] tables but the URDF "
                                 f"'{urdf_path.name}' has {len(joints)} moving joints; give one table "
                                 f"per moving joint, or none")
        for k, (joint, tab) in enumerate(zip(joints, overrides)):
            _apply_joint_options(joint, tab, k, path, kinematics=False)
        apriori = dict(from_urdf.apriori)
        provenance = dict(from_urdf.provenance)
        notices = list(from_urdf.notices)
    else:
        if chain["base"] is not None or chain["tip"] is not None:
            raise RobotFileError(f"{path}: base/tip select a chain of a URDF, but this robot file has "
                                 f"no 'urdf'; remove base/tip, or add urdf = \"<file>.urdf\"")
        tables = doc.get("joints")
        if not isinstance(tables, list) or not tables:
            raise RobotFileError(f"{path}: at least one [[joints]] table is required")
        if len(tables) > MAX_JOINTS:     # the regressor grows with n^2: 400 joints take minutes
            raise RobotFileError(f"{path}: {len(tables)} [[joints]] tables, more than the {MAX_JOINTS} "
                                 f"joints dynid models (the regressor grows as n^2); check the file")
        joints = []
        for k, tab in enumerate(tables):
            if not isinstance(tab, dict):
                raise RobotFileError(f"{path}: joints[{k + 1}] must be a table")
            joint = Joint(name=f"j{k + 1}")
            _apply_joint_options(joint, tab, k, path, kinematics=True)
            joints.append(joint)
        apriori, provenance, notices = {}, {}, []

    names = [j.name for j in joints]
    seen, dup = set(), set()
    for nm in names:
        (dup if nm in seen else seen).add(nm)
    if dup:
        raise RobotFileError(f"{path}: duplicated joint name(s) {', '.join(sorted(dup))}; give every "
                             f"joint a unique name")
    n = len(joints)

    couplings = []
    tabs = doc.get("couplings", [])
    if not isinstance(tabs, list):      # [[couplings]] must be an array of tables
        raise RobotFileError(f"{path}: 'couplings' must be a list of [[couplings]] tables")
    for k, tab in enumerate(tabs):
        couplings.append(_coupling(tab, k, n, path))
    motors = [c.motor for c in couplings]
    if len(set(motors)) != len(motors):  # one motor, one set of names Fvm<j>, Fcm<j>
        raise RobotFileError(f"{path}: two [[couplings]] have the same motor; give each motor "
                             f"one coupling table")

    controller = _controller(doc["controller"], n, path) if "controller" in doc else None

    robot = Robot(name=name, joints=joints, gravity=gravity, couplings=couplings,
                  controller=controller, source=str(path), description=description)
    robot.notices = notices
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise RobotFileError(f"{path}: [provenance] must be a table of texts")
    for k, v in prov.items():
        _check_text(str(k), "a [provenance] key", path)
        _check_text(str(v), f"provenance.{shown(k)}", path)
    provenance.update({str(k): str(v) for k, v in prov.items()})
    robot.provenance = provenance

    ap = doc.get("apriori", {})
    if not isinstance(ap, dict):
        raise RobotFileError(f"{path}: [apriori] must be a table with 'source' and 'values'")
    _no_unknown_keys(ap, ("source", "values", "mass_tolerance"), "[apriori]", path)
    if "mass_tolerance" in ap:
        tol = _num(ap["mass_tolerance"], "apriori.mass_tolerance", path)
        if not 0 <= tol < 10:
            raise RobotFileError(f"{path}: apriori.mass_tolerance must be a fraction of the a-priori mass "
                                 f"between 0 and 10 (0.1 for +-10 %), got {tol:g}")
        robot.mass_tolerance = tol
    values = ap.get("values", {})
    if not isinstance(values, dict):
        raise RobotFileError(f"{path}: apriori.values must be a table of name = number")
    given = {}
    for key, v in values.items():
        given[str(key)] = _num(v, f"apriori.values.{shown(key)}", path)
    if "source" in ap:
        _check_text(str(ap["source"]), "apriori.source", path)
        robot.provenance["apriori"] = str(ap["source"])
    standard = set(robot.standard_names)
    # base names are standard names with an R appended (ZZ1R), not any name holding an R
    bad = [k for k in given if k not in standard and not (k.endswith("R") and k[:-1] in standard)]
    if bad:
        raise RobotFileError(f"{path}: apriori value(s) for unknown parameter(s) "
                             f"{', '.join(shown(b) for b in sorted(bad))} of this {n}-joint robot; use "
                             f"its standard names such as ZZ1, MX2, Ia{min(3, n)}, Fv{n} or base names "
                             f"with R (ZZ1R)")
    for key, v in given.items():
        _apriori_bounds(key, v, key in standard, path)
    apriori.update(given)
    robot.apriori = apriori
    return robot


_NONNEGATIVE = {"M": MAX_MASS, "XX": MAX_INERTIA, "YY": MAX_INERTIA, "ZZ": MAX_INERTIA,
                "Ia": MAX_INERTIA}
_SIGNED = {"XY": MAX_INERTIA, "XZ": MAX_INERTIA, "YZ": MAX_INERTIA}
_UNITS = {"M": "kg"}


def _apriori_bounds(key, v, is_standard, path):
    """Masses, inertia diagonals and rotor inertias are not negative; every value is bounded."""
    where = f"apriori.values.{key}"
    prefix = re.sub(r"\d+$", "", key) if is_standard else None
    unit = " " + _UNITS.get(prefix, "kg m^2") if prefix in _NONNEGATIVE or prefix in _SIGNED else ""
    if prefix in _NONNEGATIVE and v < 0:
        what = "a mass" if prefix == "M" else "an inertia about an axis"
        raise RobotFileError(f"{path}: {where} = {v:g}{unit} is negative; {what} must not be "
                             f"negative: fix it")
    bound = _NONNEGATIVE.get(prefix) or _SIGNED.get(prefix) or MAX_APRIORI
    if abs(v) > bound:
        raise RobotFileError(f"{path}: {where} = {v:g}{unit} is beyond the {bound:g}{unit} dynid "
                             f"accepts, far more than a real robot needs; check the number and its unit")


def _apply_joint_options(joint, tab, k, path, *, kinematics):
    where = f"joints[{k + 1}]"
    unknown = sorted(map(str, set(tab) - _JOINT_KEYS))
    if unknown:
        raise RobotFileError(f"{path}: {where} has unknown key(s) {', '.join(map(shown, unknown))}; "
                             f"allowed: {', '.join(sorted(_JOINT_KEYS))}")
    if "name" in tab:
        if not isinstance(tab["name"], str) or not tab["name"]:
            raise RobotFileError(f"{path}: {where}.name must be a non-empty string")
        check_name(tab["name"], f"{where}.name", path)
        joint.name = tab["name"]
    if kinematics:
        sigma = tab.get("sigma", 0)
        if sigma not in (0, 1) or isinstance(sigma, bool):
            raise RobotFileError(f"{path}: {where}.sigma must be 0 (revolute) or 1 (prismatic), "
                                 f"got {_short(sigma)}")
        vals = [_num(tab.get(key, 0.0), f"{where}.{key}", path,
                     bounds=(0, MAX_LENGTH) if key in ("d", "r") else None,
                     unit=" m" if key in ("d", "r") else "")
                for key in ("alpha", "d", "theta", "r")]
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
        if tab["drive_gain"] == 0 and not isinstance(tab["drive_gain"], bool):
            raise RobotFileError(f"{path}: {where}.drive_gain must not be 0")
        joint.drive_gain = _num(tab["drive_gain"], f"{where}.drive_gain", path,
                                bounds=(MIN_RATIO, MAX_RATIO))
    if "friction" in tab:
        if tab["friction"] not in ("viscous_coulomb",):
            raise RobotFileError(f"{path}: {where}.friction must be 'viscous_coulomb', "
                                 f"got {_short(tab['friction'])}")
        joint.friction = tab["friction"]


def _no_unknown_keys(tab, allowed, where, path):
    unknown = sorted(set(tab) - set(allowed))
    if unknown:
        raise RobotFileError(f"{path}: {where} has unknown key(s) {', '.join(map(shown, unknown))}; "
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
    # True is an int to Python, and a joint listed twice would count twice
    if (not isinstance(joints, list) or len(set(map(repr, joints))) != len(joints)
            or not all(isinstance(j, int) and not isinstance(j, bool) and 1 <= j <= n for j in joints)):
        raise RobotFileError(f"{path}: {where}.joints must be a list of distinct joint numbers "
                             f"1..{n}, got {_short(joints)}")
    if not isinstance(coef, list) or len(coef) != len(joints):
        raise RobotFileError(f"{path}: {where}.coefficients must have one number per joint in 'joints'")
    coef = [_num(c, f"{where}.coefficients", path) for c in coef]
    motor = tab["motor"]
    if not isinstance(motor, int) or isinstance(motor, bool) or motor not in joints:
        raise RobotFileError(f"{path}: {where}.motor must be one of its joints {joints}, got {_short(motor)}")
    c_motor = coef[joints.index(motor)]
    if c_motor == 0.0:   # the regressor divides by it
        raise RobotFileError(f"{path}: {where}.coefficients: the motor joint's coefficient must not be 0")
    # finite but absurd ratios (1.6e154, 1e-300) overflow the regressor or the base relations
    checks = ([(j, f"coefficient of joint {j}", c) for j, c in zip(joints, coef)]
              + [(j, f"ratio of joint {j}'s coefficient to the motor's", c / c_motor)
                 for j, c in zip(joints, coef)])
    for j, label, v in checks:
        if not MIN_RATIO <= abs(v) <= MAX_RATIO:
            raise RobotFileError(
                f"{path}: {where}.coefficients: the {label} is {v:g}; its size must be between "
                f"{MIN_RATIO:g} and {MAX_RATIO:g} (a gear ratio, or a joint the motor does not "
                f"drive): check the numbers" + ("" if j == motor else
                                                 f", or remove joint {j} from {where}.joints"))
    friction = tab.get("friction", True)
    if not isinstance(friction, bool):     # "no" or 0 must not pass as a truth value
        raise RobotFileError(f"{path}: {where}.friction must be true or false, got {_short(friction)}")
    return Coupling(motor=motor, joints=tuple(joints), coefficients=tuple(coef), friction=friction)


def _controller(tab, n, path):
    if not isinstance(tab, dict):
        raise RobotFileError(f"{path}: [controller] must be a table")
    _no_unknown_keys(tab, ("kind", "rate", "wn", "zeta", "J_ap", "g_ap", "ki"), "[controller]", path)
    kind = tab.get("kind", "pd")
    if kind not in ("pd", "pid"):
        raise RobotFileError(f"{path}: controller.kind must be 'pd' or 'pid', got {_short(kind)}")
    rate = _num(tab.get("rate", 1000.0), "controller.rate", path, positive=True)
    if not MIN_RATE <= rate <= MAX_RATE:
        raise RobotFileError(f"{path}: controller.rate = {rate:g} Hz; it must be between {MIN_RATE:g} Hz "
                             f"and {MAX_RATE:g} Hz: check the number and its unit (Hz)")
    for key in ("wn", "zeta", "J_ap"):
        if key not in tab:
            raise RobotFileError(f"{path}: controller.{key} is required (one value per joint)")
    ratio = dict(positive=True, bounds=(MIN_RATIO, MAX_RATIO))
    c = Controller(kind=kind, rate=rate,
                   wn=_vector(tab["wn"], n, "controller.wn", path, unit=" rad/s", **ratio),
                   zeta=_vector(tab["zeta"], n, "controller.zeta", path, **ratio),
                   J_ap=_vector(tab["J_ap"], n, "controller.J_ap", path, positive=True,
                                bounds=(MIN_J_AP, MAX_INERTIA), unit=" kg m^2"),
                   g_ap=_vector(tab.get("g_ap", 1.0), n, "controller.g_ap", path, **ratio))
    if kind == "pid":
        c.ki = _vector(tab.get("ki", 0.0), n, "controller.ki", path, bounds=(0, MAX_RATIO))
    return c
