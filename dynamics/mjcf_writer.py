"""Writing a robot and a standard-parameter set as MuJoCo MJCF.

Per link a `<body>` placed like dynid's joint frame (`pos`/`quat` of
the joint placement, then a `hinge` -- or `slide` -- joint along its z
axis, as `dynid.dynamics.urdf_writer` does), its `<inertial>` (mass,
centre of mass, full inertia about the centre of mass), and per joint

* `armature` = Ia (rotor inertia reflected to the joint: MuJoCo adds it to
  the diagonal of the joint-space inertia, exactly dynid's Ia qdd);
* `damping` = Fv (MuJoCo's passive force -Fv qd, dynid's Fv qd);
* `frictionloss` = Fc. This is *not* dynid's Coulomb term Fc sign(qd):
  MuJoCo makes dry friction a soft constraint solved with the other
  constraints, a force of magnitude at most Fc that opposes the motion
  without the sign discontinuity (near qd = 0 it is smaller than Fc, it
  holds a joint at rest against a load below Fc, and the soft-constraint
  parameters `solreffriction`/`solimpfriction` set how quickly it
  saturates). The file sets `solimpfriction` near-hard (`SOLIMP_FRICTION`)
  so that inverse dynamics (`mj_inverse`) of a moving joint give Fc sign(qd).

A coupled rotor (the TX40 wrist: rotor 6 turns with q5 + q6; section 4 of
Gautier, Janot & Vandanjon 2010, eq. (33)) is a fixed `<tendon>` over the
joints it turns with, coefficients `c_k / c_motor`: its `armature` Ia_motor
adds Ia_motor c c^T / c_motor^2 to M, so the joints' own armatures are
lowered by the diagonal part dynid already counts in their Ia; its
`damping` and `frictionloss` are the motor friction `Fvm`, `Fcm` (times
c_motor, as the tendon's velocity is w / c_motor). What MJCF has no field for:
the torque offset `Off` (a constant added to the measured torque, not a
property of the arm); it is listed in a comment and is in the JSON.

`springs` (the `spring` effect of `dynid.analysis.diagnosis.effects`, fitted
beside the rigid body by `dynid.analysis.diagnosis.physical_fit`): dynid's
column is `+q_j` in the joint torque, the drive gives `Ks_j q_j`; MuJoCo's joint
spring is the passive force `-stiffness (q - springref)`, which the drive must
balance, so `stiffness = Ks_j` and `springref = 0` (a spring `k (q_j - q0)`
is `Ks q_j` plus a constant, which dynid puts in `Off`). MuJoCo's compiler
keeps a negative stiffness and its passive force applies it with its sign
(`mj_inverse` gives `+stiffness q`, `mj_step` follows the anti-spring;
checked with MuJoCo 3.3.0 and 4.0.0, and by `tests/integration/test_replay.py`), so a
negative `Ks` is written as it is and the file's comment says so.
Gravity is MJCF's `<option gravity>`, in dynid's base frame (MuJoCo's world).
One `<motor>` actuator per joint (gear 1, unbounded) drives it with torque.
Bodies get no geometry: the model is for dynamics, not for contact.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

from dynid.dynamics.urdf import inertia_about_com
from dynid.dynamics.urdf_writer import _f, _vec, inertial_slice, link_inertial, payload_argument
from dynid.errors import InputError

__all__ = ["mjcf_text", "mjcf_unrepresentable", "SOLIMP_FRICTION"]

#: near-hard dry friction: with MuJoCo's default impedance (d = 0.9 .. 0.95) the friction force of
#: a light joint (a wrist) stays well below Fc at the speeds of an identification trajectory,
#: because the constraint's regulariser scales with the joint's inverse inertia; with d = 0.9999
#: a moving joint gets Fc sign(qd), dynid's model, and one at rest is still held softly
SOLIMP_FRICTION = "0.9999 0.9999 0.001 0.5 2"

_FRICTION_NOTE = (
    "frictionloss is MuJoCo's dry friction: a soft constraint force of magnitude at most Fc that "
    "opposes the motion, with no sign discontinuity (dynid's model is Fc sign(qd)); damping = Fv "
    "(viscous), armature = Ia (rotor inertia). Not written (no MJCF field): ")


def _quat(R):
    """Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.array(q)
    return q / np.linalg.norm(q)


