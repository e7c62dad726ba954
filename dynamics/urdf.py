"""URDF reader for serial chains.

Each moving joint's frame is the URDF joint frame rotated so that its `z`
axis is the joint axis (dynid's regressor turns and slides about `z`): for
`axis = (0, -1, 0)` that is a rotation of +90 deg about `x`. Link
inertials (mass, centre of mass and inertia about the centre of mass in the
`<inertial>` frame) are converted to dynid's standard parameters of that
joint frame: inertia about the frame origin (parallel-axis theorem) and first
moments `M c`. Fixed joints are merged: their placement folds into the next
moving joint, the inertia of a fixed child link into its parent link.

Chains. dynid models one serial chain. Without `base`/`tip` the moving
joints of the whole file must form one chain from the root link (fixed side
branches -- sensors, tool frames -- are merged); a file whose moving joints
branch (a two-armed robot, a gripper with two fingers) is refused, naming the
first moving joint of each branch. `base`/`tip` (link names, as in KDL's
`getChain(base, tip)`) select the chain from `base` down to `tip`:

* `base` (default: the root link) is fixed to the ground; what hangs from
  it, or from links fixed to it, does not change the chain's dynamics and is
  left out, as is everything above it.
* Fixed children of the chain's links (and of the tip) are merged as above:
  their inertia folds into the moving link they are fixed to.
* Moving subtrees off the chain (fingers below the tip, a second arm) are
  left out **with their mass**: the model is the chain alone. Each such
  omission is described in `robot.notices` (with the mass left out).

Checks (each a `RobotFileError` naming the file and the element):
XML entity declarations and external references (defusedxml); duplicated
link or joint names; names with control characters; a link with two parents,
loops, several roots; more than `MAX_URDF_LINKS` links or `MAX_JOINTS`
moving joints in the chain; `<mimic>`, floating and planar joints on the
chain; `lower > upper` (or equal) limits and negative velocity/effort limits
(0 means "not given", as URDF exporters write it);
origins beyond `MAX_LENGTH`; link inertials with negative mass, mass above
`MAX_MASS`, inertia entries above `MAX_INERTIA`, inertia about the centre
of mass not positive semi-definite or violating the triangle inequality
(`I1 + I2 >= I3` for the principal moments; both to 1e-4 of the trace, the
rounding of inertias printed to 4-5 digits), and
mass 0 with a nonzero inertia. A massless frame (mass 0, inertia 0) is legal.
A point mass or a thin rod (a zero principal moment) is a legal limiting case.
Inertials of links that do not enter the model (the ground, left-out
subtrees) are not read.
"""
from __future__ import annotations

import difflib
import math
from collections import deque
from pathlib import Path

import numpy as np

from dynid.errors import RobotFileError

from .robot import Joint, Robot
from .robot_checks import (
    MAX_INERTIA,
    MAX_JOINTS,
    MAX_LENGTH,
    MAX_MASS,
    MAX_URDF_LINKS,
    MIN_SPEED,
    check_name,
    read_limited,
    shown,
)

_MOVING = {"revolute": 0, "continuous": 0, "prismatic": 1}
_UNSUPPORTED = {"floating", "planar"}          # valid URDF, but not a joint dynid can model
_TYPES = set(_MOVING) | _UNSUPPORTED | {"fixed"}
INERTIA_RTOL = 1e-4        # rounding slack of PSD / triangle checks, relative to trace(I_c):
                            # inertias printed to 4-5 digits (a disk: 0.0033333 + 0.0033333 < 0.0066667)


