"""SI units of parameters, from their names (the papers' names: XX1 ... Off1, regrouped ZZ1R).

XX..ZZ and Ia kg m², MX/MY/MZ kg m, M kg, Fv/Fvm N m s/rad, Fc/Fcm/Off N m. The
per-joint parameters of a prismatic joint (`prismatic=`, `prismatic_joints(robot)`) are in
N and m instead: Ia kg, Fv/Fvm N s/m, Fc/Fcm/Off N (and the per-joint figures below the
same way); the inertial parameters' units do not depend on the joint. Beside the dynamic model's names, those of the
other results: the payload's (`XXL` ... `ML`), the asymmetric friction's (`Fv+1`, `Fc-1`),
the per-joint gravity of Bona & Curatella (`k1` N m, `qoff1` rad), the gravity tilt
(`tilt_x`, `tilt_y` rad), a posterior's torque noise (`sigma1` N m) and the drive
gains (`g1`, N m per unit of the logged signal), the controller gains (`Kp1`, `Kd1`, `Ki1`)
and the residual diagnosis' effects (`Fs2` N m, `Ks4` N m/rad, `Rc4k31` N m, ...).
"""
from __future__ import annotations

import re

__all__ = ["parameter_kind", "parameter_unit", "prismatic_joints", "prismatic_of"]

_UNITS = (("XX", "kg m\u00b2"), ("XY", "kg m\u00b2"), ("XZ", "kg m\u00b2"), ("YY", "kg m\u00b2"),
          ("YZ", "kg m\u00b2"), ("ZZ", "kg m\u00b2"), ("MX", "kg m"), ("MY", "kg m"), ("MZ", "kg m"),
          ("Ia", "kg m\u00b2"), ("Fvm", "N m s/rad"), ("Fcm", "N m"), ("Fv", "N m s/rad"),
          ("Fc", "N m"), ("Off", "N m"), ("M", "kg"))
# names of the other results; consulted only when the dynamic model's table has no unit,
# so the verdict's units (the JSON) are those of `_UNITS` alone
_OTHER_UNITS = {"k": "N m", "qoff": "rad", "tilt": "rad", "sigma": "N m", "g": "N m per unit",
                "Kp": "N m/rad", "Kd": "N m s/rad", "Ki": "N m/(rad s)"}
# the per-joint parameters of a prismatic joint: forces and translations
_PRISMATIC_UNITS = {"Ia": "kg", "Fvm": "N s/m", "Fcm": "N", "Fv": "N s/m", "Fc": "N", "Off": "N",
                    "k": "N", "qoff": "m", "sigma": "N", "g": "N per unit", "Kp": "N/m", "Kd": "N s/m",
                    "Ki": "N/(m s)"}
_KIND_RE = re.compile(r"^([A-Za-z]+?)(\d+)R?$")
_OTHER_RE = re.compile(r"^([A-Za-z]+?)(?:[+-]|_[xyz])?(\d*)[RL]?$")


def parameter_kind(name: str) -> str:
    """`ZZ2R` -> `ZZ`; `Fvm6` -> `Fvm`; `M3` -> `M`; unknown patterns -> `""`."""
    m = _KIND_RE.match(str(name))
    return m.group(1) if m else ""


def prismatic_joints(model) -> frozenset:
    """The 1-based numbers of the prismatic joints of `model`: a robot (its joints) or its
    base parameters (`prismatic`); empty for None or anything else."""
    joints = getattr(model, "joints", None)
    if joints is not None:
        return frozenset(i + 1 for i, jt in enumerate(joints) if getattr(jt, "prismatic", False))
    return frozenset(getattr(model, "prismatic", None) or ())


def prismatic_of(owner) -> frozenset:
    """The 1-based prismatic joints of whatever `owner` is: a result that knows them
    (`_prismatic()`), one that holds the IDIM result it started from (`idim`: the diagnosis),
    or a robot or its base parameters (`prismatic_joints`)."""
    for o in (owner, getattr(owner, "idim", None)):
        if hasattr(o, "_prismatic"):
            return frozenset(o._prismatic())
    return prismatic_joints(owner)


def parameter_unit(name: str, prismatic=frozenset()) -> str:
    """SI unit of a parameter from its name pattern (module docstring), `""` if unknown.

    Parameters
    ----------
    name : str
        A parameter name such as `ZZ1R`, `Fv2`, `MXL` or `tilt_x`.
    prismatic : collection of int
        The 1-based numbers of the prismatic joints (`prismatic_joints(robot)`): their
        per-joint parameters are in N and m.

    Returns
    -------
    str
        The unit, e.g. `"kg m²"`; `""` when the name follows no known pattern.

    Examples
    --------
    >>> parameter_unit("ZZ1R"), parameter_unit("Fv2"), parameter_unit("ML")
    ('kg m²', 'N m s/rad', 'kg')
    """
    if prismatic:
        e = _EFFECT_RE.match(str(name))
        if e is not None and int(e.group(2)) in prismatic and e.group(1) in _PRISMATIC_EFFECT_UNITS:
            return _PRISMATIC_EFFECT_UNITS[e.group(1)]
        m = _KIND_RE.match(str(name)) or _OTHER_RE.match(str(name))
        if m is not None and m.group(2) and int(m.group(2)) in prismatic and m.group(1) in _PRISMATIC_UNITS:
            return _PRISMATIC_UNITS[m.group(1)]
    kind = parameter_kind(name)
    for k, u in _UNITS:
        if kind == k:
            return u
    e = _EFFECT_RE.match(str(name))
    if e is not None:
        return _EFFECT_UNITS[e.group(1)]
    m = _OTHER_RE.match(str(name))
    if m is None:
        return ""
    kind = m.group(1)
    if kind in _OTHER_UNITS:
        return _OTHER_UNITS[kind]
    return dict(_UNITS).get(kind, "")


# the residual diagnosis' effect parameters (dynid.analysis.diagnosis.effects): asymmetric friction
# (dFc, dFv), Stribeck level (Fs), position ripple (Rc, Rs), spring (Ks), coupling from another
# joint's speed or acceleration (Cv, Ca), drift (Dv, Dc, Dr), load-dependent friction (Fl, a ratio)
# and the payload's change of the last link (dM, dMX..)
_EFFECT_UNITS = {"dFc": "N m", "dFv": "N m s/rad", "Fs": "N m", "Rc": "N m", "Rs": "N m", "Ks": "N m/rad",
                 "Cv": "N m s/rad", "Ca": "N m s\u00b2/rad", "Dv": "N m s/rad", "Dc": "N m", "Dr": "N m",
                 "Fl": "1", "dMX": "kg m", "dMY": "kg m", "dMZ": "kg m", "dM": "kg"}
#: ... on a prismatic joint (a force; the couplings Cv, Ca depend on the other joint too: left out)
_PRISMATIC_EFFECT_UNITS = {"dFc": "N", "dFv": "N s/m", "Fs": "N", "Rc": "N", "Rs": "N", "Ks": "N/m",
                           "Dv": "N s/m", "Dc": "N", "Dr": "N"}
_EFFECT_RE = re.compile(r"^(dFc|dFv|Fs|Rc|Rs|Ks|Cv|Ca|Dv|Dc|Dr|Fl|dMX|dMY|dMZ|dM)(\d+)(?:k[\d.]+|_\w+)?$")
