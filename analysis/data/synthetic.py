"""Synthetic recordings: a robot simulated in closed loop, with sensor noise.

Used by the demo, the examples and the estimator tests (never to test the
simulator itself, which is checked against Pinocchio).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from dynid.analysis.data.experiment import Experiment
from dynid.analysis.results import Result
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.loop_stability import radius_along
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.simulation import STIFFNESS_WARNING, friction_stiffness, simulate_closed_loop
from dynid.dynamics.trajectories import MAX_HARMONICS, random_fourier_trajectory
from dynid.dynamics.urdf import inertia_about_origin, inertial_parameters
from dynid.errors import DynidError, InputError
from dynid.outputs import atomic_write_text
from dynid.provenance import json_safe
from dynid.ranges import check_range

# Values of the simulated TX40 outside Table 2. Ia6 is FIGAROH's a-priori rotor
# inertia of joint 6 (config/TX40_config.yaml): without it M66 = 0 and M(q) is
# singular. Every other base parameter outside Table 2 is zero.
TX40_EXTRA = {"Ia6": 0.0105}

#: most samples one simulation may produce (duration x rate): beyond that the
#: arrays alone take gigabytes and the run lasts hours
MAX_SAMPLES = 50_000_000
#: fewest samples of a simulated recording
MIN_SAMPLES = 10


def sample_count(duration, fs, *, option="--duration", what="the controller rate") -> int:
    """Samples of `duration` s at `fs` Hz, refused (InputError naming `option`) if unbounded.

    `fs` is `what` (the controller rate of the robot file by default).
    """
    import math

    if not (isinstance(duration, (int, float, np.floating, np.integer)) and math.isfinite(duration)
            and duration > 0):
        raise InputError(f"the duration must be a positive, finite number of seconds, got {duration!r} "
                         f"({option})")
    if not (math.isfinite(fs) and fs > 0):
        raise InputError(f"{what} must be a positive, finite number of Hz, got {fs!r}")
    n = duration * fs
    if n > MAX_SAMPLES:
        raise InputError(f"{duration:g} s at {what} of {fs:g} Hz would be {n:.3g} samples, at least "
                         f"{_bytes(n * 8 * 10)} of memory; at most {MAX_SAMPLES:.3g} samples "
                         f"({MAX_SAMPLES / fs:.4g} s) are simulated: lower {option}")
    n = int(round(n))
    if n < MIN_SAMPLES:
        raise InputError(f"{duration:g} s at {what} of {fs:g} Hz is only {n} samples; at least "
                         f"{MIN_SAMPLES} are needed: raise {option} to {MIN_SAMPLES / fs:.3g} s or more")
    return n


def _bytes(n) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n / 1e3:.3g} kB"


#: the largest noise standard deviation a simulated recording may have (its cells stay far
#: below dynid.analysis.data.plausibility.MAGNITUDE_LIMIT)
MAX_NOISE = 1e6


def check_noise(value, option) -> None:
    """A noise standard deviation (scalar or per joint): finite, non-negative, and small enough
    that the recording it makes can be read back (dynid refuses cells beyond MAGNITUDE_LIMIT)."""
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise InputError(f"the noise standard deviation must be finite and non-negative (0 for none), "
                         f"got {value!r} ({option})")
    if np.any(arr > MAX_NOISE):
        raise InputError(f"the noise standard deviation {float(arr.max()):g} ({option}) is out of range: at most "
                         f"{MAX_NOISE:g}, or the recording would hold values dynid refuses to read")


def tx40_true_parameters(robot, bp):
    """Base and standard parameters of the simulated TX40 (Table 2 + TX40_EXTRA).

    Returns (beta, chi_st): the 60 base values and one standard set with the
    same dynamics (regrouped parameters set to zero).
    """
    values = dict(robot.apriori)
    values.update(TX40_EXTRA)
    beta = np.array([values.get(n, 0.0) for n in bp.names])
    return beta, bp.to_standard(beta)


def apriori_parameters(robot, bp):
    """Standard parameters from the robot file's a-priori values (standard or base names).

    Base values (`ZZ1R`...) become a standard set through `bp.to_standard`;
    standard values (`ZZ1`...) are taken as they are. Missing ones are zero.
    """
    values = dict(robot.apriori)
    if robot.name == "tx40":
        values.update(TX40_EXTRA)
    std = {k: v for k, v in values.items() if k in robot.standard_names}
    base = {k: v for k, v in values.items() if k in bp.names and k not in std}
    if not values:
        raise InputError(f"robot '{robot.name}' ({robot.source}) has no a-priori parameter values to "
                         f"simulate with; add an [apriori] table to its TOML file")
    chi = robot.standard_vector(std)
    if base:
        beta = bp.from_standard(chi)
        for k, name in enumerate(bp.names):
            if name in base:
                beta[k] = base[name]
        chi = bp.to_standard(beta)
    return chi


def experiment_from_simulation(sim, name: str = "simulation") -> Experiment:
    """An `Experiment` of a simulation's q, qr, qd, qdd, tau (noise-free, as simulated)."""
    fs = None if sim.rate is None else float(sim.rate)
    return Experiment(t=sim.t.copy(), q=sim.q.copy(),
                      qr=None if sim.qr is None else sim.qr.copy(),
                      qd=sim.qd.copy(), qdd=sim.qdd.copy(), tau=sim.tau.copy(), fs=fs,
                      source=f"dynid simulation of '{sim.robot}' ({sim.kind})",
                      notices=list(sim.notes), name=name)


