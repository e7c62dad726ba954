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
The fields, their units and ranges are the tables `JOINT_FIELDS` and
`CONTROLLER_FIELDS`; the shared checks live in `robot_checks`.
"""
from __future__ import annotations

import math
import re
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from dynid.errors import RobotFileError

from .robot import Controller, Coupling, Joint, Robot, mdh_placement
from .robot_checks import (  # noqa: F401  (MAX_*, check_name, read_limited, shown: importable from here)
    MAX_ACCEL,
    MAX_ANGLE,
    MAX_APRIORI,
    MAX_EFFORT,
    MAX_FILE_BYTES,
    MAX_GRAVITY,
    MAX_INERTIA,
    MAX_JOINTS,
    MAX_LENGTH,
    MAX_MASS,
    MAX_NESTING,
    MAX_RATE,
    MAX_RATIO,
    MAX_SPEED,
    MAX_TRAVEL,
    MAX_URDF_LINKS,
    MIN_J_AP,
    MIN_RATE,
    MIN_RATIO,
    MIN_SPEED,
    Number,
    check_name,
    check_text,
    nesting,
    no_unknown_keys,
    number,
    radians_hint,
    read_limited,
    short,
    shown,
)
from .urdf import INERTIA_RTOL, read_urdf, snap_notice, snap_right_angle
from .urdf_writer import pseudo_inertia

# ----------------------------------------------------------------- the fields
# Every numeric field of a robot file with its unit and finite physical range
# (see robot_checks for why each bound is where it is). A new field is one row.
_LENGTH = Number(unit=" m", bounds=(0, MAX_LENGTH))
_ANGLE = Number(unit=" rad", bounds=(0, MAX_ANGLE), hint=radians_hint)
_RATIO = Number(positive=True, bounds=(MIN_RATIO, MAX_RATIO))

#: [[joints]]: modified DH row (Khalil-Kleinfinger), limits and drive gain
JOINT_FIELDS = {
    "alpha": _ANGLE, "d": _LENGTH, "theta": _ANGLE, "r": _LENGTH,
    "qd_max": Number(unit=" rad/s (m/s)", positive=True, allow_inf=True, bounds=(MIN_SPEED, MAX_SPEED)),
    "qdd_max": Number(positive=True, allow_inf=True, bounds=(0, MAX_ACCEL)),
    "tau_max": Number(positive=True, allow_inf=True, bounds=(0, MAX_EFFORT)),
    "drive_gain": Number(bounds=(MIN_RATIO, MAX_RATIO)),
}
_KINEMATICS = ("alpha", "d", "theta", "r")
_Q_LIMIT = Number(allow_inf=True, bounds=(0, MAX_TRAVEL))      # each of [lower, upper]

#: [controller]: rate (a number) and per-joint gains (a number or one per joint), with defaults
CONTROLLER_FIELDS = {
    "rate": (Number(unit=" Hz", positive=True, bounds=(MIN_RATE, MAX_RATE)), 1000.0),
    "wn": (Number(unit=" rad/s", positive=True, bounds=(MIN_RATIO, MAX_RATIO)), None),
    "zeta": (_RATIO, None),
    "J_ap": (Number(unit=" kg m^2", positive=True, bounds=(MIN_J_AP, MAX_INERTIA)), None),
    "g_ap": (_RATIO, 1.0),
    "ki": (Number(nonnegative=True, bounds=(0, MAX_RATIO)), 0.0),   # "pid" only
}

_GRAVITY = Number(unit=" m/s^2", bounds=(0, MAX_GRAVITY))
_JOINT_KEYS = {"name", "sigma", "q_limits", "friction", *JOINT_FIELDS}
_TOP_KEYS = {"name", "description", "gravity", "urdf", "base", "tip", "joints", "couplings",
             "controller", "apriori", "provenance"}


_ROBOT_SUFFIXES = (".toml", ".urdf", ".xml")


def bundled_robots():
    """Names of the robots shipped with dynid."""
    folder = resources.files("dynid.dynamics.robots")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def is_bundled_name(spec) -> bool:
    """`spec` names a bundled robot (`"tx40"`), not a robot file: `load_robot`'s rule."""
    spec = str(spec)
    return Path(spec).suffix.lower() not in _ROBOT_SUFFIXES and spec in bundled_robots()


