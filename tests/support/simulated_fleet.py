"""A simulated production fleet, for tests and benchmarks (not part of the dynid package).

Imported by tests/analysis/fleet/test_fleet.py (tests/support/ is on the path, conftest.py) and by benchmarks/fleet.py and
benchmarks/chunked_memory.py (which put tests/support/ on the path).

N robots x D days, one recording a day at a random hour: the robot repeats its
cell's pick-and-place cycle (trapezoidal-velocity moves between a few poses with
dwells, as production programs do, not an excitation trajectory), simulated in
closed loop by `dynid.dynamics.simulation.simulate_closed_loop` with the
sensor model of `dynid.analysis.data.synthetic.simulate_experiment`
(integrating torque sensor, white noise on q and tau).

What varies: each robot's parameters (inertial +-5 %, friction +-20 %); the
temperature (a daily cycle plus the robot's place in the hall) acting on the
friction as `F (1 + c (T - 25))`, c = -0.8 %/K; wear on one joint of a fraction
of the robots: Fv and Fc of that joint rise from a random day on, linearly over
`ramp_days` to +20 .. +40 %; and a few corrupted logs (non-finite torques, a
torn file, a missing column).

Default robot: `planar2` at 200 Hz, 9 s per recording: one simulation takes
about 50 ms and one identification 30 ms on one core, so 200 x 30 recordings fit
in a few minutes on 2 cores, while the friction parameters are still identified
to 2-3 % (a 20 % change is 7 sigma).
"""
from __future__ import annotations

import functools
import os
import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

#: friction's temperature coefficient of the simulated gearboxes, 1/K
TEMPERATURE_COEFFICIENT = -0.008
START = pd.Timestamp("2026-03-02T00:00:00Z")


@dataclass
class SimulatedFleet:
    """The files written and what was simulated."""

    catalogue: str               # path of catalogue.csv
    robots: pd.DataFrame         # robot_id, worn_joint (0 = none), onset_day (index), wear (fraction)
    corrupted: list              # recording paths written corrupted on purpose
    n_days: int