#: RK4 substeps per controller period of the simulated recordings (more where the friction is stiff)
SUBSTEPS = 4


def simulate_experiment(robot, chi_st, trajectory, duration, *, rng, tau_noise, q_noise,
                        fs=None, name="simulated", v_s=0.01, substeps=None, feedforward=True,
                        progress=None, fast=False):
    """Closed-loop run of `trajectory` for `duration` s, as a noisy Experiment.

    The controller of the robot description (with velocity feedforward by
    default, as industrial controllers have) runs at its rate (the sampling
    rate `fs` by default); measured q and tau get white Gaussian noise of standard
    deviation `q_noise` (rad) and `tau_noise` (N m), scalars or per joint.
    `progress(fraction)` is passed to the simulation. `fast`: the simulation's
    `crba=True, adaptive=True` (the `substeps` only near velocity reversals, where the
    smoothed friction is stiff); on the demo's TX40 that is a third of the CPU, and the
    states differ from the uniform steps' at the RK4 error level (1.5e-10 rad, against
    the demo's position noise of 4e-5 rad). The noise draws do not depend on it.
    `substeps` None: `SUBSTEPS`, or more where the smoothed friction makes the plant stiff
    for that RK4 step (h*lambda above the simulator's warning, e.g. the LWR4+ with its controller at 200 Hz):
    as many as bring it to 1.5.
    """
    fs = float(robot.controller.rate if fs is None else fs)
    check_noise(q_noise, "--noise-q")
    check_noise(tau_noise, "--noise-tau")
    t = np.arange(sample_count(duration, fs, what="the controller rate" if fs == getattr(
        robot.controller, "rate", None) else "the sampling rate")) / fs
    qr, qdr, _ = trajectory.evaluate(t)
    if substeps is None:
        substeps = SUBSTEPS
        x = friction_stiffness(robot, chi_st, qr[0], 1.0 / (fs * substeps), v_s)
        if math.isfinite(x) and x > STIFFNESS_WARNING:
            substeps = int(math.ceil(substeps * x / 1.5))
    # v_s and substeps: Coulomb friction smoothed over 0.01 rad/s, well inside the
    # identification's dead zone, and an RK4 step small enough for that stiffness.
    sim = simulate_closed_loop(robot, chi_st, t, qr, qdr, q0=qr[0], qd0=qdr[0], v_s=v_s,
                               substeps=substeps, feedforward=feedforward, progress=progress,
                               crba=fast, adaptive=fast)
    n = robot.n_joints
    q_noise = np.broadcast_to(np.asarray(q_noise, dtype=float), (n,))
    tau_noise = np.broadcast_to(np.asarray(tau_noise, dtype=float), (n,))
    q = sim.q + rng.normal(size=sim.q.shape) * q_noise
    # The controller holds tau_k over [t_k, t_k+1). The recorded torque is that
    # of an integrating sensor centred on t_k, (tau_k-1 + tau_k) / 2: the torque
    # the central-difference acceleration at t_k responds to. Recording the held
    # value instead puts a half-sample lag between Y and W that biases the wrist
    # inertias by ~0.7 % (Ia5 of the TX40), an artefact of the simulation.
    tau_sensor = sim.tau.copy()
    tau_sensor[1:] = 0.5 * (sim.tau[1:] + sim.tau[:-1])
    tau = tau_sensor + rng.normal(size=sim.tau.shape) * tau_noise
    notices = [f"simulated: closed loop at {fs:g} Hz, white noise of standard deviation "
               f"q [{', '.join(f'{v:.3g}' for v in q_noise)}] rad, "
               f"tau [{', '.join(f'{v:.3g}' for v in tau_noise)}] N m"]
    return Experiment(t=t, q=q, qr=qr, tau=tau, fs=fs, source=name, name=name, notices=notices,
                      meta={"true_q": sim.q, "true_tau": tau_sensor, "torque_timing": "centred"})