def mjcf_unrepresentable(robot) -> list:
    """Standard parameters of `robot` an MJCF has no field for (Off, coupled-rotor friction)."""
    per_joint = {f"{s}{j + 1}" for j in range(robot.n_joints) for s in ("Ia", "Fv", "Fc")}
    per_joint |= {nm for c in robot.couplings for nm in c.parameter_names}
    inertial = {nm for j in range(robot.n_joints) for nm in robot.standard_names[inertial_slice(robot, j)]}
    return [n for n in robot.standard_names if n not in per_joint and n not in inertial]


def _springs(robot, springs):
    """`{joint (1-based): Ks}` checked: whole joint numbers of `robot`, finite values."""
    out = {}
    for j, k in dict(springs or {}).items():
        if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or not 1 <= j <= robot.n_joints:
            raise InputError(f"mjcf_text: spring on joint {j!r}: joints of '{robot.name}' are "
                             f"1..{robot.n_joints}")
        try:
            k = float(k)
        except (TypeError, ValueError):
            raise InputError(f"mjcf_text: spring Ks{j} = {k!r} is not a number") from None
        if not math.isfinite(k):
            raise InputError(f"mjcf_text: spring Ks{j} = {k} is not finite; the model cannot be "
                             "written as MJCF")
        out[int(j)] = k
    return dict(sorted(out.items()))


def _checked_parameters(robot, chi_st):
    """`chi_st` as a float array of `robot`'s standard parameters: right length, all finite."""
    chi_st = np.asarray(chi_st, dtype=float)
    if chi_st.shape != (robot.n_standard,):
        raise InputError(f"mjcf_text: {chi_st.size} values given, robot '{robot.name}' has "
                         f"{robot.n_standard} standard parameters")
    if not np.all(np.isfinite(chi_st)):
        raise InputError("mjcf_text: the standard parameters hold NaN or infinite values")
    return chi_st


def _coupled_rotors(robot, value, armature):
    """Tendons of the coupled rotors `(coupling, coef / c_motor, Ia_motor, damping, frictionloss)`
    and their note; lowers `armature` (in place) by the share of Ia_motor dynid counts in the joints'."""
    tendons, note = [], ""
    for c in robot.couplings:
        coef = np.asarray(c.coefficients, dtype=float)
        cm = coef[list(c.joints).index(c.motor)] if c.motor in c.joints else 1.0
        ia_m = value[f"Ia{c.motor}"]
        for jn, k in zip(c.joints, coef):
            armature[jn - 1] -= ia_m * (k / cm) ** 2
        fv, fc = ((value[f"Fvm{c.motor}"], value[f"Fcm{c.motor}"]) if c.friction else (0.0, 0.0))
        tendons.append((c, coef / cm, ia_m, fv * cm * cm, fc * abs(cm)))
        note += (f"; rotor {c.motor} turns joints {list(c.joints)}: tendon {robot.name}_rotor{c.motor}, "
                 f"joint armatures lowered by the part of Ia{c.motor} it carries")
    return tendons, note


def _clip_armature(robot, armature):
    """`armature` with negative entries written 0, and the note naming those joints ("" if none)."""
    clipped = [j + 1 for j in range(robot.n_joints) if armature[j] < 0]
    if not clipped:
        return armature, ""
    return np.maximum(armature, 0.0), ("; armature of joint(s) " + ", ".join(map(str, clipped)) + " would be "
                                       "negative (joint Ia below the coupled rotor's share) and is written 0")


def _springs_note(springs):
    """The comment's part on the joint springs ("" without springs)."""
    if not springs:
        return ""
    note = ("; joint springs (dynid's Ks q in the drive torque): stiffness = Ks, springref = 0: "
            + ", ".join(f"Ks{j} = {_f(k)}" for j, k in springs.items()))
    negative = [j for j, k in springs.items() if k < 0]
    if negative:
        note += ("; negative stiffness on joint(s) " + ", ".join(map(str, negative)) + ": a spring "
                 "pushing away from q = 0, which MuJoCo's passive force applies with its sign")
    return note


def _inertial_attrs(m, h, I_o):
    """`<inertial>` attributes of a body of mass `m`, first moments `h`, inertia `I_o` about its frame."""
    c = h / m
    I_c = inertia_about_com(m, c, I_o)
    return {"pos": _vec(c), "mass": _f(m),
            "fullinertia": _vec([I_c[0, 0], I_c[1, 1], I_c[2, 2], I_c[0, 1], I_c[0, 2], I_c[1, 2]])}


