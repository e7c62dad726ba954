"""Benchmark of one DIDIM step (analysis/didim.py) on 20 s of 5 kHz TX40 data.

One Gauss-Newton step of DIDIM = closed-loop simulation of 100,000 controller
steps (numba RK4, TX40 under its PD controller) + base regressor of the
simulated states + parallel decimation with the measured torque + per-joint
WLS. The paper reports 7 minutes per step (Simulink, 2008 PC); the goal here
is under 3 s.

Side by side, in the same run, the same closed loop (same controller, ZOH and
RK4 step) as a plain-Python loop on Pinocchio:

* ``pin.aba`` on the TX40 rigid body with the rotor inertias as Pinocchio's
  armature (diag(Ia)); the wrist coupling's off-diagonal rotor term, which ABA
  cannot take, is left out, so this is the cost of an ABA-based loop, not the
  exact TX40 dynamics;
* tests/support/oracles.py ``pin_closed_loop``: the exact TX40 dynamics through
  ``crba`` + ``nonLinearEffects`` + a 6x6 solve (what the tests compare with).

The Python loops are timed on the first ``--pin-seconds`` s (default 1 s,
5,000 steps) and scaled linearly to 100,000 steps (the cost per step does not
depend on the motion). BLAS runs single-threaded (OPENBLAS_NUM_THREADS=1 unless
set): the least squares work on small matrices, which multi-threaded OpenBLAS
slows down by 30x on a busy 2-core machine.

Run from the repository root: python benchmarks/didim.py
The last line is a JSON object with the figures.
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "support"))

import numpy as np  # noqa: E402

PAPER_STEP_S = 7 * 60.0
GOAL_S = 3.0


def make_data(duration, fs, seed):
    from dynid.analysis.data.synthetic import simulate_experiment, tx40_true_parameters
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    from dynid.dynamics.trajectories import random_fourier_trajectory

    robot = load_robot("tx40")
    bp = base_parameters(robot)
    beta, chi = tx40_true_parameters(robot, bp)
    rng = np.random.default_rng(seed)
    traj = random_fourier_trajectory(robot, 0.1, 10, rng)
    exp = simulate_experiment(robot, chi, traj, duration, rng=rng, q_noise=4e-5,
                              tau_noise=[2.0, 2.0, 0.7, 0.25, 0.4, 0.25], fs=fs,
                              name="simulated TX40 (dynid)")
    return robot, bp, beta, chi, exp


def didim_step(robot, bp, exp, workers=1):
    from dynid.analysis.estimators.didim import identify_didim

    t0 = time.perf_counter()
    res = identify_didim(exp, robot, bp=bp, max_iter=1, essential=False, workers=workers)
    return time.perf_counter() - t0, res


def dynid_simulation(robot, chi, t, qr, qdr):
    from dynid.dynamics.simulation import simulate_closed_loop

    t0 = time.perf_counter()
    sim = simulate_closed_loop(robot, chi, t, qr, qdr, q0=qr[0], qd0=qdr[0], v_s=0.05,
                               feedforward=True, saturate=False)
    return time.perf_counter() - t0, sim


def pin_aba_loop(robot, chi, t, qr, qdr, v_s=0.05):
    """The closed loop of dynid.dynamics.simulation in plain Python on pin.aba (diagonal armature)."""
    import oracles
    pin = oracles.pin
    model = oracles.pin_model_from_robot(robot, chi)
    model.armature = np.array([chi[14 * j + 10] for j in range(robot.n_joints)])
    data = model.createData()
    ctrl = robot.controller
    kp = ctrl.wn / (2 * ctrl.zeta)
    kv = 2 * ctrl.zeta * ctrl.wn
    scale = np.asarray(ctrl.J_ap, float) / np.asarray(ctrl.g_ap, float)
    g = robot.drive_gains

    def plant(q, qd, tau):
        return pin.aba(model, data, q, qd, tau - oracles.friction_torques(robot, chi, qd, v_s))

    q, qd = qr[0].copy(), qdr[0].copy()
    Q = np.empty_like(qr)
    t0 = time.perf_counter()
    for k in range(len(t)):
        tau = g * scale * kv * (kp * (qr[k] - q) - qd + qdr[k])
        Q[k] = q
        if k == len(t) - 1:
            break
        h = t[k + 1] - t[k]
        q, qd = oracles.rk4_step(plant, q, qd, tau, h, plant(q, qd, tau))
    return time.perf_counter() - t0, Q


def pin_exact_loop(robot, chi, t, qr, qdr, v_s=0.05):
    import oracles
    t0 = time.perf_counter()
    Q = oracles.pin_closed_loop(robot, chi, t, qr, qdr, qr[0], qdr[0], v_s=v_s, feedforward=True,
                                saturate=False)[0]
    return time.perf_counter() - t0, Q


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=20.0, help="recording length, s (default 20)")
    ap.add_argument("--pin-seconds", type=float, default=1.0,
                    help="stretch the Python Pinocchio loops are timed on, s (default 1)")
    ap.add_argument("--repeat", type=int, default=3, help="DIDIM step repetitions, best kept")
    ap.add_argument("--workers", type=int, default=1, help="threads building the regressor (default 1)")
    args = ap.parse_args()
    import oracles

    fs = 5000.0
    robot, bp, beta, chi, exp = make_data(args.duration, fs, seed=1)
    n_steps = exp.t.size
    print(f"data: simulated TX40, {args.duration:g} s at {fs:g} Hz = {n_steps:,} controller steps "
          f"(BLAS threads: {os.environ.get('OPENBLAS_NUM_THREADS')})")

    # one DIDIM step, from chi^0 (eq. (31)); the first call also loads the numba caches
    didim_step(robot, bp, exp, args.workers)
    step_s, res = min((didim_step(robot, bp, exp, args.workers) for _ in range(args.repeat)),
                      key=lambda r: r[0])
    sim_in_step = res.timings[0]["simulation_s"]
    print(f"one DIDIM step: {step_s:.2f} s (goal {GOAL_S:g} s; the paper: {PAPER_STEP_S / 60:.0f} min) = "
          f"closed-loop simulation {sim_in_step:.2f} s + regressor, decimation and WLS "
          f"{step_s - sim_in_step:.2f} s; {res.t_dec.size} decimated samples, relative error "
          f"{res.result.rel_error:.4f} after 1 step ({args.workers} regressor thread(s))")

    # the closed loop alone, dynid vs Pinocchio, with the true parameters
    t, qr = exp.t, exp.qr
    qdr = np.gradient(qr, t, axis=0, edge_order=2)
    dynid_s, sim = min((dynid_simulation(robot, chi, t, qr, qdr) for _ in range(args.repeat)),
                       key=lambda r: r[0])
    m = int(round(args.pin_seconds * fs))
    chi_pin = oracles.pin_compatible_parameters(robot, bp, beta)
    aba_s, Q_aba = pin_aba_loop(robot, chi_pin, t[:m], qr[:m], qdr[:m])
    exact_s, Q_exact = pin_exact_loop(robot, chi_pin, t[:m], qr[:m], qdr[:m])
    scale = (n_steps - 1) / (m - 1)
    aba_full, exact_full = aba_s * scale, exact_s * scale
    agree = float(np.max(np.abs(Q_exact - sim.q[:m])))
    print(f"closed loop, {n_steps:,} steps: dynid (numba) {dynid_s:.2f} s "
          f"({1e6 * dynid_s / n_steps:.1f} us/step)")
    print(f"  Pinocchio aba Python loop: {aba_s:.2f} s for {m:,} steps -> {aba_full:.1f} s for "
          f"{n_steps:,} (x{aba_full / dynid_s:.0f} dynid)")
    print(f"  Pinocchio crba+solve Python loop (exact TX40, tests/support/oracles.py): {exact_s:.2f} s for "
          f"{m:,} steps -> {exact_full:.1f} s (x{exact_full / dynid_s:.0f} dynid); "
          f"max |q_pin - q_dynid| = {agree:.1e} rad")
    print(json.dumps({
        "samples": int(n_steps), "fs": fs,
        "didim_step_s": round(step_s, 3), "didim_step_simulation_s": round(sim_in_step, 3),
        "didim_step_rest_s": round(step_s - sim_in_step, 3), "goal_s": GOAL_S,
        "paper_step_s": PAPER_STEP_S,
        "dynid_simulation_s": round(dynid_s, 3),
        "pinocchio_aba_loop_s": round(aba_full, 2), "pinocchio_exact_loop_s": round(exact_full, 2),
        "pinocchio_timed_steps": m, "ratio_aba_to_dynid": round(aba_full / dynid_s, 1),
        "ratio_exact_to_dynid": round(exact_full / dynid_s, 1),
        "max_q_difference_rad": agree,
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"), "regressor_threads": args.workers,
    }))


if __name__ == "__main__":
    main()