#: what `simulate` says of its torque, which DIDIM must be told when it reads the file back
TORQUE_TIMING_NOTICE = ("the torques are an integrating sensor's, centred on the samples ((tau_k-1 + tau_k) / 2); "
                        "DIDIM on the file written from it needs --torque-timing centred (torque_timing="
                        "'centred'); the recording in Python (dynid.simulate(...).experiment) says so by itself")


def missing_effects(robot) -> list:
    """What a simulation of `robot`'s a-priori values leaves out, in words (empty when nothing):
    the joints without friction (no nonzero Fv/Fc value) and a robot without rotor inertia (no
    nonzero Ia): a robot made from a URDF has neither until its TOML adds them (docs/guide.md)."""
    values = dict(robot.apriori)
    if robot.name == "tx40":
        values.update(TX40_EXTRA)
    nonzero = {k for k, v in values.items() if v}
    n = robot.n_joints
    no_friction = [j for j in range(1, n + 1) if not any(re.fullmatch(rf"(Fv|Fc){j}R?", k) for k in nonzero)]
    out = []
    if no_friction:
        which = "any joint" if len(no_friction) == n else "joint" + ("s " if len(no_friction) > 1 else " ") \
            + ", ".join(map(str, no_friction))
        out.append(f"simulated without friction on {which}: the robot file gives no Fv or Fc value "
                   f"(add them to its [apriori] table)")
    if not any(re.fullmatch(r"Ia\d+R?", k) for k in nonzero):
        out.append("simulated without rotor inertia: the robot file gives no Ia value (add them to its "
                   "[apriori] table)")
    return out


