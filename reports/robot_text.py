"""What `dynid robot` prints and writes: a robot's kinematics, standard and base parameters."""
from __future__ import annotations


def robot_text(robot, bp) -> str:
    """The DH table (or URDF joints), couplings, standard parameters and base-parameter relations."""
    out = [f"robot '{robot.name}': {robot.n_joints} joints"
           + (f" — {robot.description}" if robot.description else "")]
    dh = robot.dh_table()
    if dh:
        out.append("\nmodified DH (Khalil-Kleinfinger):")
        out.append(f"  {'j':>2} {'name':<10} {'sigma':>5} {'alpha/rad':>9} {'d/m':>8} {'theta/rad':>9} {'r/m':>8}")
        for (j, sg, a, d, th, r), name in zip(dh, robot.joint_names):
            out.append(f"  {j:>2} {name:<10} {sg:>5} {a:>9.4f} {d:>8.4f} {th:>9.4f} {r:>8.4f}")
    else:
        out.append("\njoints (from URDF; frames rotated so each axis is z): " + ", ".join(robot.joint_names))
    for c in robot.couplings:
        out.append(f"coupling: motor {c.motor} turns with joints {list(c.joints)} "
                   f"(coefficients {list(c.coefficients)})")
    out.append(f"\n{robot.n_standard} standard parameters:")
    names = robot.standard_names
    for k in range(0, len(names), 14):
        out.append("  " + " ".join(names[k:k + 14]))
    out.append(f"\n{bp.n_base} base parameters:")
    for rel in bp.relations:
        out.append("  " + rel)
    if bp.unidentifiable:
        out.append(f"\nno effect on the dynamics ({len(bp.unidentifiable)}): " + " ".join(bp.unidentifiable))
    notices = list(getattr(robot, "notices", None) or [])
    if notices:
        out.append("\nnotices:")
        out += [f"  - {n}" for n in notices]
    return "\n".join(out)


def robot_doc(robot, bp) -> dict:
    """The JSON document of `dynid robot --json`."""
    dh = robot.dh_table()
    return {"robot": robot.name, "n_joints": robot.n_joints, "source": robot.source,
            "standard": robot.standard_names, "base": bp.table(), "unidentifiable": bp.unidentifiable,
            "dh": [dict(zip(("j", "sigma", "alpha", "d", "theta", "r"), row)) for row in dh] if dh else None,
            "couplings": [{"motor": c.motor, "joints": list(c.joints),
                           "coefficients": list(c.coefficients)} for c in robot.couplings],
            "regrouping_matrix": bp.matrix.tolist(), "provenance": robot.provenance,
            "notices": list(getattr(robot, "notices", None) or [])}
