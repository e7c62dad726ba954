"""The whole per-joint campaign of Bona & Curatella (2005), section 3, on the simulated COMAU.

`simulate_campaign` records the experiments on the simulated decoupled
COMAU Smart-3 S2 of `dynid.dynamics.comau_decoupled` (true values: the paper's
Tables 1-3), n repetitions each with fresh sensor noise:

* constant-velocity sweeps of +-1.2 rad in the "sweep" set-up (Table 1),
* bang-bang accelerations, velocity +-1 rad/s, "sweep" set-up (Table 2),
* a Fourier excitation, f0 = 0.1 Hz, 5 harmonics, one period after a 1 s
  lead-in, "identification" set-up (Table 3),
* one trapezoidal-velocity run for the validation (section 3.5).

`identify_campaign` runs the three estimators in the paper's order
(gravity -> friction with gravity compensation -> inertia with friction
compensation) and the validation, and returns a `DecoupledIdentification`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.linalg import block_diag

from dynid.analysis.decoupled.estimates import estimate_friction, estimate_gravity, estimate_inertia, identified_model
from dynid.analysis.decoupled.repeated import DEFAULT_CONFIDENCE, RepeatedEstimate
from dynid.analysis.decoupled.validation import DecoupledValidation, validate_decoupled
from dynid.analysis.results import ParameterResults
from dynid.dynamics import comau_decoupled as C
from dynid.dynamics.joint_model import JointPID, JointSimulation, simulate_joints
from dynid.dynamics.joint_trajectories import (
    bang_bang_reference,
    excitation_reference,
    sweep_reference,
    trapezoid_reference,
)
from dynid.provenance import json_safe, versions

__all__ = ["DecoupledCampaign", "DecoupledIdentification", "simulate_campaign", "identify_campaign"]


@dataclass(eq=False, repr=False)
class DecoupledCampaign:
    """Recordings of the simulated campaign (each a `JointSimulation`); `summary()` (also
    `str()`) says what each holds."""

    sweep: JointSimulation
    bang_bang: JointSimulation
    excitation: JointSimulation
    validation: JointSimulation
    controller: JointPID
    truth: dict
    settings: dict = field(default_factory=dict)

    def summary(self) -> str:
        """One line per recording, and the campaign's settings."""
        lines = ["Simulated decoupled campaign (Bona & Curatella 2005, section 3)"]
        for name in ("sweep", "bang_bang", "excitation", "validation"):
            lines.append(f"  {name:<11} {getattr(self, name).describe()}")
        lines.append("  settings: " + ", ".join(f"{k} {v}" for k, v in self.settings.items()))
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        return (f"<DecoupledCampaign {self.excitation.q.shape[2]} joints, "
                f"{self.settings.get('n_repetitions', self.excitation.n_repetitions)} repetitions>")


@dataclass(eq=False, repr=False)
class DecoupledIdentification(ParameterResults):
    """Tables 1-3 (`RepeatedEstimate`) and the validation of section 3.5."""

    gravity: RepeatedEstimate
    friction: RepeatedEstimate
    inertia: RepeatedEstimate
    validation: DecoupledValidation | None = None
    elapsed: float = float("nan")

    method = "per-joint (Bona & Curatella 2005, section 3)"

    @property
    def tables(self):
        return (self.gravity, self.friction, self.inertia)

    # the shared interface over Tables 1-3 together (each table is independent of the others)
    @property
    def names(self):
        return [n for r in self.tables for n in r.names]

    def _estimate(self):
        return np.concatenate([r.mean for r in self.tables])

    @property
    def cov(self):
        return block_diag(*[r.cov for r in self.tables])

    def conf_int(self, alpha: float = 0.05):
        return pd.concat([r.conf_int(alpha) for r in self.tables])

    def to_frame(self):
        return pd.concat([r.to_frame().assign(table=r.table or r.kind) for r in self.tables])

    @property
    def n_inside(self):
        return sum(int(np.sum(r.inside)) for r in self.tables if r.truth is not None)

    @property
    def n_parameters(self):
        return sum(len(r.names) for r in self.tables)

    def summary(self) -> str:
        parts = [r.summary() for r in self.tables]
        if self.validation is not None:
            parts.append(self.validation.summary())
        if all(r.truth is not None for r in self.tables):
            parts.append(f"true values inside the {100 * self.gravity.confidence:g} % intervals: "
                         f"{self.n_inside} of {self.n_parameters}")
        return "\n\n".join(parts)

    def to_dict(self) -> dict:
        gravity, friction, inertia = (r.to_dict() for r in self.tables)
        # the interface's flat list (as every result's "parameters"), each row naming its table
        params = [{**p, "table": r.table or r.kind} for r, d in zip(self.tables, (gravity, friction, inertia))
                  for p in d["parameters"]]
        return json_safe({"method": "per-joint identification (Bona & Curatella 2005, section 3)",
                          "parameters": params, "gravity": gravity, "friction": friction, "inertia": inertia,
                          "validation": None if self.validation is None else self.validation.to_dict(),
                          "elapsed_s": self.elapsed, "versions": versions()})