@dataclass(eq=False, repr=False)
class SimulatedRecording(Result):
    """A simulated recording (`experiment`) with what produced it.

    `to_csv(path)` writes the recording in dynid's column format (what `dynid simulate
    --out` writes, read back by `load_experiment`); `to_json(path)` the settings, the
    reference and the true parameters (`to_dict`).
    """

    experiment: Experiment
    robot: object
    trajectory: object
    chi: np.ndarray                 # the standard parameters simulated
    seed: int
    duration: float
    noise_q: float
    noise_tau: float
    #: what the simulation leaves out (friction, rotor inertia), in words
    notices: list = field(default_factory=list)
    #: the payload carried by the last link (`add_payload`), or None
    payload: dict | None = None

    def summary(self) -> str:
        """What was simulated: robot, duration, rate, noise and the reference, as text.

        Returns
        -------
        str
        """
        e, tr = self.experiment, self.trajectory
        lines = [f"Simulated {self.robot.name} ({self.robot.n_joints} joints): {self.duration:g} s at "
                 f"{e.fs:g} Hz ({e.n_samples} samples), seed {self.seed}",
                 f"  reference: random Fourier series, f0 = {tr.f0:g} Hz, {tr.harmonics} harmonics",
                 f"  noise: q {self.noise_q:g} rad, tau {self.noise_tau:g} N m (white, standard deviations)",
                 "  true parameters: the robot file's a-priori values (to_dict()['true_parameters'])"]
        if self.payload is not None:
            pl = self.payload
            lines.append(f"  payload on link {pl['link']}: {pl['mass']:g} kg, centre of mass "
                         f"({', '.join(f'{c:g}' for c in pl['com'])}) m in the link frame, a sphere of radius "
                         f"{pl['radius']:g} m (its parameters: to_dict()['payload'])")
        lines += [f"  notice: {n}" for n in self.notices]
        return "\n".join(lines)

    def to_frame(self):
        """The recording as `dynid simulate --out` writes it: t, q1.., qr1.., tau1..

        Returns
        -------
        pandas.DataFrame
        """
        return self.experiment.to_frame()

    def to_csv(self, path=None) -> str:
        """The recording in dynid's column format (`dynid simulate --out`), written atomically
        to `path` when given.

        Returns
        -------
        str
            The CSV text.
        """
        text = self.to_frame().to_csv(index=False, float_format="%.10g", lineterminator="\n")
        if path is not None:
            atomic_write_text(path, text)
        return text

    def to_dict(self) -> dict:
        """Settings, reference coefficients and true parameters (JSON-safe).

        Returns
        -------
        dict
            JSON-safe.
        """
        bp = base_parameters(self.robot)
        extra = (" (with " + ", ".join(f"{k} = {v:g}" for k, v in TX40_EXTRA.items())
                 + " added: the coupled wrist needs a rotor-6 inertia)") if self.robot.name == "tx40" else ""
        tr = self.trajectory
        return json_safe({
            "robot": self.robot.name, "seed": self.seed, "duration": self.duration, "fs": self.experiment.fs,
            "noise": {"q_std": self.noise_q, "tau_std": self.noise_tau}, "notices": list(self.notices),
            "reference": {"f0": tr.f0, "harmonics": tr.harmonics, "a": tr.a, "b": tr.b, "q0": tr.q0},
            "payload": self.payload,
            "true_parameters": {"source": "the robot file's a-priori values" + extra
                                + (", with the payload" if self.payload is not None else ""),
                                "base": dict(zip(bp.names, bp.from_standard(self.chi))),
                                "standard": dict(zip(self.robot.standard_names, self.chi))}})


