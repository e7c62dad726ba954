"""URDF reader for serial chains.

Each moving joint's frame is the URDF joint frame rotated so that its ``z``
axis is the joint axis (dynid's regressor turns and slides about ``z``): for
``axis = (0, -1, 0)`` that is a rotation of +90 deg about ``x``. Link
inertials (mass, centre of mass and inertia about the centre of mass in the
``<inertial>`` frame) are converted to dynid's standard parameters of that
joint frame: inertia about the frame origin (parallel-axis theorem) and first
moments ``M c``. Fixed joints are merged: their placement folds into the next
moving joint, the inertia of a fixed child link into its parent link.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from dynid.errors import RobotFileError
from .robot import Joint, Robot

_MOVING = {"revolute": 0, "continuous": 0, "prismatic": 1}


def rpy_matrix(r, p, y):
    """URDF fixed-axis roll-pitch-yaw: R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def align_z(axis):
    """A rotation A with A @ [0, 0, 1] = axis (unit), deterministic."""
    a = np.asarray(axis, dtype=float)
    a = a / np.abs(a).max()     # fix: the norm of a huge axis (1e300) overflowed to a NaN rotation
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


def _origin(elem, where, path):
    o = elem.find("origin") if elem is not None else None
    if o is None:
        return np.eye(3), np.zeros(3)
    xyz = _floats(o.get("xyz", "0 0 0"), 3, f"{where} origin xyz", path)
    rpy = _floats(o.get("rpy", "0 0 0"), 3, f"{where} origin rpy", path)
    return rpy_matrix(*rpy), xyz


def _spatial_inertia(link, path):
    """(mass, c, I_origin) of a link's <inertial> in the link frame, or None."""
    inertial = link.find("inertial")
    if inertial is None:
        return None
    name = link.get("name")
    mass_el = inertial.find("mass")
    if mass_el is None:
        raise RobotFileError(f"{path}: link '{name}' has <inertial> without <mass>")
    m = _floats(mass_el.get("value"), 1, f"link '{name}' mass", path)[0]
    R, c = _origin(inertial, f"link '{name}' inertial", path)
    I_el = inertial.find("inertia")
    if I_el is None:
        raise RobotFileError(f"{path}: link '{name}' has <inertial> without <inertia>")
    vals = {}
    for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
        vals[key] = _floats(I_el.get(key, "0"), 1, f"link '{name}' inertia {key}", path)[0]
    Ic = np.array([[vals["ixx"], vals["ixy"], vals["ixz"]],
                   [vals["ixy"], vals["iyy"], vals["iyz"]],
                   [vals["ixz"], vals["iyz"], vals["izz"]]])
    Ic = R @ Ic @ R.T
    return m, c, Ic + m * (c @ c * np.eye(3) - np.outer(c, c))


def _transform_inertia(inertia, R, p):
    """Express (m, c, I_origin) given in frame B in frame A, where x_A = R x_B + p."""
    m, c, I_o = inertia
    c_new = R @ c + p
    # back to the centre of mass, rotate, then to the new origin
    I_c = I_o - m * (c @ c * np.eye(3) - np.outer(c, c))
    I_c = R @ I_c @ R.T
    return m, c_new, I_c + m * (c_new @ c_new * np.eye(3) - np.outer(c_new, c_new))


def _add(a, b):
    if a is None:
        return b
    if b is None:
        return a
    m = a[0] + b[0]
    c = (a[0] * a[1] + b[0] * b[1]) / m if m > 0 else np.zeros(3)
    return m, c, a[2] + b[2]