def _joint_attrs(joint, k, armature, value, springs):
    """`<joint>` attributes of joint `k` (1-based)."""
    attrs = {"name": joint.name, "type": "slide" if joint.sigma == 1 else "hinge",
             "pos": "0 0 0", "axis": "0 0 1", "armature": _f(armature),
             "damping": _f(value[f"Fv{k}"]), "frictionloss": _f(value[f"Fc{k}"]),
             "solimpfriction": SOLIMP_FRICTION}
    lo, hi = joint.q_limits
    if math.isfinite(lo) and math.isfinite(hi):
        attrs["range"] = f"{_f(lo)} {_f(hi)}"
    if k in springs:
        attrs.update(stiffness=_f(springs[k]), springref="0")
    return attrs


def _add_links(root, robot, chi_st, armature, value, springs, pay):
    """The chain of `<body>` elements under `<worldbody>`, the payload welded to its link."""
    parent = ET.SubElement(root, "worldbody")
    for j, joint in enumerate(robot.joints):
        k = j + 1
        m, h, I_o = link_inertial(chi_st[inertial_slice(robot, j)])
        if not m > 0:
            raise InputError(f"mjcf_text: link {k} has mass {m:g}; MuJoCo needs a positive mass on every "
                             "moving body: export a physically consistent set (--physical)")
        body = ET.SubElement(parent, "body", {"name": f"{robot.name}_link{k}", "pos": _vec(joint.p),
                                              "quat": _vec(_quat(joint.R))})
        ET.SubElement(body, "joint", _joint_attrs(joint, k, armature[j], value, springs))
        ET.SubElement(body, "inertial", _inertial_attrs(m, h, I_o))
        if pay is not None and pay[0] == j:
            pb = ET.SubElement(body, "body", {"name": pay[2], "pos": "0 0 0"})
            ET.SubElement(pb, "inertial", _inertial_attrs(*link_inertial(pay[1])))
        parent = body


def _add_tendons(root, robot, tendons):
    """One fixed `<tendon>` per coupled rotor (none without couplings)."""
    if not tendons:
        return
    ten = ET.SubElement(root, "tendon")
    for c, coef, ia_m, fv, fc in tendons:
        fixed = ET.SubElement(ten, "fixed", {"name": f"{robot.name}_rotor{c.motor}", "armature": _f(ia_m),
                                             "damping": _f(fv), "frictionloss": _f(fc),
                                             "solimpfriction": SOLIMP_FRICTION})
        for jn, k in zip(c.joints, coef):
            ET.SubElement(fixed, "joint", {"joint": robot.joints[jn - 1].name, "coef": _f(k)})


def mjcf_text(robot, chi_st, *, name=None, comment="", springs=None, payload=None) -> str:
    """The MJCF of `robot` with the standard parameters `chi_st` (see the module doc).

    Every link must be physically consistent with positive mass (MuJoCo's
    compiler rejects others): export a PC-WLS solution
    (`dynid.analysis.estimators.physical`), not an unconstrained fit.
    `springs`: `{joint (1-based): Ks}` [N m/rad, N/m for a prismatic joint], the
    linear springs `Ks_j q_j` fitted with that rigid body, written as the joint's
    `stiffness` with `springref` 0.
    `payload`: an identified payload written as a child body of its link without a joint
    (welded), `{"link": 1-based, "values": ten values about the link frame, "name": ...}`.
    """
    springs = _springs(robot, springs)
    pay = None if payload is None else payload_argument(robot, payload, "mjcf_text")
    chi_st = _checked_parameters(robot, chi_st)
    value = dict(zip(robot.standard_names, chi_st))
    root = ET.Element("mujoco", {"model": name or robot.name})
    if comment:
        root.append(ET.Comment(" " + comment.replace("--", "-") + " "))
    missing = mjcf_unrepresentable(robot)
    note = _FRICTION_NOTE + (", ".join(f"{n} = {_f(value[n])}" for n in missing) or "nothing")
    armature = np.array([value[f"Ia{j + 1}"] for j in range(robot.n_joints)])
    tendons, rotor_note = _coupled_rotors(robot, value, armature)
    armature, clip_note = _clip_armature(robot, armature)
    note += rotor_note + clip_note + _springs_note(springs)
    root.append(ET.Comment(" " + note.replace("--", "-") + " "))
    # balanceinertia off: the written inertia is the identified one, never adjusted by the compiler
    ET.SubElement(root, "compiler", {"angle": "radian", "balanceinertia": "false", "autolimits": "true"})
    ET.SubElement(root, "option", {"gravity": _vec(robot.gravity)})
    _add_links(root, robot, chi_st, armature, value, springs, pay)
    _add_tendons(root, robot, tendons)
    act = ET.SubElement(root, "actuator")
    for joint in robot.joints:
        ET.SubElement(act, "motor", {"name": f"{joint.name}_motor", "joint": joint.name, "gear": "1"})
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"
