"""Writing a robot and a standard-parameter set as a URDF, and checking physical consistency.

The URDF holds what URDF can hold: per link the mass, centre of mass and
inertia about the centre of mass (`<inertial>`), per joint its placement,
axis, limits and `<dynamics damping friction>` (dynid's `Fv`, `Fc`).
Standard parameters URDF has no field for -- actuator inertia `Ia`, torque
offset `Off`, the friction of a coupled motor (`Fvm6`, `Fcm6`) -- go
into a `<dynid:parameters>` element in dynid's XML namespace, which URDF
parsers ignore; a model that needs them (rotor inertia is Pinocchio's
`armature`) must take them from there or from the JSON written beside.

Each moving joint of the written URDF has axis `0 0 1` and its link frame
is dynid's joint frame, so `dynid.dynamics.urdf.read_urdf` reads back the
same placements and standard parameters (to rounding of the written
decimals: 17 significant digits, i.e. exactly).

Physical consistency of a link (Wensing, Kim, Slotine 2017): the pseudo-inertia
`J = [[tr(I)/2 1 - I, h], [h^T, m]]` (`I` about the frame origin, `h = m c`)
is positive definite. That is the same as: mass > 0, inertia about the centre
of mass positive definite, and its principal moments obeying the triangle
inequality (each at most the sum of the other two), i.e. a non-negative mass
density can have these ten numbers.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

from dynid.errors import InputError

from .urdf import align_z, inertia_about_com

DYNID_NS = "https://github.com/dynid/dynid/urdf-extension"


# ------------------------------------------------------------------ per-link quantities
def link_inertial(values):
    """(m, h, I_o) of one link from its ten standard values in the order XX XY XZ YY YZ ZZ MX MY MZ M."""
    XX, XY, XZ, YY, YZ, ZZ, MX, MY, MZ, M = (float(v) for v in values)
    I_o = np.array([[XX, XY, XZ], [XY, YY, YZ], [XZ, YZ, ZZ]])
    return M, np.array([MX, MY, MZ]), I_o


def pseudo_inertia(values) -> np.ndarray:
    """The 4x4 pseudo-inertia matrix of a link (ten standard values, frame origin)."""
    m, h, I_o = link_inertial(values)
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(I_o) * np.eye(3) - I_o
    J[:3, 3] = J[3, :3] = h
    J[3, 3] = m
    return J


def pseudo_inertia_basis():
    """E_k (10 of 4x4) with J = sum_k value_k E_k, in the order of `dynid.dynamics.robot.INERTIAL`."""
    E = []
    for k in range(10):
        v = np.zeros(10)
        v[k] = 1.0
        E.append(pseudo_inertia(v))
    return np.array(E)


def link_consistency(values, *, tol=0.0) -> dict:
    """Physical-consistency checks of one link's ten standard values (frame origin)."""
    m, h, I_o = link_inertial(values)
    out = {"mass": m, "mass_positive": bool(m > tol)}
    if m > 0:
        c = h / m
        I_c = inertia_about_com(m, c, I_o)
        moments = np.sort(np.linalg.eigvalsh(0.5 * (I_c + I_c.T)))
        out["com"] = c.tolist()
        out["principal_moments"] = moments.tolist()
        out["inertia_positive_definite"] = bool(moments[0] > tol)
        # the largest moment at most the sum of the other two is the binding one
        out["triangle_inequality"] = bool(moments[0] + moments[1] - moments[2] >= -tol)
    else:
        out.update(com=None, principal_moments=None, inertia_positive_definite=False,
                   triangle_inequality=False)
    out["pseudo_inertia_min_eig"] = float(np.linalg.eigvalsh(pseudo_inertia(values))[0])
    out["consistent"] = bool(out["mass_positive"] and out["inertia_positive_definite"]
                             and out["triangle_inequality"] and out["pseudo_inertia_min_eig"] > tol)
    return out


def inertial_slice(robot, j):
    """Indices of link j's (0-based) ten inertial parameters in the standard vector."""
    names = robot.standard_names
    start = names.index(f"XX{j + 1}")
    return slice(start, start + 10)


def consistency(robot, chi_st, *, tol=0.0) -> list:
    """`link_consistency` of every link of `robot` (list, link 1 first)."""
    chi_st = np.asarray(chi_st, dtype=float)
    out = []
    for j in range(robot.n_joints):
        row = link_consistency(chi_st[inertial_slice(robot, j)], tol=tol)
        row["link"] = j + 1
        out.append(row)
    return out