def read_urdf(path):
    """Read a serial-chain URDF into a Robot (standard parameters as a-priori values)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise RobotFileError(f"cannot read URDF '{path}': {exc.strerror}; check the path and that "
                             f"it is a readable file") from None
    except ValueError:      # fix: a path with a NUL byte raised ValueError
        raise RobotFileError(f"cannot read URDF {str(path)!r}: the path is not valid; check the path") from None
    except ET.ParseError as exc:
        raise RobotFileError(f"URDF '{path}' is not well-formed XML: {exc}; fix the XML there") from None
    if root.tag != "robot":
        raise RobotFileError(f"URDF '{path}': root element must be <robot>, got <{root.tag}>")
    links = {}
    for l in root.findall("link"):
        if not l.get("name"):
            raise RobotFileError(f"{path}: a <link> has no name")
        links[l.get("name")] = l
    joints = root.findall("joint")       # only top-level joints, not <transmission> ones
    children = {}
    for j in joints:
        name = j.get("name") or "?"
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None or not parent.get("link") or not child.get("link"):
            raise RobotFileError(f"{path}: joint '{name}' needs <parent link=...> and <child link=...>")
        missing = [l for l in (parent.get("link"), child.get("link")) if l not in links]
        if missing:
            raise RobotFileError(f"{path}: joint '{name}' refers to link '{missing[0]}' that does not "
                                 f"exist; add <link name=\"{missing[0]}\"> or fix the name")
        if j.get("type") not in _MOVING and j.get("type") != "fixed":
            raise RobotFileError(f"{path}: joint '{name}' has type '{j.get('type')}'; dynid reads "
                                 f"revolute, continuous, prismatic and fixed joints: use one of these")
        children.setdefault(parent.get("link"), []).append(j)
    child_links = {j.find("child").get("link") for j in joints}
    roots = [l for l in links if l not in child_links]
    if len(roots) != 1:
        raise RobotFileError(f"{path}: expected one root link, found {len(roots)} ({', '.join(roots)}); "
                             f"connect every link to the chain with a joint, or remove the stray ones")

    robot_joints, inertias, apriori = [], [], {}
    # pending fixed transform (rotation, translation) from the last moving frame
    A_prev = np.eye(3)                      # alignment of the previous moving frame
    T_R, T_p = np.eye(3), np.zeros(3)       # previous moving frame (URDF) -> current link frame
    link = roots[0]
    cur_inertia_target = None               # index of the moving joint that owns the current link
    visited = set()
    while True:
        if link in visited:
            raise RobotFileError(f"{path}: the kinematic tree has a loop at link '{link}'")
        visited.add(link)
        inertia = _spatial_inertia(links[link], path)
        if cur_inertia_target is not None and inertia is not None:
            # link frame -> aligned frame of the owning joint
            A = robot_joints[cur_inertia_target]._align
            R_lk = A.T @ T_R
            inertias[cur_inertia_target] = _add(inertias[cur_inertia_target],
                                                _transform_inertia(inertia, R_lk, A.T @ T_p))
        kids = children.get(link, [])
        moving_kids = [k for k in kids if k.get("type") in _MOVING]
        if len(kids) == 0:
            break
        if len(kids) > 1:
            if len(moving_kids) > 1:
                raise RobotFileError(f"{path}: link '{link}' has {len(moving_kids)} moving child joints; "
                                     f"dynid reads serial chains only: make the side branches fixed "
                                     f"joints or remove them")
            # fix: the chain goes on through the moving child or through the one fixed
            # child with moving joints below it. Before, with no moving child, the
            # first fixed child was merged as a side branch AND followed (its inertia
            # counted twice), and a fixed joint continuing the chain beside a fixed
            # side branch was rejected as "moves on a side branch".
            if moving_kids:
                leads = moving_kids
            else:
                leads = [k for k in kids if _subtree_moves(k.find("child").get("link"), children, set())]
                if len(leads) > 1:
                    raise RobotFileError(f"{path}: link '{link}' has {len(leads)} fixed child joints "
                                         f"with moving joints below them; dynid reads serial chains "
                                         f"only: remove the extra branches")
            # fixed side branches (sensors, tool frames) carry their inertia to this link
            for k in kids:
                if not leads or k is not leads[0]:
                    _merge_fixed_branch(k, links, children, path, T_R, T_p, cur_inertia_target,
                                        robot_joints, inertias, set())
            if not leads:
                break
            kids = leads
        j = kids[0]
        name = j.get("name")
        R_o, p_o = _origin(j, f"joint '{name}'", path)
        if j.get("type") == "fixed":
            T_p = T_R @ p_o + T_p
            T_R = T_R @ R_o
            cur = None
        else:
            axis = _floats(j.find("axis").get("xyz", "1 0 0") if j.find("axis") is not None else "1 0 0",
                           3, f"joint '{name}' axis", path)
            if np.linalg.norm(axis) < 1e-9:
                raise RobotFileError(f"{path}: joint '{name}' has a zero axis")
            A = align_z(axis)
            # placement of the new aligned frame in the previous aligned frame
            R = A_prev.T @ (T_R @ R_o) @ A
            p = A_prev.T @ (T_R @ p_o + T_p)
            R[np.abs(R) < 1e-15] = 0.0
            p[np.abs(p) < 1e-15] = 0.0
            if not name:    # fix: a moving joint without a name became Joint(name=None)
                raise RobotFileError(f"{path}: a {j.get('type')} joint has no name; give it name=\"...\"")
            joint = Joint(name=name, sigma=_MOVING[j.get("type")], R=R, p=p)
            joint._align = A
            lim = j.find("limit")
            if lim is not None:
                lo, hi = lim.get("lower"), lim.get("upper")
                if lo is not None and hi is not None and j.get("type") != "continuous":
                    lo_v = _floats(lo, 1, f"joint '{name}' limit lower", path)[0]
                    hi_v = _floats(hi, 1, f"joint '{name}' limit upper", path)[0]
                    if lo_v < hi_v:
                        joint.q_limits = (lo_v, hi_v)
                for key, attr in (("velocity", "qd_max"), ("effort", "tau_max")):
                    if lim.get(key) is not None:
                        v = _floats(lim.get(key), 1, f"joint '{name}' limit {key}", path)[0]
                        if v > 0:
                            setattr(joint, attr, v)
            k = len(robot_joints) + 1
            dyn = j.find("dynamics")
            if dyn is not None:
                for key, pname in (("damping", "Fv"), ("friction", "Fc")):
                    if dyn.get(key) is not None:
                        apriori[f"{pname}{k}"] = _floats(dyn.get(key), 1, f"joint '{name}' dynamics {key}", path)[0]
            robot_joints.append(joint)
            inertias.append(None)
            A_prev = A
            T_R, T_p = np.eye(3), np.zeros(3)
            cur_inertia_target = len(robot_joints) - 1
        link = j.find("child").get("link")

    if not robot_joints:
        raise RobotFileError(f"{path}: no revolute or prismatic joint found")
    # fix: duplicated joint names and numbers that overflow (e.g. xyz="1e300 ...") gave
    # robots with clashing names or infinite/NaN placements and parameters
    names = [jt.name for jt in robot_joints]
    dup = sorted({nm for nm in names if names.count(nm) > 1})
    if dup:
        raise RobotFileError(f"{path}: duplicated joint name(s) {', '.join(dup)}; give every joint a "
                             f"unique name")
    for jt, inertia in zip(robot_joints, inertias):
        vals = [jt.R, jt.p] + ([] if inertia is None else [inertia[0], inertia[1], inertia[2]])
        if not all(np.isfinite(v).all() for v in vals):
            raise RobotFileError(f"{path}: joint '{jt.name}' or its link has origins or inertials too "
                                 f"large to compute with; check the numbers (metres, kg, kg m^2)")
    for k, inertia in enumerate(inertias, start=1):
        if inertia is None:
            continue
        m, c, I = inertia
        apriori.update({f"XX{k}": I[0, 0], f"XY{k}": I[0, 1], f"XZ{k}": I[0, 2],
                        f"YY{k}": I[1, 1], f"YZ{k}": I[1, 2], f"ZZ{k}": I[2, 2],
                        f"MX{k}": m * c[0], f"MY{k}": m * c[1], f"MZ{k}": m * c[2], f"M{k}": m})
    for jt in robot_joints:
        del jt._align
    robot = Robot(name=root.get("name") or path.stem, joints=robot_joints,
                  gravity=np.array([0.0, 0.0, -9.81]), source=str(path),
                  description=f"read from URDF {path.name}")
    robot.apriori = {k: float(v) for k, v in apriori.items()}
    robot.provenance = {"kinematics": f"URDF {path.name}", "apriori": f"URDF {path.name} inertials and <dynamics>"}
    return robot


def _subtree_moves(link, children, seen):
    """Whether a moving joint hangs anywhere below ``link`` (cycle-safe)."""
    if link in seen:
        return False
    seen.add(link)
    return any(k.get("type") in _MOVING or _subtree_moves(k.find("child").get("link"), children, seen)
               for k in children.get(link, []))


def _merge_fixed_branch(joint, links, children, path, T_R, T_p, target, robot_joints, inertias, seen):
    """Add the inertia of a fixed side branch to the moving link it hangs from."""
    if target is None:
        return
    R_o, p_o = _origin(joint, f"joint '{joint.get('name')}'", path)
    R = T_R @ R_o
    p = T_R @ p_o + T_p
    child = joint.find("child").get("link")
    if child in seen:   # fix: a cycle of fixed joints recursed until RecursionError
        raise RobotFileError(f"{path}: the fixed joints below joint '{joint.get('name')}' form a loop "
                             f"at link '{child}'; remove the joint that closes it")
    seen.add(child)
    inertia = _spatial_inertia(links[child], path)
    if inertia is not None:
        A = robot_joints[target]._align
        inertias[target] = _add(inertias[target], _transform_inertia(inertia, A.T @ R, A.T @ p))
    for k in children.get(child, []):
        if k.get("type") != "fixed":
            raise RobotFileError(f"{path}: joint '{k.get('name')}' moves on a side branch; "
                                 f"dynid reads serial chains only")
        _merge_fixed_branch(k, links, children, path, R, p, target, robot_joints, inertias, seen)