def simulate_campaign(n_repetitions=25, seed=0, *, torque_noise=None, position_noise=None,
                      rate=C.RATE, substeps=2) -> DecoupledCampaign:
    """Simulate the campaign on the COMAU of `dynid.dynamics.comau_decoupled` (module doc).

    Parameters
    ----------
    n_repetitions : int
        Repetitions of every experiment (the paper's tables average over them).
    seed : int
        Seed of the noise: the same seed gives the same campaign.
    torque_noise : float or (6,) array, optional
        Standard deviation of the measured torque noise per joint, N m (default
        `TORQUE_NOISE` of `dynid.dynamics.comau_decoupled`).
    position_noise : float, optional
        Standard deviation of the encoder noise, rad (default `POSITION_NOISE`, 2e-6).
    rate : float
        Controller and sampling rate, Hz (default 1000, section 3.3).
    substeps : int
        RK4 substeps per controller period of the simulation.

    Returns
    -------
    DecoupledCampaign
        The sweep, bang-bang, excitation and validation recordings of each joint, the
        controller and the true parameters.
    """
    n = C.N_JOINTS
    tn = C.TORQUE_NOISE if torque_noise is None else torque_noise
    pn = C.POSITION_NOISE if position_noise is None else position_noise
    pid = C.controller()
    seeds = np.random.SeedSequence(seed).spawn(4)
    common = dict(repetitions=n_repetitions, q_noise=pn, tau_noise=tn, substeps=substeps)
    sweep_ref = sweep_reference(np.full(n, -1.2), np.full(n, 1.2), fs=rate)
    bb_ref = bang_bang_reference(np.zeros(n), np.ones(n), fs=rate)
    exc = excitation_reference(np.zeros(n), 1.2, 1.0, 1.5,
                               first_moments=[j in C.FIRST_MOMENT_JOINTS for j in range(1, n + 1)])
    t_exc = np.arange(int(round((exc.period + 1.0) * rate)) + 1) / rate
    q_exc = exc.evaluate(t_exc)[0]
    val_ref = trapezoid_reference(np.full(n, -0.8), np.full(n, 0.8), fs=rate)
    sweep = simulate_joints(C.true_model("sweep"), sweep_ref.t, sweep_ref.q, pid, seed=seeds[0], **common)
    bang = simulate_joints(C.true_model("sweep"), bb_ref.t, bb_ref.q, pid, seed=seeds[1], **common)
    excitation = simulate_joints(C.true_model("identification"), t_exc, q_exc, pid, seed=seeds[2], **common)
    validation = simulate_joints(C.true_model("identification"), val_ref.t, val_ref.q, pid,
                                 repetitions=1, q_noise=pn, tau_noise=tn, substeps=substeps, seed=seeds[3])
    return DecoupledCampaign(sweep, bang, excitation, validation, pid, C.true_values(),
                             {"n_repetitions": n_repetitions, "seed": seed, "rate": rate,
                              "excitation_f0": exc.f0, "excitation_harmonics": exc.harmonics})


def identify_campaign(c: DecoupledCampaign, *, confidence=DEFAULT_CONFIDENCE, validate=True,
                      use_truth=True) -> DecoupledIdentification:
    """Tables 1, 2, 3 (in the paper's order, each compensating with the previous means) and the
    validation of section 3.5.

    Parameters
    ----------
    c : DecoupledCampaign
        What `simulate_campaign` returned.
    confidence : float
        Level of the intervals over the repetitions (default 0.999, as the paper's tables).
    validate : bool
        Also simulate the identified model against the validation recordings (section 3.5).
    use_truth : bool
        Attach the true values, for the coverage check of the intervals.

    Returns
    -------
    DecoupledIdentification
        Gravity, friction and inertia estimates over the repetitions (Tables 1-3) and
        the validation.
    """
    t0 = time.perf_counter()
    truth = c.truth if use_truth else None
    n = c.sweep.q.shape[2]
    s = c.sweep
    grav = estimate_gravity(s.t, s.q_meas, s.tau_meas, s.qr, joints=C.GRAVITY_JOINTS,
                            confidence=confidence, truth=truth)
    b = c.bang_bang
    fric = estimate_friction(b.t, b.q_meas, b.tau_meas, b.qr, gravity=grav, confidence=confidence,
                             truth=truth)
    e = c.excitation
    iner = estimate_inertia(e.t, e.q_meas, e.tau_meas, friction=fric,
                            first_moments=C.FIRST_MOMENT_JOINTS, confidence=confidence, truth=truth)
    val = None
    if validate:
        model = identified_model(fric, iner, n, name="identified (Tables 2 and 3 means)")
        v = c.validation
        val = validate_decoupled(model, c.controller, v.t, v.qr, v.q_meas[0], v.tau_meas[0])
    return DecoupledIdentification(grav, fric, iner, val, time.perf_counter() - t0)
