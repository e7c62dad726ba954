"""SI units of parameters, from their names (the papers' names: XX1 ... Off1, regrouped ZZ1R).

XX..ZZ and Ia kg m², MX/MY/MZ kg m, M kg, Fv/Fvm N m s/rad, Fc/Fcm/Off N m (revolute
joints; a prismatic joint's are in N and kg). Beside the dynamic model's names, those of the
other results: the payload's (`XXL` ... `ML`), the asymmetric friction's (`Fv+1`, `Fc-1`),
the per-joint gravity of Bona & Curatella (`k1` N m, `qoff1` rad), the gravity tilt
(`tilt_x`, `tilt_y` rad), a posterior's torque noise (`sigma1` N m) and the drive
gains (`g1`, N m per unit of the logged signal) and the controller gains (`Kp1`, `Kd1`, `Ki1`).
"""
from __future__ import annotations

import re

__all__ = ["parameter_kind", "parameter_unit"]

_UNITS = (("XX", "kg m\u00b2"), ("XY", "kg m\u00b2"), ("XZ", "kg m\u00b2"), ("YY", "kg m\u00b2"),
          ("YZ", "kg m\u00b2"), ("ZZ", "kg m\u00b2"), ("MX", "kg m"), ("MY", "kg m"), ("MZ", "kg m"),
          ("Ia", "kg m\u00b2"), ("Fvm", "N m s/rad"), ("Fcm", "N m"), ("Fv", "N m s/rad"),
          ("Fc", "N m"), ("Off", "N m"), ("M", "kg"))
# names of the other results; consulted only when the dynamic model's table has no unit,
# so the verdict's units (the JSON) are those of `_UNITS` alone
_OTHER_UNITS = {"k": "N m", "qoff": "rad", "tilt": "rad", "sigma": "N m", "g": "N m per unit",
                "Kp": "N m/rad", "Kd": "N m s/rad", "Ki": "N m/(rad s)"}
_KIND_RE = re.compile(r"^([A-Za-z]+?)(\d+)R?$")
_OTHER_RE = re.compile(r"^([A-Za-z]+?)(?:[+-]|_[xyz])?(\d*)[RL]?$")


def parameter_kind(name: str) -> str:
    """`ZZ2R` -> `ZZ`; `Fvm6` -> `Fvm`; `M3` -> `M`; unknown patterns -> `""`."""
    m = _KIND_RE.match(str(name))
    return m.group(1) if m else ""


def parameter_unit(name: str) -> str:
    """SI unit of a parameter from its name pattern (module docstring), `""` if unknown.

    Parameters
    ----------
    name : str
        A parameter name such as `ZZ1R`, `Fv2`, `MXL` or `tilt_x`.

    Returns
    -------
    str
        The unit, e.g. `"kg m²"`; `""` when the name follows no known pattern.

    Examples
    --------
    >>> parameter_unit("ZZ1R"), parameter_unit("Fv2"), parameter_unit("ML")
    ('kg m²', 'N m s/rad', 'kg')
    """
    kind = parameter_kind(name)
    for k, u in _UNITS:
        if kind == k:
            return u
    m = _OTHER_RE.match(str(name))
    if m is None:
        return ""
    kind = m.group(1)
    if kind in _OTHER_UNITS:
        return _OTHER_UNITS[kind]
    return dict(_UNITS).get(kind, "")
