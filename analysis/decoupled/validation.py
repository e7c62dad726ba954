"""Validation of an identified per-joint model by simulation (Bona & Curatella 2005, sec. 3.5, Fig. 8).

The identified model (Table 2 friction, Table 3 inertia and first moments) is
simulated in closed loop under the robot's controller on the reference the
robot followed (trapezoidal velocity moves), and compared with the
measurements: position error `q_meas - q_sim` and torque error
`tau_meas - tau_sim`. As in the paper the measurements are first filtered by
an 8th-order Chebyshev (type I, 0.5 dB ripple, unit gain at DC) low-pass,
here zero-phase at `fc` (default 80 Hz, the cut-off of section 3.4). The error PDFs are
compared with a Gaussian by `dynid.analysis.statistics.noise.noise_pdf_tests`, on the
error resampled at `test_rate` (200 Hz, section 3.4) so that neighbouring
samples of the filtered error are not counted as independent.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import signal

from dynid.analysis.results import Result, percent
from dynid.analysis.statistics.noise import NoiseTests, noise_pdf_tests
from dynid.dynamics.joint_model import JointModel, JointPID, simulate_joints
from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["DecoupledValidation", "validate_decoupled"]


@dataclass(eq=False, repr=False)
class DecoupledValidation(Result):
    """Errors between the measured run and the simulated identified model; arrays (N, n)."""

    t: np.ndarray
    qr: np.ndarray
    q_meas: np.ndarray
    q_sim: np.ndarray
    tau_meas: np.ndarray
    tau_sim: np.ndarray
    q_tests: NoiseTests
    tau_tests: NoiseTests
    settings: dict = field(default_factory=dict)

    @property
    def q_error(self):
        return self.q_meas - self.q_sim

    @property
    def tau_error(self):
        return self.tau_meas - self.tau_sim

    @property
    def max_q_error(self):
        """Largest |q_meas - q_sim| per joint, rad (SI; `_deg`: the paper's unit)."""
        return np.abs(self.q_error).max(axis=0)

    @property
    def rms_q_error(self):
        """RMS of q_meas - q_sim per joint, rad."""
        return np.sqrt(np.mean(self.q_error ** 2, axis=0))

    @property
    def max_q_error_deg(self):
        return np.degrees(self.max_q_error)

    @property
    def max_tau_error(self):
        return np.abs(self.tau_error).max(axis=0)

    @property
    def rms_q_error_deg(self):
        return np.degrees(self.rms_q_error)

    @property
    def rms_tau_error(self):
        return np.sqrt(np.mean(self.tau_error ** 2, axis=0))

    @property
    def rel_tau_error(self):
        """‖τ_meas − τ_sim‖ / ‖τ_meas‖ per joint."""
        return np.linalg.norm(self.tau_error, axis=0) / np.linalg.norm(self.tau_meas, axis=0)

    def to_frame(self) -> pd.DataFrame:
        """One row per joint: the errors of `summary` (rad and the paper's degrees, N m, relative).

        Returns
        -------
        pandas.DataFrame
            Index `joint` = 1..n; the unit in each column's name.
        """
        return pd.DataFrame({"max_q_error [rad]": self.max_q_error, "rms_q_error [rad]": self.rms_q_error,
                             "max_q_error [deg]": self.max_q_error_deg, "rms_q_error [deg]": self.rms_q_error_deg,
                             "max_tau_error [N m]": self.max_tau_error, "rms_tau_error [N m]": self.rms_tau_error,
                             "rel_tau_error": self.rel_tau_error},
                            index=pd.Index(range(1, self.q_meas.shape[1] + 1), name="joint"))

    def summary(self) -> str:
        lines = ["Model validation by simulation (section 3.5): measured (filtered) minus simulated",
                 "  joint  max|e_q| [deg]  rms e_q [deg]  max|e_tau| [N m]  rms e_tau [N m]  "
                 "rel. e_tau  q Gaussian  tau Gaussian"]
        gq, gt = self.q_tests.gaussian, self.tau_tests.gaussian
        for j in range(self.q_meas.shape[1]):
            lines.append(f"  {j + 1:5d} {self.max_q_error_deg[j]:15.4g} {self.rms_q_error_deg[j]:14.4g} "
                         f"{self.max_tau_error[j]:17.4g} {self.rms_tau_error[j]:16.4g} "
                         f"{percent(self.rel_tau_error[j]):>11}  {'yes' if gq[j] else 'no':>10}  "
                         f"{'yes' if gt[j] else 'no':>12}")
        return "\n".join(lines)

    def to_dict(self) -> dict:

        return json_safe({"settings": self.settings,
                          "max_q_error": self.max_q_error, "rms_q_error": self.rms_q_error,
                          "max_q_error_deg": self.max_q_error_deg, "rms_q_error_deg": self.rms_q_error_deg,
                          "max_tau_error": self.max_tau_error, "rms_tau_error": self.rms_tau_error,
                          "rel_tau_error": self.rel_tau_error,
                          "q_error_tests": self.q_tests.to_dict(),
                          "tau_error_tests": self.tau_tests.to_dict()})


def _chebyshev(x, fs, fc, order=8, ripple_db=0.5):
    if not 0 < fc < 0.5 * fs:
        raise InputError(f"the filter cut-off fc = {fc!r} Hz must be in (0, fs/2 = {0.5 * fs:g})")
    sos = signal.cheby1(order, ripple_db, fc, fs=fs, output="sos")
    # An even-order Chebyshev I sits at -ripple dB at DC; unnormalised it would scale a
    # position by 0.89 (both passes) and show as a model error.
    _, h0 = signal.sosfreqz(sos, worN=[0.0], fs=fs)
    sos[0, :3] /= abs(h0[0])
    return signal.sosfiltfilt(sos, x, axis=0)


def validate_decoupled(model: JointModel, controller: JointPID, t, qr, q_meas, tau_meas, *,
                       fc=80.0, test_rate=200.0, substeps=2, alpha=0.05) -> DecoupledValidation:
    """Simulate `model` under `controller` on `qr` (N, n) and compare with one measured run
    `q_meas`, `tau_meas` (N, n) at times `t` (module doc)."""
    t = np.asarray(t, dtype=float)
    qr, q_meas, tau_meas = (np.asarray(x, dtype=float) for x in (qr, q_meas, tau_meas))
    n = model.n_joints
    if q_meas.ndim == 3:
        if q_meas.shape[0] != 1:
            raise InputError("validate_decoupled compares ONE measured run; pass q_meas[k], tau_meas[k]")
        q_meas, tau_meas = q_meas[0], tau_meas[0]
    if qr.shape != (t.size, n) or q_meas.shape != qr.shape or tau_meas.shape != qr.shape:
        raise InputError(f"t (N,), qr, q_meas and tau_meas (N, {n}) expected; got {t.shape}, "
                         f"{qr.shape}, {q_meas.shape}, {tau_meas.shape}")
    fs = 1.0 / float(np.mean(np.diff(t)))
    sim = simulate_joints(model, t, qr, controller, q0=q_meas[0], substeps=substeps)
    qf = _chebyshev(q_meas, fs, fc)
    tf = _chebyshev(tau_meas, fs, fc)
    step = max(1, int(round(fs / test_rate)))
    names = [f"j{j + 1}" for j in range(n)]
    eq, et = (qf - sim.q[0])[::step], (tf - sim.tau[0])[::step]
    q_tests = noise_pdf_tests(eq, alpha, names=names, label="position error", unit="rad")
    tau_tests = noise_pdf_tests(et, alpha, names=names, label="torque error", unit="N m")
    return DecoupledValidation(t=t, qr=qr, q_meas=qf, q_sim=sim.q[0], tau_meas=tf, tau_sim=sim.tau[0],
                               q_tests=q_tests, tau_tests=tau_tests,
                               settings={"fc": fc, "filter": "Chebyshev I, order 8, 0.5 dB, zero phase",
                                         "test_rate": fs / step, "alpha": alpha, "model": model.name})