def bundled_path(name):
    return Path(str(resources.files("dynid.dynamics.robots") / f"{name}.toml"))


def load_robot(spec, base=None, tip=None):
    """A robot from a bundled name (`"tx40"`), a `.toml` or a `.urdf` path.

    `base`, `tip`: link names selecting one chain of a URDF (the `.urdf`
    given, or the `urdf` of a TOML file); see `dynid.dynamics.urdf.read_urdf`.

    Parameters
    ----------
    spec : str, path or Robot
        A bundled robot's name (`dynid.dynamics.robot_file.bundled_robots`), or the path
        of a `.toml` or `.urdf` (`.xml`) robot file. A Robot is returned as it is.
    base : str, optional
        The link the chain starts from. Default None: the TOML file's `base`, else the
        URDF's root link.
    tip : str, optional
        The link the chain ends at. Default None: the TOML file's `tip`, else the end of
        the URDF's only moving chain.

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
    known = path.suffix.lower() in _ROBOT_SUFFIXES
    # A folder or file called "panda" in the working directory must not hide the bundled robot.
    if is_bundled_name(spec):
        return read_toml(bundled_path(spec), base=base, tip=tip)
    if known or path.exists():
        if not path.exists():
            raise RobotFileError(f"robot file '{spec}' does not exist; give a path to a .toml or "
                                 f".urdf file, or one of the bundled robots: {', '.join(bundled_robots())}")
        if path.suffix.lower() == ".toml":
            return read_toml(path, base=base, tip=tip)
        if path.suffix.lower() in (".urdf", ".xml"):
            return read_urdf(path, base=base, tip=tip)
        if path.is_dir():
            raise RobotFileError(f"robot file '{spec}' is a folder; give a .toml or .urdf file in it, or one of "
                                 f"the bundled robots: {', '.join(bundled_robots())}")
        raise RobotFileError(f"robot file '{spec}': unknown extension '{path.suffix}'; use .toml or .urdf")
    if spec in bundled_robots():
        return read_toml(bundled_path(spec), base=base, tip=tip)
    raise RobotFileError(f"unknown robot '{spec}': not a file and not a bundled robot; give a path "
                         f"to a .toml or .urdf file or one of: {', '.join(bundled_robots())}")


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
    """Build a Robot from a parsed TOML document, validating every field.

    Parameters
    ----------
    doc : dict
        The parsed document (see the module docstring for its schema).
    path : str or Path
        Named in every message.
    base, tip : str, optional
        Link names selecting one chain of the document's URDF.

    Returns
    -------
    Robot

    Raises
    ------
    RobotFileError
        One message naming the file, the field and what to do.
    """
    _check_document(doc, path)
    name = _robot_name(doc, path)
    description = _description(doc, path)
    gravity = _gravity(doc, path)
    chain = _chain(doc, base, tip, path)
    if "urdf" in doc:
        joints, apriori, provenance, notices = _joints_from_urdf(doc, chain, path)
    else:
        joints, apriori, provenance, notices = _joints_from_tables(doc, chain, path)
    _check_unique_names(joints, path)
    n = len(joints)
    couplings = _couplings(doc, n, path)
    controller = (_controller(doc["controller"], n, path, [j.name for j in joints])
                  if "controller" in doc else None)
    robot = Robot(name=name, joints=joints, gravity=gravity, couplings=couplings,
                  controller=controller, source=str(path), description=description)
    robot.notices = notices
    provenance.update(_provenance(doc, path))
    robot.provenance = provenance
    _apply_apriori(robot, doc, apriori, path)
    return robot


def _check_document(doc, path):
    if not isinstance(doc, dict):
        raise RobotFileError(f"{path}: a robot description must be a table of keys, got {short(doc)}")
    if nesting(doc) > MAX_NESTING:
        raise RobotFileError(f"{path}: tables or arrays are nested more than {MAX_NESTING} deep; a "
                             f"robot file needs 4 levels: fix the file")
    unknown = sorted(map(str, set(doc) - _TOP_KEYS))
    if unknown and "experiment" in doc:
        raise RobotFileError(f"{path} is an experiment description (a recording), not a robot file: give it "
                             "as the data, and the robot with --robot (a bundled name, a robot TOML or a URDF)")
    if unknown:
        raise RobotFileError(f"{path}: unknown top-level key(s) {', '.join(map(shown, unknown))}; "
                             f"allowed: {', '.join(sorted(_TOP_KEYS))}")


def _robot_name(doc, path):
    name = doc.get("name")
    if not isinstance(name, str) or not name.strip():
        raise RobotFileError(f"{path}: 'name' (a non-empty string) is required")
    check_name(name, "robot name", path)
    return name


def _description(doc, path):
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise RobotFileError(f"{path}: 'description' must be a text (a string), got {short(description)}")
    check_text(description, "'description'", path)
    return description


def _gravity(doc, path):
    gravity = doc.get("gravity", [0.0, 0.0, -9.81])
    if not isinstance(gravity, list) or len(gravity) != 3:
        raise RobotFileError(f"{path}: 'gravity' must be a list of 3 numbers in the base frame, "
                             f"got {short(gravity)}")
    gravity = np.array([_GRAVITY(g, f"gravity[{k}]", path) for k, g in enumerate(gravity)])
    if np.linalg.norm(gravity) > MAX_GRAVITY:
        raise RobotFileError(f"{path}: 'gravity' has norm {np.linalg.norm(gravity):g} m/s^2, beyond the "
                             f"{MAX_GRAVITY:g} m/s^2 dynid accepts (the Earth's is 9.81); check the "
                             f"numbers and their unit (m/s^2)")
    return gravity


def _chain(doc, base, tip, path):
    """The base and tip links of the URDF chain: from the call or from the file, not both."""
    chain = {}
    for key, given in (("base", base), ("tip", tip)):
        in_file = doc.get(key)
        if in_file is not None and "urdf" not in doc:
            raise RobotFileError(f"{path}: '{key}' selects a chain of a URDF, but there is no 'urdf'; "
                                 f"remove '{key}' or add urdf = \"<file>.urdf\"")
        if in_file is not None and (not isinstance(in_file, str) or not in_file):
            raise RobotFileError(f"{path}: '{key}' must be a link name of the URDF (a string), "
                                 f"got {short(in_file)}")
        if given is not None and in_file is not None and given != in_file:
            raise RobotFileError(f"{path}: {key} {short(given)} was asked for, but the file says "
                                 f"{key} = {short(in_file)}; give one of them only")
        chain[key] = given if given is not None else in_file
    return chain


def _joints_from_urdf(doc, chain, path):
    """Joints, a-priori values, provenance and notices of the URDF, with the [[joints]] overrides."""
    # a non-string 'urdf' is no path, and [[joints]] overrides must be tables
    if not isinstance(doc["urdf"], str) or not doc["urdf"].strip():
        raise RobotFileError(f"{path}: 'urdf' must be the path of a URDF file (a string), "
                             f"got {short(doc['urdf'])}")
    urdf_path = Path(path).parent / doc["urdf"]
    if urdf_path.is_dir():
        raise RobotFileError(f"{path}: urdf = {doc['urdf']!r} is a folder ({urdf_path}); give the .urdf file "
                             f"in it (the path is relative to the robot file's folder)")
    if not urdf_path.is_file():
        raise RobotFileError(f"{path}: urdf = {doc['urdf']!r}: no such file ({urdf_path}); the path is "
                             f"relative to the robot file's folder")
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
    return joints, dict(from_urdf.apriori), dict(from_urdf.provenance), list(from_urdf.notices)


def _joints_from_tables(doc, chain, path):
    """Joints from the [[joints]] tables (modified DH rows); no a-priori values, provenance or notices yet."""
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
    snapped = []
    for k, tab in enumerate(tables):
        if not isinstance(tab, dict):
            raise RobotFileError(f"{path}: joints[{k + 1}] must be a table")
        joint = Joint(name=f"j{k + 1}")
        _apply_joint_options(joint, tab, k, path, kinematics=True)
        joints.append(joint)
        # the angles `_set_kinematics` took as right angles: those that differ from the file's
        snapped += [f"joints[{k + 1}].{key} = {float(tab[key])!r} as {joint.mdh[i]!r}"
                    for i, key in ((0, "alpha"), (2, "theta")) if key in tab and float(tab[key]) != joint.mdh[i]]
    return joints, {}, {}, snap_notice(Path(path).name, snapped)


def _check_unique_names(joints, path):
    seen, dup = set(), set()
    for nm in (j.name for j in joints):
        (dup if nm in seen else seen).add(nm)
    if dup:
        raise RobotFileError(f"{path}: duplicated joint name(s) {', '.join(sorted(dup))}; give every "
                             f"joint a unique name")


def _couplings(doc, n, path):
    tabs = doc.get("couplings", [])
    if not isinstance(tabs, list):      # [[couplings]] must be an array of tables
        raise RobotFileError(f"{path}: 'couplings' must be a list of [[couplings]] tables")
    couplings = [_coupling(tab, k, n, path) for k, tab in enumerate(tabs)]
    motors = [c.motor for c in couplings]
    if len(set(motors)) != len(motors):  # one motor, one set of names Fvm<j>, Fcm<j>
        raise RobotFileError(f"{path}: two [[couplings]] have the same motor; give each motor "
                             f"one coupling table")
    return couplings


def _provenance(doc, path):
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise RobotFileError(f"{path}: [provenance] must be a table of texts")
    for k, v in prov.items():
        check_text(str(k), "a [provenance] key", path)
        check_text(str(v), f"provenance.{shown(k)}", path)
    return {str(k): str(v) for k, v in prov.items()}


def _apply_apriori(robot, doc, apriori, path):
    """Check [apriori] and set the robot's a-priori values (over the URDF's), mass tolerance and source."""
    ap = doc.get("apriori", {})
    if not isinstance(ap, dict):
        raise RobotFileError(f"{path}: [apriori] must be a table with 'source' and 'values'")
    no_unknown_keys(ap, ("source", "values", "mass_tolerance"), "[apriori]", path)
    if "mass_tolerance" in ap:
        tol = number(ap["mass_tolerance"], "apriori.mass_tolerance", path)
        if not 0 <= tol < 10:
            raise RobotFileError(f"{path}: apriori.mass_tolerance must be a fraction of the a-priori mass "
                                 f"between 0 and 10 (0.1 for +-10 %), got {tol:g}")
        robot.mass_tolerance = tol
    values = ap.get("values", {})
    if not isinstance(values, dict):
        raise RobotFileError(f"{path}: apriori.values must be a table of name = number")
    given = {str(key): number(v, f"apriori.values.{shown(key)}", path) for key, v in values.items()}
    if "source" in ap:
        check_text(str(ap["source"]), "apriori.source", path)
        robot.provenance["apriori"] = str(ap["source"])
    standard = set(robot.standard_names)
    n = robot.n_joints
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
    _centres_of_mass(apriori, robot, path)
    both = sorted(k[:-1] for k in given if k.endswith("R") and k[:-1] in given)
    if both:        # legal, but one of each pair is not what the a-priori base vector takes
        robot.notices.append(f"{path}: apriori.values give {', '.join(f'{k} and {k}R' for k in both)}: with base "
                             "names (R) the a-priori base vector takes the base value, and standard values that "
                             "are not base parameters themselves are not used")
    if set(apriori) <= standard:
        # standard values are a mass distribution per link; beside base names (R) they are not used as
        # one (dynamics.excitation_measures.apriori_parameters reads the base names as they are)
        # the links [apriori] gives values of (a URDF's inertials were checked by its reader)
        _links_realizable(apriori, robot, path, {int(m.group(1)) for k in given
                                                 if (m := re.fullmatch(r"(?:XX|XY|XZ|YY|YZ|ZZ|MX|MY|MZ|M)(\d+)", k))})
    robot.apriori = apriori


_NONNEGATIVE = {"M": MAX_MASS, "XX": MAX_INERTIA, "YY": MAX_INERTIA, "ZZ": MAX_INERTIA,
                "Ia": MAX_INERTIA}
_SIGNED = {"XY": MAX_INERTIA, "XZ": MAX_INERTIA, "YZ": MAX_INERTIA}
#: viscous and Coulomb friction (of a joint or a coupled motor) dissipate: not negative
_FRICTION = {"Fv": "N m s/rad", "Fc": "N m", "Fvm": "N m s/rad", "Fcm": "N m"}
_UNITS = {"M": "kg"}


#: m: the centre-of-mass check never refuses closer than this (the reach counts the joints'
#: offsets, not the last link's length: a pendulum's joints all sit at its base)
MIN_COM_BOUND = 10.0


def _centres_of_mass(apriori, robot, path):
    """A link's centre of mass (first moment / mass, where the mass is positive) within twice the
    robot's reach (the joints' offsets and prismatic travel) plus 1 m of its frame, and never
    closer than MIN_COM_BOUND: far more than any link of the robot can hold, so a value beyond
    is a wrong number or unit."""
    reach = 0.0
    for jt in robot.joints:
        reach += float(np.linalg.norm(jt.p))
        if jt.sigma == 1:
            lo, hi = jt.q_limits
            reach += max(abs(lo), abs(hi)) if np.isfinite(lo) and np.isfinite(hi) else MAX_LENGTH
    bound = max(2.0 * reach + 1.0, MIN_COM_BOUND)
    for j in range(1, robot.n_joints + 1):
        m = apriori.get(f"M{j}")
        ms = [apriori.get(f"{k}{j}", 0.0) for k in ("MX", "MY", "MZ")]
        if m is None or not m > 0 or math.hypot(*ms) <= bound * m:
            continue
        raise RobotFileError(f"{path}: apriori.values put link {j}'s centre of mass {math.hypot(*ms) / m:.3g} m "
                             f"from its frame (MX{j}, MY{j}, MZ{j} = {', '.join(f'{x:g}' for x in ms)} kg m, "
                             f"M{j} = {m:g} kg), beyond the {bound:.3g} m this robot can hold (twice its reach "
                             f"plus 1 m, at least {MIN_COM_BOUND:g} m); the first moments are mass times the centre's position: check the "
                             f"numbers and their units")


def _links_realizable(apriori, robot, path, links):
    """What no mass distribution gives is refused at load time (it failed mid-simulation, naming
    no file): a first moment without a positive mass, an inertia beside a mass given as zero or
    less; XX, YY, ZZ about the link frame that break
    the triangle inequality (when all three are given: a planar arm's file gives ZZ alone); with
    all ten inertial values given, a pseudo-inertia that is not positive semidefinite."""
    for j in sorted(links):
        ms = {k: apriori[f"{k}{j}"] for k in ("MX", "MY", "MZ") if apriori.get(f"{k}{j}", 0.0) != 0.0}
        m = apriori.get(f"M{j}", 0.0)
        if ms and not m > 0:
            raise RobotFileError(f"{path}: apriori.values give link {j} a first moment "
                                 f"({', '.join(f'{k}{j} = {v:g} kg m' for k, v in ms.items())}) but "
                                 f"{'no mass' if f'M{j}' not in apriori else f'M{j} = {m:g} kg'}: a first moment "
                                 f"is mass times the centre of mass's position; give M{j} > 0")
        inertia = {k: apriori[f"{k}{j}"] for k in ("XX", "XY", "XZ", "YY", "YZ", "ZZ")
                   if apriori.get(f"{k}{j}", 0.0) != 0.0}
        if inertia and f"M{j}" in apriori and not m > 0:
            raise RobotFileError(f"{path}: apriori.values give link {j} an inertia "
                                 f"({', '.join(f'{k}{j} = {v:g} kg m^2' for k, v in inertia.items())}) but "
                                 f"M{j} = {m:g} kg: a link without mass has no inertia; give M{j} > 0")
        diag = [apriori.get(f"{k}{j}") for k in ("XX", "YY", "ZZ")]
        if all(v is not None for v in diag):
            scale = max(max(diag), 1e-300)
            for a, b, c, name in ((0, 1, 2, "ZZ"), (0, 2, 1, "YY"), (1, 2, 0, "XX")):
                if diag[c] > diag[a] + diag[b] + INERTIA_RTOL * scale:
                    raise RobotFileError(
                        f"{path}: apriori.values give link {j} XX{j}, YY{j}, ZZ{j} = "
                        f"{', '.join(f'{v:g}' for v in diag)} kg m^2: {name}{j} is more than the sum of the "
                        "other two, which no mass distribution gives (the triangle inequality); check the "
                        "numbers, and that they are about the link frame, not the centre of mass")
        keys = [f"{k}{j}" for k in ("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M")]
        if all(k in apriori for k in keys):
            values = np.array([apriori[k] for k in keys])
            ev = np.linalg.eigvalsh(pseudo_inertia(values))
            if ev[0] < -INERTIA_RTOL * max(abs(ev[-1]), 1e-300):
                raise RobotFileError(f"{path}: apriori.values of link {j} ({', '.join(keys)}) are not those of "
                                     f"any mass distribution (its pseudo-inertia has a negative eigenvalue, "
                                     f"{ev[0]:.3g}): check the numbers, their units and the frame they are about")


def _apriori_bounds(key, v, is_standard, path):
    """Masses, inertia diagonals and rotor inertias are not negative; every value is bounded."""
    where = f"apriori.values.{key}"
    prefix = re.sub(r"\d+$", "", key) if is_standard else None
    unit = " " + _UNITS.get(prefix, "kg m^2") if prefix in _NONNEGATIVE or prefix in _SIGNED else ""
    if prefix in _NONNEGATIVE and v < 0:
        what = "a mass" if prefix == "M" else "an inertia about an axis"
        raise RobotFileError(f"{path}: {where} = {v:g}{unit} is negative; {what} must not be "
                             f"negative: fix it")
    if prefix in _FRICTION and v < 0:
        raise RobotFileError(f"{path}: {where} = {v:g} {_FRICTION[prefix]} is negative; a friction "
                             f"coefficient dissipates and must not be negative: fix it (a torque offset is Off)")
    bound = _NONNEGATIVE.get(prefix) or _SIGNED.get(prefix) or MAX_APRIORI
    if abs(v) > bound:
        raise RobotFileError(f"{path}: {where} = {v:g}{unit} is beyond the {bound:g}{unit} dynid "
                             f"accepts, far more than a real robot needs; check the number and its unit")


def _apply_joint_options(joint, tab, k, path, *, kinematics):
    """Set a joint's fields from its [[joints]] table (its kinematics only when they are not the URDF's)."""
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
    who = f" (joint '{shown(joint.name)}')"
    if kinematics:
        _set_kinematics(joint, tab, where, path, who)
    elif any(key in tab for key in ("sigma", *_KINEMATICS)):
        raise RobotFileError(f"{path}: {where} gives kinematics, but they come from the URDF; remove "
                             f"sigma/alpha/d/theta/r there")
    if "q_limits" in tab:
        joint.q_limits = _q_limits(tab["q_limits"], where, path)
    for key in ("qd_max", "qdd_max", "tau_max", "drive_gain"):
        if key in tab:
            setattr(joint, key, JOINT_FIELDS[key](tab[key], f"{where}.{key}", path, who))
    if "friction" in tab:
        if tab["friction"] not in ("viscous_coulomb",):
            raise RobotFileError(f"{path}: {where}.friction must be 'viscous_coulomb', "
                                 f"got {short(tab['friction'])}")
        joint.friction = tab["friction"]


def _set_kinematics(joint, tab, where, path, who):
    """Joint type and modified DH row (alpha, d, theta, r; rad and m), and the placement they give."""
    sigma = tab.get("sigma", 0)
    if sigma not in (0, 1) or isinstance(sigma, bool):
        raise RobotFileError(f"{path}: {where}.sigma must be 0 (revolute) or 1 (prismatic), "
                             f"got {short(sigma)}")
    vals = [JOINT_FIELDS[key](tab.get(key, 0.0), f"{where}.{key}", path, who) for key in _KINEMATICS]
    for i in (0, 2):                      # alpha, theta: a rounded right angle is the right angle
        vals[i] = snap_right_angle(vals[i])
    joint.sigma = int(sigma)
    joint.mdh = tuple(vals)
    joint.R, joint.p = mdh_placement(*vals)


def _q_limits(lim, where, path):
    if not isinstance(lim, list) or len(lim) != 2:
        raise RobotFileError(f"{path}: {where}.q_limits must be [lower, upper]")
    lo, hi = (_Q_LIMIT(v, f"{where}.q_limits", path) for v in lim)
    if not lo < hi:
        raise RobotFileError(f"{path}: {where}.q_limits lower {lo} must be below upper {hi}")
    return lo, hi


def _coupling(tab, k, n, path):
    """One [[couplings]] table: a motor turning several joints with coefficients (gear ratios)."""
    where = f"couplings[{k + 1}]"
    if not isinstance(tab, dict):
        raise RobotFileError(f"{path}: {where} must be a table")
    no_unknown_keys(tab, ("motor", "joints", "coefficients", "friction"), where, path)
    for key in ("motor", "joints", "coefficients"):
        if key not in tab:
            raise RobotFileError(f"{path}: {where} needs '{key}'")
    joints = _coupled_joints(tab["joints"], n, where, path)
    coef = tab["coefficients"]
    if not isinstance(coef, list) or len(coef) != len(joints):
        raise RobotFileError(f"{path}: {where}.coefficients must have one number per joint in 'joints'")
    coef = [number(c, f"{where}.coefficients", path) for c in coef]
    motor = tab["motor"]
    if not isinstance(motor, int) or isinstance(motor, bool) or motor not in joints:
        raise RobotFileError(f"{path}: {where}.motor must be one of its joints {joints}, got {short(motor)}")
    _check_ratios(joints, coef, motor, where, path)
    friction = tab.get("friction", True)
    if not isinstance(friction, bool):     # "no" or 0 must not pass as a truth value
        raise RobotFileError(f"{path}: {where}.friction must be true or false, got {short(friction)}")
    return Coupling(motor=motor, joints=tuple(joints), coefficients=tuple(coef), friction=friction)


def _coupled_joints(joints, n, where, path):
    # True is an int to Python, and a joint listed twice would count twice
    if (not isinstance(joints, list) or len(set(map(repr, joints))) != len(joints)
            or not all(isinstance(j, int) and not isinstance(j, bool) and 1 <= j <= n for j in joints)):
        raise RobotFileError(f"{path}: {where}.joints must be a list of distinct joint numbers "
                             f"1..{n}, got {short(joints)}")
    return joints


def _check_ratios(joints, coef, motor, where, path):
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


def _controller(tab, n, path, names=None):
    """The [controller] table: kind, rate and per-joint gains, each checked against `CONTROLLER_FIELDS`."""
    if not isinstance(tab, dict):
        raise RobotFileError(f"{path}: [controller] must be a table")
    no_unknown_keys(tab, ("kind", *CONTROLLER_FIELDS), "[controller]", path)
    kind = tab.get("kind", "pd")
    if kind not in ("pd", "pid"):
        raise RobotFileError(f"{path}: controller.kind must be 'pd' or 'pid', got {short(kind)}")
    values = {}
    for key, (field, default) in CONTROLLER_FIELDS.items():
        if key == "ki" and kind != "pid":
            if "ki" in tab:     # it would be ignored without a word
                raise RobotFileError(f"{path}: controller.ki is the integral gain of kind = 'pid'; this "
                                     f"controller is kind = '{kind}': remove ki, or set kind = 'pid'")
            continue
        if default is None and key not in tab:
            raise RobotFileError(f"{path}: controller.{key} is required (one value per joint)")
        value = tab.get(key, default)
        values[key] = (field(value, f"controller.{key}", path) if key == "rate" else
                       field.vector(value, n, f"controller.{key}", path, names))
    return Controller(kind=kind, **values)