# ------------------------------------------------------------------ writing
def rpy_from_matrix(R):
    """URDF roll-pitch-yaw of a rotation (inverse of `dynid.dynamics.urdf.rpy_matrix`)."""
    R = np.asarray(R, dtype=float)
    sp = -R[2, 0]
    if abs(sp) < 1.0 - 1e-12:
        p = math.asin(max(-1.0, min(1.0, sp)))
        r = math.atan2(R[2, 1], R[2, 2])
        y = math.atan2(R[1, 0], R[0, 0])
    else:                                    # gimbal lock: only r - y (or r + y) is defined
        p = math.copysign(math.pi / 2, sp)
        y = 0.0
        r = math.atan2(math.copysign(1.0, sp) * R[0, 1], R[1, 1])
    return r, p, y


def _f(x) -> str:
    x = float(x)
    if x == 0.0:
        return "0"
    return repr(x)                            # shortest text that reads back to the same float


def _vec(v) -> str:
    return " ".join(_f(x) for x in v)


def _extra_names(robot):
    std = robot.standard_names
    inertial = set()
    for j in range(robot.n_joints):
        inertial.update(std[inertial_slice(robot, j)])
    friction = {f"Fv{j + 1}" for j in range(robot.n_joints)} | {f"Fc{j + 1}" for j in range(robot.n_joints)}
    return [n for n in std if n not in inertial and n not in friction]


def urdf_unrepresentable(robot) -> list:
    """Standard parameters of `robot` a URDF has no field for (Ia, Off, coupling friction)."""
    return _extra_names(robot)