def simulate(robot, duration: float = 20.0, *, seed: int = 1, f0: float = 0.1, harmonics: int = 10,
             noise_q: float = 4e-5, noise_tau: float = 0.5, payload=None, progress=None) -> SimulatedRecording:
    """Simulate `robot` (its a-priori parameters) tracking a random Fourier reference.

    The reference is a random feasible finite Fourier series (fundamental `f0` Hz,
    `harmonics` harmonics, Bona & Curatella eqs. (17)-(19)); the robot runs
    under the controller of its robot file; q and tau get white Gaussian noise of
    standard deviation `noise_q` (rad) and `noise_tau` (N m). `payload`: a mass (kg), or
    (mass, (x, y, z)) with its centre of mass in the last link's frame (m), carried by the
    last link (`add_payload`): a recording to try `dynid payload` on.

    Parameters
    ----------
    robot : Robot, str or path
        A Robot, a bundled name (`"tx40"`) or a robot file path; it needs a
        `[controller]` and a-priori parameter values.
    duration : float
        Length of the recording, s, sampled at the controller's rate.
    seed : int
        Seed of the reference and of the noise: the same seed gives the same recording.
    f0 : float
        Fundamental frequency of the reference, Hz.
    harmonics : int
        Number of harmonics of the reference (`f0 * harmonics` at most a tenth of the
        controller's rate).
    noise_q : float
        Standard deviation of the position noise, rad (0 for none).
    noise_tau : float
        Standard deviation of the torque noise, N m (0 for none).
    payload : float or (float, (float, float, float)), optional
        The payload's mass, kg, or its mass and centre of mass in the last link's frame,
        m. Default None: no payload.
    progress : callable, optional
        Called with the fraction of the simulation done (0 to 1). Default None: silent.

    Returns
    -------
    SimulatedRecording
        The recording (`experiment`) with the trajectory, the simulated parameters and
        the noise levels that produced it.
    """
    robot = load_robot(robot)   # a Robot passes through
    if robot.controller is None:
        raise InputError(f"robot '{robot.name}' ({robot.source}) has no [controller]; add one to simulate")
    seed = check_range("seed", seed)
    duration = check_range("duration", duration)
    for name, value in (("f0", f0), ("harmonics", harmonics)):
        if isinstance(value, (str, bytes)) or not isinstance(value, (int, float, np.number)):
            raise InputError(f"{name} must be a number, got {value!r} (--{name})")
    if not (duration > 0 and f0 > 0 and harmonics >= 1):
        raise InputError("duration and f0 must be positive and harmonics at least 1 "
                         "(--duration, --f0, --harmonics)")
    if not np.isfinite(f0):
        raise InputError(f"f0 must be a finite frequency in Hz, got {f0!r} (--f0)")
    if harmonics > MAX_HARMONICS:
        raise InputError(f"harmonics = {harmonics} is more than {MAX_HARMONICS}, the most a reference "
                         f"trajectory uses (--harmonics)")
    check_noise(noise_q, "--noise-q")
    check_noise(noise_tau, "--noise-tau")
    rate = float(robot.controller.rate)
    if rate < 10 * f0 * harmonics:
        # fewer samples per period of the highest harmonic alias the reference (to DC at the rate)
        raise InputError(f"f0 x harmonics = {f0 * harmonics:g} Hz is too high for the controller rate of robot "
                         f"'{robot.name}' ({rate:g} Hz): a reference needs at least 10 samples per period of its "
                         f"highest harmonic; lower --f0 or --harmonics (at most {rate / 10:g} Hz together)")
    sample_count(duration, rate, what=f"the controller rate of robot '{robot.name}'")
    chi = apriori_parameters(robot, base_parameters(robot))
    payload_doc = None
    if payload is not None:
        chi, payload_doc = add_payload(robot, chi, payload)
    rng = np.random.default_rng(seed)
    traj = random_fourier_trajectory(robot, f0, harmonics, rng)
    # before the simulation: an unstable loop may make it fail, and then the reason is this
    unstable = _stability_notice(robot, chi, traj.evaluate(np.arange(sample_count(duration, rate)) / rate)[0])
    try:
        exp = simulate_experiment(robot, chi, traj, duration, rng=rng, q_noise=noise_q, tau_noise=noise_tau,
                                  progress=progress, name=f"simulated {robot.name} (seed {seed})")
    except DynidError as err:
        if unstable:
            raise InputError(f"the closed-loop simulation diverged: {unstable[0]} (it stopped with: {err})") from err
        raise
    # an unstable loop tracks poorly too, and for that reason rather than soft gains
    notices = (missing_effects(robot) + [TORQUE_TIMING_NOTICE] + unstable
               + ([] if unstable else _tracking_notice(exp, robot)))
    exp.notices = list(exp.notices or []) + notices
    return SimulatedRecording(experiment=exp, robot=robot, trajectory=traj, chi=chi, seed=seed,
                              duration=duration, noise_q=noise_q, noise_tau=noise_tau, notices=notices,
                              payload=payload_doc)


#: a simulated joint whose tracking error (RMS of qr - q) exceeds this fraction of its reference's
#: span tracks poorly: the recording describes the robot file's loop more than the reference
POOR_TRACKING = 0.10


def _stability_notice(robot, chi, qr) -> list:
    """A notice when the robot file's sampled controller is unstable somewhere along the
    reference (`dynid.dynamics.loop_stability`): the recording then holds a limit cycle at up
    to half the rate, which no rigid-body model describes."""
    rows, radius = radius_along(robot, chi, qr)
    worst = int(np.argmax(radius))
    if radius[worst] <= 1.0:
        return []
    share = float(np.mean(radius > 1.0))
    source = getattr(robot, "source", "") or ""
    return [(f"the robot file's [controller]{f' ({source})' if source else ''} is unstable at "
             f"{robot.controller.rate:g} Hz on this robot along "
             f"{100 * share:.0f} % of the reference (sampled loop linearised at its configurations: spectral "
             f"radius up to {radius[worst]:.3g}, at t = {rows[worst] / robot.controller.rate:.3g} s, above 1): "
             "the simulated motion oscillates at up to half the rate, torque that no rigid-body model "
             "describes and the identification will leave in its residual; raise [controller].rate or "
             "lower wn or J_ap of the joints whose inertia the a-priori model makes small")]