def _robot_plan(rng, n_robots, n_days, wear_fraction, n_joints):
    rows = []
    worn = set(rng.choice(n_robots, size=int(round(wear_fraction * n_robots)), replace=False).tolist())
    for r in range(n_robots):
        w = r in worn
        rows.append({"robot_id": f"R{r:03d}", "worn_joint": int(rng.integers(1, n_joints + 1)) if w else 0,
                     "onset_day": int(rng.integers(max(10, n_days // 3), max(11, n_days - 5))) if w else -1,
                     "wear": float(rng.uniform(0.2, 0.4)) if w else 0.0,
                     "spread_seed": int(rng.integers(2**31)), "hall_offset": float(rng.normal(0, 2.0))})
    return pd.DataFrame(rows)


def _cycle(rng, poses, fs, n_moves):
    from dynid.dynamics.joint_trajectories import piecewise_acceleration
    durations, accel = [0.3], [np.zeros(poses.shape[1])]
    q = poses[0]
    for k in range(n_moves):
        target = poses[(k + 1) % len(poses)] + rng.normal(0, 0.03, poses.shape[1])
        T = rng.uniform(0.8, 1.5)           # the cycle's move time, varied by the program's speed override
        ta = T / 3
        A = (target - q) / (ta * (T - ta))
        durations += [ta, T - 2 * ta, ta, 0.25]
        accel += [A, 0 * A, -A, 0 * A]
        q = target
    return piecewise_acceleration(durations, accel, fs, poses[0])


@functools.lru_cache(maxsize=8)
def _robot(spec: str):
    # one load per worker process and robot model, as dynid.analysis.fleet does, through public names
    from dynid.analysis.identify import as_robot
    from dynid.dynamics.base_parameters import base_parameters
    robot = as_robot(spec)
    return robot, base_parameters(robot)


def simulate_recording(job: dict) -> str:
    """Simulate and write one recording (a job of `simulate_fleet`); returns its path."""
    from dynid.analysis.data.synthetic import apriori_parameters
    from dynid.dynamics.simulation import simulate_closed_loop
    robot, bp = _robot(job["robot"])
    rng = np.random.default_rng(job["seed"])
    spread = np.random.default_rng(job["spread_seed"])
    chi = apriori_parameters(robot, bp).copy()
    names = robot.standard_names
    n = robot.n_joints
    inertial = spread.normal(1.0, 0.05, len(names))
    friction = spread.uniform(0.8, 1.2, len(names))
    poses = spread.uniform(-1.0, 1.0, (4, n)) * np.array([min(2.0, 0.8 * hi) for _, hi in
                                                         (j.q_limits for j in robot.joints)])
    for k, name in enumerate(names):
        m = re.search(r"(\d+)$", name)
        joint = int(m.group(1)) if m else 0
        if name.startswith(("Fv", "Fc")):
            f = friction[k] * (1 + TEMPERATURE_COEFFICIENT * (job["temperatures"][joint - 1] - 25.0))
            if joint == job["worn_joint"]:
                f *= 1 + job["wear_now"]
            chi[k] *= f
        else:
            chi[k] *= inertial[k]
    ref = _cycle(rng, poses, job["fs"], job["moves"])
    sim = simulate_closed_loop(robot, chi, ref.t, ref.q, ref.qd, q0=ref.q[0], qd0=ref.qd[0], v_s=0.01,
                               substeps=4, feedforward=True, rate=job["fs"])
    tau = sim.tau.copy()
    tau[1:] = 0.5 * (sim.tau[1:] + sim.tau[:-1])     # integrating torque sensor (see synthetic.py)
    q = sim.q + rng.normal(size=sim.q.shape) * 4e-5
    tau = tau + rng.normal(size=tau.shape) * 0.2
    path = job["path"]
    kind = job.get("corrupt")
    if kind == "nan":
        tau[len(tau) // 3: len(tau) // 3 + 20, 0] = np.nan
    if kind == "torn":
        from dynid.outputs import atomic_write_bytes
        atomic_write_bytes(path, b"PK\x03\x04" + rng.bytes(300))     # a zip cut short by a full disk
        return path
    arrays = {"t": ref.t, "q": q, "qr": ref.q, "tau": tau}
    if kind == "column":
        arrays = {"t": ref.t, "q": q}
    tmp = path + ".part.npz"
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return path


def simulate_fleet(folder, n_robots: int = 20, n_days: int = 30, *, seed: int = 1, robot: str = "planar2",
                   fs: float = 200.0, moves: int = 6, wear_fraction: float = 0.3, n_corrupted: int = 3,
                   ramp_days: int = 2, client=None, write: bool = True) -> SimulatedFleet:
    """Write a simulated fleet's recordings and `catalogue.csv` to `folder`.

    `client`: a Dask client to simulate on (the recordings are independent), else serial.
    `write=False`: only the plan and the truth (the recordings of an earlier call with the
    same arguments are reused).

    Returns
    -------
    SimulatedFleet
        The plan of the recordings, the true parameters (with wear) and the paths
        written.
    """
    os.makedirs(folder, exist_ok=True)
    rng = np.random.default_rng(seed)
    n_joints = _robot(robot)[0].n_joints
    robots = _robot_plan(rng, n_robots, n_days, wear_fraction, n_joints)
    jobs, rows = [], []
    corrupt_at = set(rng.choice(n_robots * n_days, size=min(n_corrupted, n_robots * n_days), replace=False).tolist())
    kinds = ("nan", "torn", "column")
    corrupted = []
    for r in robots.itertuples():
        for d in range(n_days):
            hour = rng.uniform(0, 24)
            ambient = 28.0 + 6.0 * np.sin(2 * np.pi * (hour - 10.0) / 24) + r.hall_offset
            temps = [float(ambient + rng.normal(0, 0.5) + 2.0 * j) for j in range(n_joints)]
            wear_now = r.wear * min(1.0, (d - r.onset_day + 1) / ramp_days) if r.worn_joint and d >= r.onset_day else 0.0
            name = f"{r.robot_id}_d{d:02d}.npz"
            idx = len(jobs)
            job = {"robot": robot, "seed": int(rng.integers(2**31)), "spread_seed": r.spread_seed,
                   "temperatures": temps, "worn_joint": r.worn_joint, "wear_now": wear_now, "fs": fs,
                   "moves": moves, "path": os.path.join(folder, name), "corrupt": None}
            if idx in corrupt_at:
                job["corrupt"] = kinds[len(corrupted) % len(kinds)]
                corrupted.append(job["path"])
            jobs.append(job)
            ts = START + pd.Timedelta(days=d) + pd.Timedelta(hours=hour)
            rows.append({"robot_id": r.robot_id, "timestamp": ts.strftime("%Y-%m-%dT%H:%M:%SZ"), "path": name,
                         "robot": robot, **{f"temperature{j + 1}": round(t, 2) for j, t in enumerate(temps)}})
    if not write:
        pass
    elif client is not None:
        client.gather(client.map(simulate_recording, jobs, pure=False))
    else:
        for job in jobs:
            simulate_recording(job)
    catalogue = os.path.join(folder, "catalogue.csv")
    pd.DataFrame(rows).to_csv(catalogue, index=False)
    return SimulatedFleet(catalogue=catalogue, robots=robots.drop(columns=["spread_seed", "hall_offset"]),
                          corrupted=corrupted, n_days=n_days)