def payload_argument(robot, payload, where):
    """`(link index, ten values about that link's frame, name)` of a `payload` argument, checked.

    `payload`: `{"link": 1-based link, "values": ten values XX..M about the link frame,
    "name": optional}` (dynid.analysis.estimators.payload.payload_link_values gives the values).
    """
    try:
        j = int(payload["link"]) - 1
        values = np.asarray(payload["values"], dtype=float).reshape(10)
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{where}: payload must be {{'link': 1..{robot.n_joints}, 'values': ten numbers "
                         f"XX..M about the link frame}}, got {payload!r}") from None
    if not 0 <= j < robot.n_joints:
        raise InputError(f"{where}: payload link {j + 1} is not a link of robot '{robot.name}' "
                         f"(1..{robot.n_joints})")
    if not np.all(np.isfinite(values)) or not values[9] > 0:
        raise InputError(f"{where}: the payload needs finite values and a positive mass, got mass {values[9]:g}")
    return j, values, str(payload.get("name") or "payload")


def _inertial_element(parent, m, h, I_o):
    c = h / m if m != 0.0 else np.zeros(3)
    I_c = inertia_about_com(m, c, I_o)
    inertial = ET.SubElement(parent, "inertial")
    ET.SubElement(inertial, "origin", {"xyz": _vec(c), "rpy": "0 0 0"})
    ET.SubElement(inertial, "mass", {"value": _f(m)})
    ET.SubElement(inertial, "inertia", {
        "ixx": _f(I_c[0, 0]), "ixy": _f(I_c[0, 1]), "ixz": _f(I_c[0, 2]),
        "iyy": _f(I_c[1, 1]), "iyz": _f(I_c[1, 2]), "izz": _f(I_c[2, 2])})


def urdf_text(robot, chi_st, *, name=None, comment="", link_names=None, payload=None) -> str:
    """The URDF of `robot` with the standard parameters `chi_st`.

    `payload`: an identified payload written as one more link, fixed to its link by a
    `fixed` joint at the link frame (see `payload_argument`).
    `link_names`: names of the n moving links (default `<robot>_link<j>`);
    the root link is `base_link`. Gravity must be along an axis of the base
    frame or not: a fixed `world -> base_link` joint turns the base so that
    gravity is along -z of `world`, as URDF consumers assume.
    """
    chi_st = np.asarray(chi_st, dtype=float)
    if chi_st.shape != (robot.n_standard,):
        raise InputError(f"urdf_text: {chi_st.size} values given, robot '{robot.name}' has "
                         f"{robot.n_standard} standard parameters")
    if not np.all(np.isfinite(chi_st)):
        raise InputError("urdf_text: the standard parameters hold NaN or infinite values")
    std = robot.standard_names
    value = dict(zip(std, chi_st))
    n = robot.n_joints
    links = list(link_names) if link_names else [f"{robot.name}_link{j + 1}" for j in range(n)]
    ET.register_namespace("dynid", DYNID_NS)
    root = ET.Element("robot", {"name": name or robot.name})
    if comment:
        root.append(ET.Comment(" " + comment.replace("--", "-") + " "))
    g = np.asarray(robot.gravity, dtype=float)
    parent = "base_link"
    if np.linalg.norm(g) > 0 and not np.allclose(g / np.linalg.norm(g), [0, 0, -1], atol=1e-12):
        A = align_z(-g)                        # A z = -g/|g|: world z is A^T applied to base -g
        ET.SubElement(root, "link", {"name": "world"})
        j0 = ET.SubElement(root, "joint", {"name": "world_base_joint", "type": "fixed"})
        ET.SubElement(j0, "origin", {"xyz": "0 0 0", "rpy": _vec(rpy_from_matrix(A.T))})
        ET.SubElement(j0, "parent", {"link": "world"})
        ET.SubElement(j0, "child", {"link": "base_link"})
    ET.SubElement(root, "link", {"name": "base_link"})
    for j, joint in enumerate(robot.joints):
        k = j + 1
        q_lo, q_hi = joint.q_limits
        finite = math.isfinite(q_lo) and math.isfinite(q_hi)
        kind = "prismatic" if joint.sigma == 1 else ("revolute" if finite else "continuous")
        if kind == "prismatic" and not finite:
            q_lo, q_hi, finite = -1e3, 1e3, True       # URDF requires limits on a prismatic joint
        el = ET.SubElement(root, "joint", {"name": joint.name, "type": kind})
        ET.SubElement(el, "origin", {"xyz": _vec(joint.p), "rpy": _vec(rpy_from_matrix(joint.R))})
        ET.SubElement(el, "parent", {"link": parent})
        ET.SubElement(el, "child", {"link": links[j]})
        ET.SubElement(el, "axis", {"xyz": "0 0 1"})
        lim = {}
        if finite:
            lim.update(lower=_f(q_lo), upper=_f(q_hi))
        # URDF wants effort and velocity; 0 is read back by dynid as "no limit"
        lim["effort"] = _f(joint.tau_max) if math.isfinite(joint.tau_max) else "0"
        lim["velocity"] = _f(joint.qd_max) if math.isfinite(joint.qd_max) else "0"
        ET.SubElement(el, "limit", lim)
        ET.SubElement(el, "dynamics", {"damping": _f(value[f"Fv{k}"]), "friction": _f(value[f"Fc{k}"])})
        link = ET.SubElement(root, "link", {"name": links[j]})
        m, h, I_o = link_inertial(chi_st[inertial_slice(robot, j)])
        if m != 0.0 or np.any(h) or np.any(I_o):
            _inertial_element(link, m, h, I_o)
        parent = links[j]
    if payload is not None:
        jp, pv, pname = payload_argument(robot, payload, "urdf_text")
        el = ET.SubElement(root, "joint", {"name": f"{pname}_joint", "type": "fixed"})
        ET.SubElement(el, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
        ET.SubElement(el, "parent", {"link": links[jp]})
        ET.SubElement(el, "child", {"link": pname})
        _inertial_element(ET.SubElement(root, "link", {"name": pname}), *link_inertial(pv))
    extras = _extra_names(robot)
    if extras:
        ext = ET.SubElement(root, f"{{{DYNID_NS}}}parameters")
        for nm in extras:
            ET.SubElement(ext, f"{{{DYNID_NS}}}parameter", {"name": nm, "value": _f(value[nm])})
    ET.indent(root, space="  ")
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def read_extra_parameters(path) -> dict:
    """The `<dynid:parameters>` of a URDF written by `urdf_text` (name -> value)."""
    root = ET.parse(path).getroot()
    out = {}
    for ext in root.findall(f"{{{DYNID_NS}}}parameters"):
        for p in ext.findall(f"{{{DYNID_NS}}}parameter"):
            out[p.get("name")] = float(p.get("value"))
    return out
