"""A random physically consistent standard set near the constraints, for the Panda seeds.

Thin links (one principal moment of inertia 1e-4 kg m^2), no rotor inertia on joints 5-7,
small viscous friction: the truth of benchmarks/physical_seeds.py (which imports it from
here) and of tests/analysis/estimators/test_physical.py's seed-16 check.
"""
import numpy as np


def truth(robot, rng):
    """Standard parameters (robot.n_standard,) drawn with ``rng``."""
    chi = np.zeros(robot.n_standard)
    names = robot.standard_names
    for k in range(1, robot.n_joints + 1):
        m = rng.uniform(0.5, 4.0)
        c = rng.normal(0, 0.05, 3)
        a = rng.uniform(0.005, 0.03)
        # a rod-like link (moments eps, a, a + eps/2): near a singular pseudo-inertia
        moments = rng.permutation([1e-4, a, a + 0.5e-4])
        I_o = np.diag(moments) + m * (c @ c * np.eye(3) - np.outer(c, c))
        for sym, v in zip(("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M"),
                          (I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2], *(m * c), m)):
            chi[names.index(f"{sym}{k}")] = v
        chi[names.index(f"Ia{k}")] = 0.0 if k >= 5 else rng.uniform(0.01, 0.1)
        chi[names.index(f"Fv{k}")] = rng.uniform(0.0, 0.05)
        chi[names.index(f"Fc{k}")] = rng.uniform(0.1, 1.0)
    return chi