def rpy_matrix(r, p, y):
    """URDF fixed-axis roll-pitch-yaw: R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def align_z(axis):
    """A rotation A with A @ [0, 0, 1] = axis (unit), deterministic."""
    a = np.asarray(axis, dtype=float)
    a = a / np.abs(a).max()     # scaled first: the norm of a huge axis (1e300) would overflow
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ a)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])          # Rot(x, pi)
    v = np.cross(z, a)
    s = np.linalg.norm(v)
    k = v / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    A = np.eye(3) + s * K + (1 - c) * K @ K
    A[np.abs(A) < 1e-15] = 0.0
    return A


def _floats(text, n, where, path):
    try:
        vals = [float(v) for v in (text or "").split()]
    except ValueError:
        raise RobotFileError(f"{path}: {where} must hold {n} numbers, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise RobotFileError(f"{path}: {where} must hold {n} finite numbers, got {text!r}")
    return np.array(vals)


#: A joint angle that is a nonzero multiple of pi/2 rounded to the decimals written (1.5708, 1.571,
#: 1.57, 3.1416) is that multiple: the rounded value would give the base parameters of a slightly
#: skewed arm (a parameter that regroups at pi/2, Ia2 into ZZ2R, kept apart with cond(W) ~ 1e6).
#: Any other value (a calibrated 1.5703, a small 0.0005) is kept as written, as is one within
#: RIGHT_ANGLE_EXACT of the multiple; RIGHT_ANGLE_SNAP bounds the rounding taken (2 decimals: 8e-4 rad).
RIGHT_ANGLE_SNAP = 1e-3
RIGHT_ANGLE_EXACT = 1e-9


def snap_right_angle(value: float, text: str | None = None) -> float:
    """`value` (rad), or the nonzero multiple of pi/2 it is a rounding of: `text` (the number as
    written; default `repr(value)`) has d decimals and `value` is the multiple rounded to d."""
    k = round(value / (math.pi / 2))
    dev = abs(value - k * math.pi / 2)
    if k == 0 or not RIGHT_ANGLE_EXACT < dev <= RIGHT_ANGLE_SNAP:
        return value
    text = (repr(float(value)) if text is None else str(text)).strip().lower()
    if "e" in text or "." not in text:
        return value
    decimals = len(text.split(".", 1)[1])
    return k * math.pi / 2 if round(k * math.pi / 2, decimals) == round(value, decimals) else value


def _origin(elem, where, path, snapped=None):
    """(R, xyz) of `elem`'s <origin>; with a list `snapped`, rpy angles that round a multiple of pi/2
    are taken as it (`snap_right_angle`) and (where, written, taken) appended."""
    o = elem.find("origin") if elem is not None else None
    if o is None:
        return np.eye(3), np.zeros(3)
    xyz = _floats(o.get("xyz", "0 0 0"), 3, f"{where} origin xyz", path)
    if np.abs(xyz).max() > MAX_LENGTH:
        raise RobotFileError(f"{path}: {where} origin xyz {o.get('xyz')!r} is beyond {MAX_LENGTH:g} m "
                             f"from its parent frame, more than any robot arm; check the number and "
                             f"its unit (metres)")
    rpy = _floats(o.get("rpy", "0 0 0"), 3, f"{where} origin rpy", path)
    if snapped is not None:
        taken = np.array([snap_right_angle(float(a), t) for a, t in zip(rpy, o.get("rpy", "0 0 0").split())])
        if np.any(taken != rpy):
            snapped.append((where, o.get("rpy"), taken))
            rpy = taken
    return rpy_matrix(*rpy), xyz


def _spatial_inertia(link, where, path):
    """(mass, c, I_origin) of a link's <inertial> in the link frame, or None (none or massless)."""
    inertial = link.find("inertial")
    if inertial is None:
        return None
    mass_el = inertial.find("mass")
    if mass_el is None:
        raise RobotFileError(f"{path}: {where} has <inertial> without <mass>; add <mass value=...>")
    m = _floats(mass_el.get("value"), 1, f"{where} mass", path)[0]
    if m < 0:
        raise RobotFileError(f"{path}: {where} has mass {m:g} kg; a mass must not be negative: fix it")
    if m > MAX_MASS:
        raise RobotFileError(f"{path}: {where} has mass {m:g} kg, above the {MAX_MASS:g} kg dynid "
                             f"accepts for one link; check the number and its unit (kg)")
    R, c = _origin(inertial, f"{where} inertial", path)
    I_el = inertial.find("inertia")
    if I_el is None:
        raise RobotFileError(f"{path}: {where} has <inertial> without <inertia>; add <inertia ixx=... />")
    vals = {}
    missing = [key for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz") if I_el.get(key) is None]
    if missing:
        # as urdfdom: a missing moment read as 0 would be a wrong a-priori value, not a default
        raise RobotFileError(f"{path}: {where} <inertia> has no {', '.join(missing)}; URDF needs all six "
                             f"(ixx ixy ixz iyy iyz izz, kg m^2): add the missing one(s), 0 where a product of inertia is 0")
    for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
        vals[key] = _floats(I_el.get(key), 1, f"{where} inertia {key}", path)[0]
        if abs(vals[key]) > MAX_INERTIA:
            raise RobotFileError(f"{path}: {where} inertia {key} = {vals[key]:g} kg m^2 is beyond the "
                                 f"{MAX_INERTIA:g} kg m^2 dynid accepts; check the number and its "
                                 f"unit (kg m^2)")
    Ic = np.array([[vals["ixx"], vals["ixy"], vals["ixz"]],
                   [vals["ixy"], vals["iyy"], vals["iyz"]],
                   [vals["ixz"], vals["iyz"], vals["izz"]]])
    if m == 0:
        if np.any(Ic):
            raise RobotFileError(f"{path}: {where} has mass 0 but a nonzero inertia, which no body "
                                 f"has; give its mass, or set the inertia to 0 for a massless frame")
        return None                                  # a massless frame: nothing to add
    moments = np.sort(np.linalg.eigvalsh(Ic))
    tol = INERTIA_RTOL * max(float(np.trace(Ic)), 0.0)
    if moments[0] < -tol:
        raise RobotFileError(f"{path}: {where} has an inertia that is not positive definite "
                             f"(principal moments {', '.join(f'{v:.6g}' for v in moments)} kg m^2); "
                             f"fix the inertia (about the centre of mass, in kg m^2) there")
    if moments[0] + moments[1] < moments[2] - tol:
        raise RobotFileError(f"{path}: {where} has principal moments of inertia "
                             f"{', '.join(f'{v:.6g}' for v in moments)} kg m^2 that violate the "
                             f"triangle inequality (the largest must be at most the sum of the other "
                             f"two), which no body has; fix the inertia there")
    Ic = R @ Ic @ R.T
    return m, c, inertia_about_origin(m, c, Ic)


def inertia_about_origin(m, c, I_c):
    """The inertia matrix about the frame's origin of a body of mass `m`, centre of mass `c` and
    inertia `I_c` about it (parallel axes): I_c + m (|c|² 1 - c cᵀ)."""
    return I_c + m * (c @ c * np.eye(3) - np.outer(c, c))


def inertia_about_com(m, c, I_o):
    """The inertia about the centre of mass `c` of a body of mass `m` whose inertia about the
    frame's origin is `I_o` (`inertia_about_origin` undone): I_o - m (|c|² 1 - c cᵀ)."""
    return I_o - m * (c @ c * np.eye(3) - np.outer(c, c))


def inertial_parameters(k, m, c, I_o) -> dict:
    """The standard inertial parameters XXk .. Mk of a body (mass `m`, centre of mass `c`, inertia
    `I_o` about the frame origin; the matrix entries, XY = -∫xy dm) carried by link k."""
    return {f"XX{k}": I_o[0, 0], f"XY{k}": I_o[0, 1], f"XZ{k}": I_o[0, 2],
            f"YY{k}": I_o[1, 1], f"YZ{k}": I_o[1, 2], f"ZZ{k}": I_o[2, 2],
            f"MX{k}": m * c[0], f"MY{k}": m * c[1], f"MZ{k}": m * c[2], f"M{k}": m}


def _transform_inertia(inertia, R, p):
    """Express (m, c, I_origin) given in frame B in frame A, where x_A = R x_B + p."""
    m, c, I_o = inertia
    c_new = R @ c + p
    # back to the centre of mass, rotate, then to the new origin
    I_c = R @ inertia_about_com(m, c, I_o) @ R.T
    return m, c_new, inertia_about_origin(m, c_new, I_c)


def _add(a, b):
    if a is None:
        return b
    if b is None:
        return a
    m = a[0] + b[0]
    c = (a[0] * a[1] + b[0] * b[1]) / m if m > 0 else np.zeros(3)
    return m, c, a[2] + b[2]


def _parse(path):
    """The root element of a URDF file, parsed with defusedxml (no entities, no external refs)."""
    data = read_limited(path, "URDF")
    try:        # a dependency; imported here so a broken environment gives a RobotFileError
        import defusedxml
        from defusedxml import ElementTree as SafeET
    except ImportError:
        raise RobotFileError(f"cannot read URDF '{path}': the Python package 'defusedxml', which dynid "
                             f"uses to parse XML safely, is not installed; add it to the "
                             f"Python environment (pip install defusedxml)") from None
    try:
        return SafeET.fromstring(data)
    except SafeET.ParseError as exc:
        raise RobotFileError(f"URDF '{path}' is not well-formed XML: {exc}; fix the XML there") from None
    except defusedxml.DefusedXmlException as exc:
        raise RobotFileError(f"URDF '{path}': the XML declares entities or refers to external "
                             f"resources ({type(exc).__name__}), which dynid refuses (they can expand "
                             f"without bound or read other files); remove the <!DOCTYPE>/<!ENTITY> "
                             f"declarations (expand a xacro file first)") from None
    except RecursionError:
        raise RobotFileError(f"URDF '{path}': the XML is nested too deeply to read; check that it "
                             f"is a URDF") from None


def _few(names, k=6):
    names = list(names)
    shown = ", ".join(f"'{n}'" for n in names[:k])
    return shown + (f" and {len(names) - k} more" if len(names) > k else "")


class _Tree:
    """The validated kinematic tree of a URDF: one root, every link one parent, no loops."""

    def __init__(self, root, path):
        self.path = path
        self.links = self._read_links(root)
        self.joints = root.findall("joint")       # only top-level joints, not <transmission> ones
        self.parent_joint, self.children = {}, {}
        names = set()
        for j in self.joints:
            self._add_joint(j, names)
        if not self.links:
            raise RobotFileError(f"{path}: the URDF has no <link>; add the robot's links and joints")
        self.root = self._find_root()
        # moves[l]: a moving joint hangs somewhere below link l (bottom-up, no recursion)
        self.moves = {}
        for l in reversed(self.order):
            self.moves[l] = any(k.get("type") != "fixed" or self.moves[self.child(k)]
                                for k in self.children.get(l, []))

    def _read_links(self, root):
        path, links = self.path, {}
        for el in root.findall("link"):
            name = el.get("name")
            if not name:
                raise RobotFileError(f"{path}: a <link> has no name; give it name=\"...\"")
            check_name(name, "link name", path)
            if name in links:
                raise RobotFileError(f"{path}: duplicate <link> name '{name}': two <link> elements are named '{name}'; give every "
                                     f"link a unique name")
            links[name] = el
            if len(links) > MAX_URDF_LINKS:
                raise RobotFileError(f"{path}: more than {MAX_URDF_LINKS} links, far more than a robot "
                                     f"arm has; check that it is the right file")
        return links

    def _add_joint(self, j, names):
        """Check one <joint> (name, type, existing parent and child links, no loop) and link it in."""
        path, name, kind = self.path, j.get("name"), j.get("type")
        if not name:
            raise RobotFileError(f"{path}: a {shown(kind or '')} joint has no name; give it "
                                 f"name=\"...\"")
        check_name(name, "joint name", path)
        if name in names:
            raise RobotFileError(f"{path}: two <joint> elements are named '{name}' (duplicated joint "
                                 f"name); give every joint a unique name")
        names.add(name)
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None or not parent.get("link") or not child.get("link"):
            raise RobotFileError(f"{path}: joint '{name}' needs <parent link=...> and <child link=...>")
        missing = [l for l in (parent.get("link"), child.get("link")) if l not in self.links]
        if missing:
            raise RobotFileError(f"{path}: joint '{name}' refers to link {missing[0]!r} that does "
                                 f"not exist; add <link name={missing[0]!r}> or fix the name")
        if kind not in _TYPES:
            raise RobotFileError(f"{path}: joint '{name}' has type {kind!r}; dynid reads revolute, "
                                 f"continuous, prismatic and fixed joints: use one of these")
        p, c = parent.get("link"), child.get("link")
        if p == c:
            raise RobotFileError(f"{path}: joint '{name}' joins link '{c}' to itself; fix its "
                                 f"<parent> or <child>")
        if c in self.parent_joint:
            raise RobotFileError(f"{path}: link '{c}' is the child of two joints, "
                                 f"'{self.parent_joint[c].get('name')}' and '{name}', which makes a "
                                 f"loop; remove the joint that closes it (a URDF is a tree)")
        self.parent_joint[c] = j
        self.children.setdefault(p, []).append(j)

    def _find_root(self):
        """The one root link, every link reachable from it (sets `order`, breadth first)."""
        path = self.path
        roots = [l for l in self.links if l not in self.parent_joint]
        if not roots and self.links:     # every link is some joint's child: the joints close a loop
            raise RobotFileError(f"{path}: every link is the child of a joint, so the joints form a loop and "
                                 f"there is no root link; a URDF is a tree: remove the joint that closes it")
        if len(roots) != 1:
            raise RobotFileError(f"{path}: expected one root link, found {len(roots)} ({', '.join(roots)}); "
                                 f"connect every link to the chain with a joint, or remove the stray ones")
        root = roots[0]
        self.order = self.below(root)
        if len(self.order) != len(self.links):
            lost = [l for l in self.links if l not in set(self.order)]
            raise RobotFileError(f"{path}: the joints between links {_few(lost)} form a loop not "
                                 f"connected to the root link '{root}'; remove the joint that "
                                 f"closes it")
        return root

    @staticmethod
    def child(j):
        return j.find("child").get("link")

    @staticmethod
    def parent(j):
        return j.find("parent").get("link")

    def below(self, link):
        """Links of the subtree of `link`, breadth first (`link` first)."""
        out, queue = [], deque([link])
        while queue:
            l = queue.popleft()
            out.append(l)
            queue.extend(self.child(k) for k in self.children.get(l, []))
        return out

    def first_moving(self, joint):
        """The moving joints nearest the top of the branch that starts with `joint`."""
        out, queue = [], deque([joint])
        while queue:
            j = queue.popleft()
            if j.get("type") != "fixed":
                out.append(j.get("name"))
            else:
                queue.extend(self.children.get(self.child(j), []))
        return out

    def tips(self, joint):
        """Child links of the last moving joints of a branch: tips one may select."""
        out = []
        for l in self.below(self.child(joint)):
            pj = self.parent_joint[l]
            if pj.get("type") != "fixed" and not self.moves[l]:
                out.append(l)
        return out

    def check_link(self, name, what):
        if not isinstance(name, str):
            raise RobotFileError(f"{self.path}: {what} must be a link name (a string), got "
                                 f"{shown(repr(name))[:80]}")
        if name in self.links:
            return
        close = difflib.get_close_matches(name, list(self.links), n=3)
        hint = f" (did you mean {_few(close)}?)" if close else ""
        raise RobotFileError(f"{self.path}: {what} {name!r} is not a link of this URDF{hint}; give one "
                             f"of its links, e.g. {_few(self.links)}")

    def chain(self, base, tip):
        """The joints from `base` down to `tip` (or down the only moving chain)."""
        path = self.path
        if base is None:
            base = self.root
        self.check_link(base, "base")
        if tip is not None:
            self.check_link(tip, "tip")
            if tip == base:
                raise RobotFileError(f"{path}: tip '{tip}' is the base itself; give a tip link below "
                                     f"the base '{base}'")
            joints, l = [], tip
            while l != base:
                j = self.parent_joint.get(l)
                if j is None:
                    raise RobotFileError(f"{path}: tip '{tip}' is not below base '{base}'; give a tip "
                                         f"among the links below '{base}' (or a base above '{tip}')")
                joints.append(j)
                l = self.parent(j)
            return base, joints[::-1]
        joints, l = [], base
        while True:
            leads = [k for k in self.children.get(l, [])
                     if k.get("type") != "fixed" or self.moves[self.child(k)]]
            if not leads:
                return base, joints
            if len(leads) > 1:
                starts = [", ".join(f"'{n}'" for n in self.first_moving(k)) for k in leads]
                tips = [t for k in leads for t in self.tips(k)[:2]]
                raise RobotFileError(
                    f"{path}: the moving joints do not form one serial chain: below link '{l}' "
                    f"{len(leads)} branches move, starting with joint(s) {'; '.join(starts)}. dynid "
                    f"models one serial chain: give the one you want with --tip LINK (and --base LINK) on the "
                    f"command line, tip=/base= in load_robot, or tip = \"<link>\" beside "
                    f"urdf = ... in a TOML robot file; tips here include {_few(tips)}")
            joints.append(leads[0])
            l = self.child(leads[0])


def read_urdf(path, base=None, tip=None):
    """Read the serial chain of a URDF into a Robot (standard parameters as a-priori values).

    Parameters
    ----------
    path : str or Path
        The URDF file.
    base, tip : str, optional
        Link names selecting the chain from `base` (default: the root link)
        down to `tip` (default: the end of the only moving chain).

    Returns
    -------
    Robot
        Fixed children of chain links are merged; moving subtrees off the
        chain are left out *with their mass*, and `robot.notices` says so
        (see the module docstring).

    Raises
    ------
    RobotFileError
        One message naming the file, the element and what to do.
    """
    path = Path(path)
    root = _parse(path)
    if root.tag != "robot":
        raise RobotFileError(f"URDF '{path}': root element must be <robot>, got <{root.tag}>")
    if root.get("name"):
        check_name(root.get("name"), "robot name", path)
    tree = _Tree(root, path)
    base, chain = tree.chain(base, tip)
    _check_chain(tree, chain, base, tip, path)
    walk = _ChainWalk(tree, path)
    walk.run(base, chain)
    _check_finite(walk.joints, walk.inertias, path)
    apriori = dict(walk.apriori)
    apriori.update(_inertial_apriori(walk.inertias))
    selected = base != tree.root or tip is not None
    chain_text = f"chain '{base}' -> '{walk.chain_links[-1]}'"
    robot = Robot(name=root.get("name") or path.stem, joints=walk.joints,
                  gravity=np.array([0.0, 0.0, -9.81]), source=str(path),
                  description=f"read from URDF {path.name}" + (f", {chain_text}" if selected else ""))
    robot.apriori = {k: float(v) for k, v in apriori.items()}
    robot.provenance = {"kinematics": f"URDF {path.name}" + (f", {chain_text}" if selected else ""),
                        "apriori": f"URDF {path.name} inertials and <dynamics>"}
    robot.notices = _notices(tree, base, chain, walk.left_out, walk.joints, chain_text) + _snap_notices(
        path, walk.snapped)
    return robot


def _snap_notices(path, snapped):
    """The notice naming the joint origins whose rpy was taken as a right angle."""
    return snap_notice(f"URDF {Path(path).name}",
                       [f"{where} rpy=\"{text}\" as ({', '.join(_angle_text(a) for a in taken)})"
                        for where, text, taken in snapped],
                       keep="; a value written with digits beyond its rounding (1.570800) is kept as written")


def snap_notice(source, parts, keep=""):
    """[one notice] naming the angles of `source` (a URDF, a robot file) taken as right angles
    (`snap_right_angle`), or [] when there are none. `keep`: how to keep a value as written."""
    if not parts:
        return []
    more = f" and {len(parts) - 6} more" if len(parts) > 6 else ""
    return [f"{source}: multiples of pi/2 rounded to the decimals written taken as the multiple: "
            f"{'; '.join(parts[:6])}{more}. Taken literally, a rounded right angle describes a slightly skewed "
            f"arm, whose base parameters differ (a regrouped parameter kept apart, barely identifiable){keep}"]


def _angle_text(a):
    k = round(a / (math.pi / 2))
    if a == k * math.pi / 2:
        return {0: "0", 1: "pi/2", -1: "-pi/2", 2: "pi", -2: "-pi", 3: "3pi/2", -3: "-3pi/2", 4: "2pi",
                -4: "-2pi"}.get(k, f"{k}*pi/2")
    return f"{a:g}"


def _check_chain(tree, chain, base, tip, path):
    """The chain has 1..MAX_JOINTS moving joints, none of a type or a mimic dynid cannot model."""
    n_moving = sum(j.get("type") != "fixed" for j in chain)
    if n_moving == 0:
        where = f" between '{base}' and '{tip}'" if tip is not None else f" below link '{base}'"
        raise RobotFileError(f"{path}: no revolute or prismatic joint found{where}; add one or give "
                             f"another base/tip")
    if n_moving > MAX_JOINTS:
        raise RobotFileError(f"{path}: the chain has {n_moving} moving joints, more than the "
                             f"{MAX_JOINTS} dynid models (the regressor grows as n^2); check the file "
                             f"or give base/tip to select a shorter chain")
    for j in chain:
        name, kind = j.get("name"), j.get("type")
        if kind in _UNSUPPORTED:
            raise RobotFileError(f"{path}: joint '{name}' has type '{kind}'; dynid reads revolute, "
                                 f"continuous, prismatic and fixed joints: use one of these, or give "
                                 f"base/tip so the chain leaves it out (e.g. base='{tree.child(j)}')")
        if j.find("mimic") is not None:
            raise RobotFileError(f"{path}: joint '{name}' is a <mimic> joint (it moves with joint "
                                 f"{j.find('mimic').get('joint')!r}); dynid cannot model mimic joints: "
                                 f"give base/tip so the chain leaves it out")


class _ChainWalk:
    """The walk down a URDF chain that builds the moving joints and folds link inertias into them.

    `joints`: the Robot joints (frames aligned with their axis as z); `aligns`:
    each one's alignment with its URDF frame; `inertias`: (m, c, I) carried by
    each, or None; `apriori`: friction read from <dynamics>; `left_out`:
    (joint, owner index or None) of the moving subtrees off the chain.
    """

    def __init__(self, tree, path):
        self.tree, self.path = tree, path
        self.joints, self.aligns, self.inertias, self.apriori, self.left_out = [], [], [], {}, []
        self.chain_links = []
        self.snapped = []                 # joint origins whose rpy rounded a right angle

    def where(self, link):
        pj = self.tree.parent_joint.get(link)
        return f"link '{link}'" + (f" (child of joint '{pj.get('name')}')" if pj is not None else "")

    def add_link(self, link, owner, R, p):
        """Fold a link's inertia (its frame at R, p in the owner's URDF frame) into the owner."""
        inertia = _spatial_inertia(self.tree.links[link], self.where(link), self.path)
        if inertia is not None:
            A = self.aligns[owner]
            self.inertias[owner] = _add(self.inertias[owner], _transform_inertia(inertia, A.T @ R, A.T @ p))

    def merge_fixed(self, joint, owner, R0, p0):
        """A fixed side branch: its links' inertias go to `owner`; moving joints in it are left out."""
        tree = self.tree
        stack = [(joint, R0, p0)]
        while stack:                      # iterative: a fixed branch 3000 links deep is fine
            j, R, p = stack.pop()
            c = tree.child(j)
            if owner is not None:
                R_o, p_o = _origin(j, f"joint '{j.get('name')}'", self.path, self.snapped)
                R, p = R @ R_o, R @ p_o + p
                self.add_link(c, owner, R, p)
            for k in tree.children.get(c, []):
                if k.get("type") == "fixed":
                    stack.append((k, R, p))
                else:
                    self.left_out.append((k, owner))

    def side_branches(self, link, nxt, owner, T_R, T_p):
        """The children of a chain link other than the next chain joint: merged or left out."""
        for k in self.tree.children.get(link, []):
            if k is nxt:
                continue
            if k.get("type") == "fixed":
                self.merge_fixed(k, owner, T_R, T_p)
            else:
                self.left_out.append((k, owner))

    def run(self, base, chain):
        A_prev = np.eye(3)                      # alignment of the previous moving frame
        T_R, T_p = np.eye(3), np.zeros(3)       # previous moving frame (URDF) -> current link frame
        owner = None                            # index of the moving joint that carries the current link
        self.chain_links = [base] + [self.tree.child(j) for j in chain]
        for i, link in enumerate(self.chain_links):
            if owner is not None:
                self.add_link(link, owner, T_R, T_p)
            nxt = chain[i] if i < len(chain) else None
            self.side_branches(link, nxt, owner, T_R, T_p)
            if nxt is None:
                break
            R_o, p_o = _origin(nxt, f"joint '{nxt.get('name')}'", self.path, self.snapped)
            if nxt.get("type") == "fixed":
                T_p = T_R @ p_o + T_p
                T_R = T_R @ R_o
                continue
            A_prev = self.moving_joint(nxt, A_prev, T_R @ R_o, T_R @ p_o + T_p)
            T_R, T_p = np.eye(3), np.zeros(3)
            owner = len(self.joints) - 1

    def moving_joint(self, j, A_prev, R_u, p_u):
        """Add moving joint `j`, at R_u, p_u in the previous moving URDF frame; returns its alignment."""
        path, name = self.path, j.get("name")
        axis = _floats(j.find("axis").get("xyz", "1 0 0") if j.find("axis") is not None else "1 0 0",
                       3, f"joint '{name}' axis", path)
        if np.linalg.norm(axis) < 1e-9:
            raise RobotFileError(f"{path}: joint '{name}' has a zero axis; give its direction "
                                 f"(<axis xyz=\"0 0 1\"/>)")
        A = align_z(axis)
        # placement of the new aligned frame in the previous aligned frame
        R = A_prev.T @ R_u @ A
        p = A_prev.T @ p_u
        R[np.abs(R) < 1e-15] = 0.0
        p[np.abs(p) < 1e-15] = 0.0
        joint = Joint(name=name, sigma=_MOVING[j.get("type")], R=R, p=p)
        _limits(joint, j, path)
        k = len(self.joints) + 1
        dyn = j.find("dynamics")
        if dyn is not None:
            for key, pname in (("damping", "Fv"), ("friction", "Fc")):
                if dyn.get(key) is not None:
                    # any sign: dynid's URDF export writes identified values, which may be < 0
                    self.apriori[f"{pname}{k}"] = _floats(dyn.get(key), 1, f"joint '{name}' dynamics {key}",
                                                          path)[0]
        self.joints.append(joint)
        self.aligns.append(A)
        self.inertias.append(None)
        return A


def _check_finite(robot_joints, inertias, path):
    # numbers that overflow (xyz="1e300 ...") would give infinite placements and parameters
    for jt, inertia in zip(robot_joints, inertias):
        vals = [jt.R, jt.p] + ([] if inertia is None else [inertia[0], inertia[1], inertia[2]])
        if not all(np.isfinite(v).all() for v in vals):
            raise RobotFileError(f"{path}: joint '{jt.name}' or its link has origins or inertials too "
                                 f"large to compute with; check the numbers (metres, kg, kg m^2)")


def _inertial_apriori(inertias):
    """Standard inertial parameters XX..M of each moving joint's link from its folded inertia."""
    apriori = {}
    for k, inertia in enumerate(inertias, start=1):
        if inertia is None:
            continue
        apriori.update(inertial_parameters(k, *inertia))
    return apriori


def _limits(joint, j, path):
    """q_limits, qd_max, tau_max of a moving joint from its <limit> (0 velocity/effort: not given)."""
    name = joint.name
    lim = j.find("limit")
    if lim is None:
        return
    lo, hi = lim.get("lower"), lim.get("upper")
    if lo is not None and hi is not None and j.get("type") != "continuous":
        lo_v = _floats(lo, 1, f"joint '{name}' limit lower", path)[0]
        hi_v = _floats(hi, 1, f"joint '{name}' limit upper", path)[0]
        if lo_v > hi_v:
            raise RobotFileError(f"{path}: joint '{name}' limit lower {lo_v:g} is above upper {hi_v:g}; "
                                 f"fix the limits (lower must be below upper)")
        if lo_v == hi_v:
            raise RobotFileError(f"{path}: joint '{name}' limit lower and upper are both {lo_v:g}, so "
                                 f"the joint cannot move; give its real limits, or make it a fixed joint")
        joint.q_limits = (lo_v, hi_v)
    for key, attr in (("velocity", "qd_max"), ("effort", "tau_max")):
        if lim.get(key) is not None:
            v = _floats(lim.get(key), 1, f"joint '{name}' limit {key}", path)[0]
            if v < 0:
                raise RobotFileError(f"{path}: joint '{name}' limit {key} = {v:g} is negative; a "
                                     f"{key} limit must be positive (0 for none): fix it")
            if key == "velocity" and 0 < v < MIN_SPEED:
                raise RobotFileError(f"{path}: joint '{name}' limit velocity = {v:g} is too small for a joint "
                                     f"(at least {MIN_SPEED:g} rad/s or m/s; 0 for none): check the number and "
                                     "its unit")
            if v > 0:
                setattr(joint, attr, v)


def _subtree_mass(tree, joint):
    """Mass (kg) of the links below a joint, read leniently (for notices only); None if unreadable."""
    total = 0.0
    for l in tree.below(tree.child(joint)):
        el = tree.links[l].find("inertial/mass")
        if el is None:
            continue
        try:
            v = float(el.get("value"))
        except (TypeError, ValueError):
            return None
        if not math.isfinite(v):
            return None
        total += v
    return total


def _notices(tree, base, chain, left_out, robot_joints, chain_text):
    """What was left out of the URDF, for `robot.notices`."""
    name = tree.path.name
    notes = []
    loaded = [(k, o) for k, o in left_out if o is not None]
    grounded = [k for k, o in left_out if o is None]
    if loaded:
        masses = [_subtree_mass(tree, k) for k, _ in loaded]
        mass = (f"{sum(masses):.4g} kg" if all(m is not None for m in masses) else "unknown")
        parts = [f"'{k.get('name')}' (on link '{tree.parent(k)}' of joint '{robot_joints[o].name}')"
                 for k, o in loaded]
        notes.append(f"URDF {name}: the moving joints {', '.join(parts)} hang off the {chain_text} "
                     f"and are left out with everything below them; their mass ({mass}) is NOT in "
                     f"the model, which is the serial chain alone")
    if grounded:
        notes.append(f"URDF {name}: the moving joints {_few([k.get('name') for k in grounded])} hang "
                     f"from the fixed base of the {chain_text} and are left out (they do not change "
                     f"its dynamics)")
    if base != tree.root:
        inside = set(tree.below(base)) - {base}
        outside = [j.get("name") for j in tree.joints
                   if j.get("type") != "fixed" and tree.child(j) not in inside]
        if outside:
            notes.append(f"URDF {name}: the moving joints {_few(outside)} are not below the base "
                         f"'{base}' and are left out: the base is taken as fixed to the ground")
    return notes