def _tracking_notice(exp, robot) -> list:
    """A notice when the simulated loop follows its reference poorly (the robot file's gains)."""
    if exp.qr is None:
        return []
    span = np.ptp(exp.qr, axis=0)
    rms = np.sqrt(np.mean((exp.qr - exp.q) ** 2, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(span > 0, rms / span, 0.0)
    poor = np.flatnonzero(share > POOR_TRACKING)
    if poor.size == 0:
        return []
    return [("the simulated loop tracks its reference poorly: RMS of qr - q "
             + ", ".join(f"j{j + 1} {rms[j]:.3g} {'m' if getattr(robot.joints[j], 'prismatic', False) else 'rad'} "
                         f"({100 * share[j]:.0f} % of its span)" for j in poor)
             + f", above {100 * POOR_TRACKING:.0f} %: the robot file's [controller] gains (and no model of "
             "gravity in the loop) are too soft for this reference; the recording is still a valid one to "
             "identify from, but not what a well-tuned robot would log")]


#: the simulated payload is a uniform sphere of this radius (m) about its centre of mass
PAYLOAD_RADIUS = 0.05
#: the heaviest simulated payload (kg) and its farthest centre of mass (m) from the link frame
MAX_PAYLOAD_KG = 1000.0
MAX_PAYLOAD_COM = 2.0


def add_payload(robot, chi_st, payload):
    """`chi_st` with a payload on the last link: a uniform sphere (radius `PAYLOAD_RADIUS`) of mass m
    centred at c in that link's frame. Its ten inertial parameters about the link frame's origin are
    added to the link's (the dynamics are linear in them): first moments m c, inertia matrix
    I_c + m (|c|² 1 - c cᵀ) (XY = -m cx cy, as the robot's inertia matrix).

    Returns
    -------
    (ndarray, dict)
        The standard parameters with the payload, and the payload's description (`link`, `mass`,
        `com`, `radius`, `parameters`: name -> value added, `XXL ... ML` about the link frame).
    """
    if isinstance(payload, (int, float, np.number)) and not isinstance(payload, bool):
        mass, com = float(payload), (0.0, 0.0, 0.0)
    else:
        try:
            mass, com = payload
            mass = float(mass)
            com = tuple(float(c) for c in com)
        except (TypeError, ValueError):
            raise InputError(f"payload must be a mass in kg or (mass, (x, y, z)) with the centre of mass in "
                             f"the last link's frame (m), got {payload!r} (--payload MASS or MASS,X,Y,Z)") from None
    if len(com) != 3 or not all(np.isfinite(com)) or not np.isfinite(mass):
        raise InputError(f"payload: give a finite mass and three finite coordinates, got {payload!r} (--payload)")
    if not 0 < mass <= MAX_PAYLOAD_KG:
        raise InputError(f"payload mass {mass:g} kg: give a mass above 0 and at most {MAX_PAYLOAD_KG:g} kg "
                         f"(--payload)")
    c = np.asarray(com)
    if np.linalg.norm(c) > MAX_PAYLOAD_COM:
        raise InputError(f"payload centre of mass {np.linalg.norm(c):.3g} m from the link frame: more than "
                         f"{MAX_PAYLOAD_COM:g} m; check the coordinates and their unit (m) (--payload)")
    n = robot.n_joints
    I_o = inertia_about_origin(mass, c, 0.4 * mass * PAYLOAD_RADIUS ** 2 * np.eye(3))
    added = inertial_parameters(n, mass, c, I_o)
    chi = np.array(chi_st, dtype=float, copy=True)
    index = {name: k for k, name in enumerate(robot.standard_names)}
    for name, value in added.items():
        chi[index[name]] += value
    doc = {"link": n, "mass": mass, "com": list(c), "radius": PAYLOAD_RADIUS,
           "parameters": {name.rstrip("0123456789") + "L": float(v) for name, v in added.items()}}
    return chi, doc
