"""DIDIM: identification from the joint torques and the reference only (section 3).

Gautier, Janot, Vandanjon (2010), *Dynamic identification of a 6 dof
industrial robot without joint position data*, section 3. DIDIM is a
closed-loop output-error method: the robot is simulated in closed loop under
the same control law and with the same reference as the actual robot, and the
parameters minimise `||Y(tau) - Y_s(tau_ddm)||`. The Gauss-Newton step is
an IDIM least-squares problem (eqs. (18)-(24)) whose regressor is built from
the *simulated* states::

    iteration k = 1, 2, ...  (chi^{k-1} known; chi^0 from eq. (31))
      1. simulate the closed loop with chi^{k-1} (base -> standard, regrouped
         parameters set to zero), tracking the recorded reference qr from the
         reference's initial state, derivative gains times J^{k-1} / J_ap
         (section 3.2, eq. (27));
      2. W_k = IDM(q_ddm, qd_ddm, qdd_ddm) from the simulated states (exact
         derivatives: no position filter), decimated in parallel with the
         measured tau (eq. (24));
      3. per-joint WLS: chi^k and rho_k = Y - W_k chi^k;
      4. stop when |(||rho_k|| - ||rho_{k-1}||)| / ||rho_{k-1}|| <= tol_I.

So `k` counts least-squares solves ("steps"). The paper's TX40 needs 1 step
for the optimum and a second one to see that the residual no longer changes
(Table 2 is "after 2 steps"). The result reports the estimate of the last
step, with the statistics of its WLS (eqs. (13)-(16)); optionally the
essential parameters (Pham & Gautier) by the same backward elimination as
IDIM, on the last step's W.

Documented choices (all in `DIDIMResult.settings`, all overridable through
`settings=`):

* **Initialisation** (eqs. (31)-(32)): chi^0 = 0 except `Ia_j = 1`. A motor
  `m` coupled with joints `k != m` with coefficients `c` (rotor speed
  `sum c_k qd_k`) adds `Ia_m c_k c_l / c_m^2` off the diagonal of M; dynid
  absorbs its diagonal share `(c_k / c_m)^2 Ia_m` into `Ia_k`. So joint
  `k` gets `Ia_k = 1 + (c_k / c_m)^2`: the rotor of `k` keeps a unit
  inertia of its own and the coupled rotor adds the positive semi-definite
  `c c^T / c_m^2`, so `M(q, chi^0) = I + c c^T / c_m^2` (restricted to the
  coupled joints) is positive definite. With `Ia_k = 1` instead the TX40
  wrist block would be `[[1, 1], [1, 1]]`, singular. For the TX40
  (`c = (1, 1)`, motor 6) this gives the paper's `Ia5 = 2` and the wrist
  block `[[2, 1], [1, 1]]` (eigenvalues 0.38 and 2.62); all other joints see
  `M = I`. (The per-joint gain update sees only the diagonal, 2 and 1, so the
  two wrist modes of the first simulation run at 0.59 and 3.4 times the
  designed loop gain: fine at 5 kHz, unstable at 1 kHz with wn = 400 rad/s.)
* **Gain update** (section 3.2, `update_gains`): before simulating with
  chi^{k-1}, `kd_scale_j = J_j / J_ap_j` with `J_j = max_q M_jj(q,
  chi^{k-1})` (eq. (27): dynid's M already contains `ZZ_j + Ia_j`, so J_j is
  the largest diagonal inertia), the maximum taken over the configurations of
  the previous simulation (of the reference `qr` for the first one), sampled
  every `1 / j_rate` s (1 ms). `True` (the paper, default): at every step.
  `False`: never (`kd_scale = 1`, the controller as described).
  `"initial"`: only for the simulation of chi^0.

  What the update does: the simulated loop becomes the *designed* one
  (`wn`, `zeta` of the normalised double integrator) whatever chi^k is;
  that equals the actual loop when the actual controller's a-priori J_ap is
  right (J_ap = max_q M_jj of the real robot). Measured on Pinocchio data of
  the TX40 (tests/analysis/estimators/test_didim.py): with the actual loop as designed, the update
  makes DIDIM independent of a wrong J_ap in the robot file (J_ap x 2 gives
  the same estimate to 1e-6; without the update Ia6 comes out 6 % low, Ia5
  1.5 % low). When instead the *actual* controller runs with
  a wrong J_ap, the update makes the simulated loop differ from the actual one
  at every step and biases the estimate (Ia6 +20 % on the TX40 at wn = 200
  rad/s); `"initial"` or `False` are then exact, since at convergence the
  simulated robot with the actual gains is the actual robot. With a soft loop
  (wn = 60 rad/s, the assumed gains of `tx40.toml`) the update also slows the
  iteration down (it makes the simulated tracking error depend on the ratio
  of the estimated friction to the estimated inertia).
* **Step safeguard**: an estimate whose `M(q)` is not positive definite at
  the previous simulation's configurations, or whose simulation fails, is
  moved back towards the last simulated estimate by halving its step (at most
  `max_step_halvings` times; history column `step_length`). The paper's
  iteration would stop there; a damped step is simulated instead, and
  convergence is only declared after a full step. PC-DIDIM (`physical=True`)
  also halves a step that raises the output error ||tau - tau_sim|| above the
  last simulated estimate's by more than tol_I (a projected Gauss-Newton step needs that descent
  test; the halved steps stay physical, the set being convex); the smallest
  step is taken untested. Plain DIDIM keeps it opt-in (`descent_test`): measured on the
  independent plant (benchmarks/results/didim_nonconvergence_seed3005.txt), the runs that did not
  converge simulated the robot file's gains where the actual loop had others: the iteration
  wanders at the 1 % level around no fixed point, and the descent test only shrinks the steps
  (the criterion, met by full steps only, is then never met). With the gains identified from the
  data and the robot file's a-priori start, 20 of 20 held-out seeds converged in 4-5 steps
  (benchmarks/didim_gains.py).
* **A simulated motion that cannot identify every parameter** (W(q_s) rank-deficient, e.g.
  eq. (31)'s unit inertias under stiff actual gains): at the first step an IdentificationError
  naming the start; later, the iteration stops (`converged` False) with that reason.
* **Initial state and transient**: the simulation starts at `(qr(0),
  qdr(0))`; the first `transient` seconds (default `5 / min(wn)`, the
  text after eq. (32)) are dropped from the identification data.
* **Simulation**: the robot's controller (`robot.controller` or
  `controller=`) with velocity feedforward by default (`feedforward`, as
  `dynid.analysis.data.synthetic` records its data), no torque saturation for the
  simulated robot (`saturate=False`: the initial robot `M = I` needs far more
  torque than the real one; the actual drive's limits say nothing about it),
  Coulomb friction smoothed over `v_s` rad/s, and as many RK4
  substeps as keep `h * lambda_friction <= 1.5` (`substeps="auto"`), taken only in the
  controller periods near a velocity reversal (`adaptive=True` of the simulator: one
  step elsewhere, where the smoothed friction is not stiff), M(q) by the composite rigid
  body algorithm (`crba=True`: equal to rounding, cheaper). The
  reference velocity is the second-order finite difference of `qr`.
* **Coulomb smoothing** `v_s` (default `"auto"`): chosen from the data by the
  output error DIDIM minimises (see `_identify_auto_v_s`): converge at 0.05 rad/s,
  walk a factor-2 grid while the residual ||rho|| falls by more than tol_I, refine once
  at a parabola's vertex in log v_s (unless it predicts a fall within tol_I), continue the
  best width's step to convergence. A robot whose friction is
  sharper than the simulated one is another robot near the velocity reversals (Ia3 +3 to
  +6 % on the independent plant at 0.05). `settings["v_s"]` is the value used,
  `settings["v_s_choice"]` how it was chosen (`"given"` for a number), and
  `settings["v_s_scan"]` the candidates with their ||rho||; `history["v_s"]` the
  width each step simulated. If DIDIM does not converge at 0.05 it starts again at 0.0125
  (`V_S_RETRY`); if not there either, v_s is not searched.
* **Decimation and dead zone**: `nd` and the low-pass cut-off as IDIM
  derives them from the data (`dynid.analysis.processing.signals.default_settings` on
  `qr`; the paper's 100 and 20 Hz at 5 kHz); the velocity dead zone of
  `dynid.analysis.processing.signals.velocity_dead_zone` (`qd_threshold`, default `"auto"` = 1 % of
  each joint's peak *reference* speed, so the thresholds stay fixed over the
  iterations) applied to the simulated velocities, widened by
  `dead_zone_guard` s on each side (default 5 ms: the simulated and the
  actual velocity cross zero at slightly different times).
* **Uncertainty** (`uncertainty`, `gains`; `settings["uncertainty"]`): the sigma is that of
  the last step's WLS on the simulated regressor. `"classic"` (default, the paper's eq. (14))
  counts the decimated samples as independent; the residual of the simulated-output error is
  not (coloured torque noise, and model error that follows the motion), so `"hac"` and
  `"bootstrap"` take the sandwich / circular block bootstrap of
  `dynid.analysis.estimators.hac` on the same system. With gains identified from the data
  (`gains=`, a GainsResult) their covariance is propagated through the simulated loop and
  added (`_gains_covariance`). Measured on the independent plant (benchmarks/coverage_didim.py,
  identified gains, coloured noise, a ripple the model lacks, 100 held-out seeds 14100-14199,
  all converged): the 95 % intervals cover 84.1 % (classic) and 94.8 % (bootstrap, width x1.40
  of classic; 94.1 % on the same runs with one block for every parameter, and 93.9 % and 92.7 %
  on seeds 9400-9499 and 9900-9999 with that rule; hac 88.5 % on an earlier campaign); the
  gains' share moved the bootstrap width by < 0.1 % on 5 seeds. The
  robot file's gains where the actual loop has others are another robot (bias, no sigma
  covers it: the former campaign's 66 % classic / 85 % bootstrap).
* `fc_position`, `order` and `edge` (IDIM's position filter) do not
  apply: the simulated derivatives are exact. They are accepted and ignored
  with a notice so that IDIM's processing settings can be passed as they are.

Convergence: `converged` is True only when the criterion was met within
`max_iter` steps; otherwise (or when a simulation fails) the result says
why in `stop_reason` and never pretends to have converged (the command line
maps that to exit code 3).

Why one module above 800 lines: the settings, the closed-loop step, the Gauss-Newton loop and
the result all read one private loop state (`_Loop`) and one settings dict, which a split would
have to make public across modules.
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.data.record import TORQUE_TIMINGS
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import essential_parameters, with_base_covariance
from dynid.analysis.estimators.physical import pc_wls, require_cvxpy
from dynid.analysis.processing.decimation import ParallelDecimator
from dynid.analysis.processing.row_masks import centred_rows, zero_dead_rows
from dynid.analysis.processing.signals import dead_zone_thresholds, default_settings, velocity_dead_zone
from dynid.analysis.results import ModelResults, notices_block, percent
from dynid.dynamics.base_parameters import base_parameters, base_regressor
from dynid.dynamics.dynamic_model import inverse_dynamics, mass_matrix
from dynid.dynamics.loop_stability import radius_along
from dynid.dynamics.robot import model_signature
from dynid.dynamics.simulation import friction_stiffness, simulate_closed_loop
from dynid.errors import DataError, DynidError, IdentificationError, InputError, did_you_mean
from dynid.provenance import json_safe, versions
from dynid.ranges import check_range

__all__ = ["identify_didim", "didim_covariance", "DIDIMResult", "initial_parameters", "initial_standard",
           "DIDIM_SETTINGS_HELP", "resolve_didim_settings"]

#: DIDIM's processing settings users may override, with their meaning.
DIDIM_SETTINGS_HELP = {
    "nd": "decimation factor n_d (1 = no decimation); default derived from the reference as for IDIM",
    "f_decimation_cutoff": "cut-off of the decimation low-pass, Hz (paper: 0.8 fs / (2 nd))",
    "bandwidth": "motion bandwidth, Hz (estimated from qr if not given)",
    "qd_threshold": ("velocity dead zone on the simulated velocities, rad/s, one value or one per "
                     "joint; 'auto' = 1 % of each joint's peak reference speed; 0 = keep all rows"),
    "dead_zone_guard": "the dead zone is widened by this many seconds on each side",
    "transient": "seconds dropped at the start (closed-loop transient; default 5 / min(wn))",
    "v_s": ("smooth-sign velocity of the simulated Coulomb friction, rad/s, or 'auto' (default): "
            "chosen from the data by the smallest DIDIM residual over a factor-2 grid"),
    "substeps": "RK4 steps per controller period, or 'auto' (h * lambda_friction <= 1.5)",
    "feedforward": "the controller adds the reference velocity (kv qdr) to the PD",
    "saturate": "clip the simulated torque at the joints' tau_max",
    "rate": "controller rate of the simulation, Hz (default: the robot's controller rate)",
    "j_rate": "rate (Hz) of the configurations J_j = max_q M_jj(q) is taken over (eq. (27))",
    "max_step_halvings": ("when an estimate cannot be simulated (M(q) not positive definite, "
                          "diverging simulation), simulate it moved back towards the previous one "
                          "by halving its step at most this many times (0 = stop at once)"),
    "descent_test": ("also halve a step whose simulated estimate raises the output error "
                     "||tau - W(q_s) chi|| by more than tol_I (always on for PC-DIDIM); default false "
                     "(today's iteration)"),
    "torque_timing": ("'held' (default: the logged torque is the command held over [t_k, t_k+1), as the "
                      "paper's g v_tau) or 'centred' (it is centred on t_k, (tau_k-1 + tau_k) / 2, as an "
                      "integrating sensor gives and dynid simulate logs): the simulated rows are "
                      "averaged to match"),
}
#: rad: a simulation tracking the reference worse than this has diverged
DIVERGED_RMS = 10.0
#: rad: a joint reference spanning less than this does not move
STILL_REFERENCE = 1e-3
#: IDIM's position-filter settings: accepted, ignored (the simulated derivatives are exact).
IGNORED_SETTINGS = ("fc_position", "order", "edge")

DEFAULT_TOL = 1e-3
#: Gauss-Newton steps before DIDIM gives up. From the paper's start (eq. (31): Ia = 1, the rest 0)
#: a 7-joint arm needs 13-17 (dynid's simulated LWR4+, seeds 2, 4, 5: at 10 it stopped at a relative
#: change of 0.004, converging); a start near the answer converges in 2-5, unaffected.
DEFAULT_MAX_ITER = 20
DEFAULT_V_S = "auto"
V_S_START = 0.05            # rad/s, where the automatic choice of v_s starts (the former default)
V_S_MIN = V_S_START / 32    # rad/s, smallest v_s tried: ~20 RK4 substeps on the TX40 at 5 kHz
V_S_MAX = V_S_START * 8     # rad/s, largest v_s tried
#: rad/s, where the choice starts again when DIDIM does not converge at V_S_START (mid-grid in log v_s)
V_S_RETRY = V_S_START / 4
DEFAULT_GUARD = 0.005
DEFAULT_J_RATE = 1000.0
DEFAULT_HALVINGS = 6
MOVING_SIGMA = 3.0          # a last step larger than this many sigma is reported
PD_MARGIN = 1e-9            # smallest accepted eigenvalue of M(q), relative to the largest
STIFFNESS_TARGET = 1.5      # h * lambda of the friction, per RK4 substep
WELL_IDENTIFIED = 10.0      # %sigma below which a parameter's relative change is tracked
CHUNK = 10_000


# ----------------------------------------------------------------------------- result

@dataclass(eq=False, repr=False)
class DIDIMResult(ModelResults):
    """Everything a DIDIM identification produced.

    `result` is the per-joint WLS of the last Gauss-Newton step on all base
    parameters (the DIDIM estimate); `essential` the essential parameters
    found from it (or None). `history` has one row per step (see
    `identify_didim`). Full-rate arrays of the last simulation (for
    Fig. 7): `t`, `q_sim`, `qr`, `tau` (measured), `tau_sim` (=
    IDM(q_sim, qd_sim, qdd_sim) chi_hat, the final model on the simulated
    motion, at each sample: with `torque_timing = "centred"` the fitted rows are the mean
    of two consecutive samples of it) and `tau_ddm` (the torque the simulated controller applied). The
    decimated system of the last step (for Fig. 6): `t_dec`, `tau_dec` (Y),
    `tau_est_dec` (W_delta chi_hat), `W_dec`, `row_mask`.
    """

    robot_name: str
    base: object                      # BaseParameters
    result: object                    # IdentificationResult, last step's WLS
    essential: object                 # EssentialResult or None
    history: pd.DataFrame
    converged: bool
    stop_reason: str
    settings: dict
    initial: np.ndarray               # chi^0 (base parameters)
    kd_scale: np.ndarray              # derivative-gain factors of the last simulation
    t: np.ndarray
    q_sim: np.ndarray
    qr: np.ndarray
    tau: np.ndarray
    tau_sim: np.ndarray
    tau_ddm: np.ndarray
    t_dec: np.ndarray
    tau_dec: np.ndarray
    tau_est_dec: np.ndarray
    W_dec: np.ndarray
    row_mask: np.ndarray
    transient_samples: int = 0
    notices: list = field(default_factory=list)
    data_hash: str = ""
    source: str = ""
    truth: dict = None                # true base-parameter values, for simulated data
    joint_names: list = None
    timings: list = field(default_factory=list)   # seconds per step (not in to_dict)
    gains: object = None              # GainsResult when the controller gains were identified
    physical: object = None           # PhysicalResult of the last step (physical=True: PC-DIDIM)
    robot_signature: str = ""     # dynamics.robot.model_signature of the robot identified
    _state: object = field(default=None, repr=False)   # (_Loop, last step) for didim_covariance

    method = "DIDIM"

    # ---------------------------------------------------------------- access
    @property
    def iterations(self) -> int:
        """Number of Gauss-Newton steps (least-squares solves) done."""
        return int(len(self.history))

    @property
    def chi(self) -> np.ndarray:
        """The final DIDIM estimate of the base parameters."""
        return self.result.chi

    @property
    def model(self):
        """The model users predict with: the essential WLS estimate if computed, else the base one."""
        return self.essential.result if self.essential is not None else self.result

    @property
    def tracking_rms(self) -> np.ndarray:
        """RMS of qr - q_sim per joint over the identification samples of the last simulation."""
        e = (self.qr - self.q_sim)[self.transient_samples:]
        return np.sqrt(np.mean(e ** 2, axis=0))

    def parameter_table(self):
        """One row per base parameter: relation, initial value, DIDIM value, std, %σ, essential.

        Returns
        -------
        pandas.DataFrame
            One row per base parameter.
        """
        rows = []
        ess = {}
        if self.essential is not None:
            m = self.essential.result
            ess = dict(zip(m.names, zip(m.chi, m.bse.to_numpy(), m.rel_std.to_numpy())))
        rel = self.base.relations
        for k, name in enumerate(self.base.names):
            row = {"name": name, "relation": rel[k], "initial": self.initial[k],
                   "value": self.result.chi[k], "std": self.result.bse.to_numpy()[k],
                   "rel_std_percent": self.result.rel_std.to_numpy()[k]}
            if self.essential is not None:
                e = ess.get(name)
                row.update({"essential": e is not None,
                            "essential_value": e[0] if e else np.nan,
                            "essential_std": e[1] if e else np.nan,
                            "essential_rel_std_percent": e[2] if e else np.nan})
            if self.truth:
                row["true"] = self.truth.get(name, np.nan)
            rows.append(row)
        return pd.DataFrame(rows).set_index("name")

    # ---------------------------------------------------------------- presentation
    def summary(self) -> str:
        h = self.history
        state = "converged" if self.converged else "DID NOT CONVERGE"
        lines = [f"DIDIM identification of robot '{self.robot_name}' from {self.source}",
                 f"  {state} after {self.iterations} Gauss-Newton step(s): {self.stop_reason}",
                 f"  samples: {self.t.size} at {self.settings['fs']:g} Hz, first "
                 f"{self.transient_samples} dropped (closed-loop transient); {self.t_dec.size} "
                 f"decimated (nd = {self.settings['nd']}, low-pass "
                 f"{self.settings['f_decimation_cutoff']:.3g} Hz)",
                 f"  base parameters: {self.base.n_base}"
                 + (f", essential: {len(self.essential.result.names)}" if self.essential else ""),
                 f"  relative error ||Y - W chi|| / ||Y||: {percent(self.result.rel_error)}"
                 + (f" (essential model {percent(self.essential.result.rel_error)})"
                    if self.essential else ""),
                 "  tracking RMS of the last simulation (qr - q_sim): "
                 + ", ".join(f"{v:.3g} {'m' if j + 1 in self._prismatic() else 'rad'}"
                             for j, v in enumerate(self.tracking_rms)),
                 f"  simulated Coulomb friction: smooth sign over v_s = {self.settings['v_s']:.3g} rad/s "
                 f"({self.settings.get('v_s_choice', 'given')})",
                 "", "Gauss-Newton steps:"]
        cols = [c for c in ("iteration", "v_s", "rho_norm", "rel_change", "output_error", "rel_error",
                            "max_rel_param_change", "max_change_sigma") if c in h]
        # the report's units: relative error and parameter change in %, ||rho|| and the output
        # error in N m; a step with no previous one to compare has no relative change: a dash
        shown = h[cols].copy()
        for c in ("rel_error", "max_rel_param_change"):
            if c in shown:
                shown[c] = 100.0 * shown[c]
        shown = shown.rename(columns={"v_s": "v_s [rad/s]", "rho_norm": "||rho|| [N m]",
                                      "output_error": "output_error [N m]", "rel_error": "rel_error [%]",
                                      "max_rel_param_change": "max_rel_param_change [%]",
                                      "max_change_sigma": "max_change [sigma]"})
        lines.append(shown.to_string(index=False, na_rep="—", float_format=lambda x: f"{x:.5g}"))
        lines.append("")
        lines.append(self.model.summary(notices=False, prismatic=self._prismatic(),
                                        title=("DIDIM: the essential model, refitted on its last step's system"
                                               if self.essential is not None else
                                               f"DIDIM: the {self.model.method} of its last step (eq. (24))")))
        if self.physical is not None:
            lines += ["", "PC-DIDIM: the last step's WLS refitted under physical consistency (the "
                      "estimate the loop simulated)", self.physical.summary()]
        block = notices_block(self.notices, self.model.notices)
        if block:
            lines += [""] + block
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-safe, deterministic dict (no timings).

        Laid out like `dynid.analysis.estimators.idim.IDIMResult.to_dict`: `parameters`,
        `rel_error` and `rms_per_joint` are those of `model` (the essential
        parameters when they were computed, `model` says which); `wls` holds the
        last step's WLS on all base parameters (the DIDIM estimate).

        Returns
        -------
        dict
            JSON-safe; the same for the same data and settings.
        """
        def params(res):
            return res._records(self._prismatic())
        r = self.result
        m = self.model
        return json_safe({
            "method": "DIDIM",
            "robot": self.robot_name,
            "robot_signature": self.robot_signature or None,
            "source": self.source,
            "converged": bool(self.converged),
            "iterations": self.iterations,
            "stop_reason": self.stop_reason,
            "settings": self.settings,
            "base_parameters": self.base.table(),
            "initial_parameters": {n: v for n, v in zip(self.base.names, self.initial) if v != 0.0},
            "model": "essential" if self.essential is not None else "base",
            "parameters": params(m),
            "rel_error": m.rel_error,
            "rms_per_joint": list(m.rms),
            "wls": {"parameters": params(r), "rel_error": r.rel_error, "rms_per_joint": list(r.rms),
                    "joint_sigma": None if r.joint_sigma is None else list(r.joint_sigma),
                    "cond": r.cond, "covariance": r.cov},
            "essential": None if self.essential is None else self.essential.to_dict(),
            "history": self.history.to_dict(orient="records"),
            "kd_scale": list(self.kd_scale),
            "tracking_rms": list(self.tracking_rms),
            "versions": versions(),
            "data_hash": self.data_hash,
            "notices": self.notices,
            "controller_gains": None if self.gains is None else self.gains.to_dict(),
            "true_values": self.truth,
            # PC-DIDIM: the physically consistent estimate of the last step (None: plain DIDIM)
            "physical": None if self.physical is None else self.physical.physical_block(),
        })



# ----------------------------------------------------------------------------- settings

def _bool(value, name):
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise InputError(f"DIDIM setting {name} must be true or false, got {value!r}")


def _positive(value, name, allow_zero=False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"DIDIM setting {name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise InputError(f"DIDIM setting {name} must be a {'non-negative' if allow_zero else 'positive'} "
                         f"number, got {value!r}")
    return v


def _v_s_setting(value):
    if isinstance(value, str):
        if value.strip().lower() == "auto":
            return "auto"
        raise InputError(f"DIDIM setting v_s must be 'auto' or a non-negative number (rad/s), got {value!r}")
    return _positive(value, "v_s", allow_zero=True)


def _count(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise InputError(f"DIDIM setting {name} must be an integer >= 0, got {value!r}")
    return int(value)


def resolve_didim_settings(experiment, robot, controller, qr, overrides=None):
    """DIDIM's settings for this recording (data-derived defaults, then `overrides`).

    Returns `(settings, notices)`; `qd_threshold` is still `"auto"` or the
    user's value here (it becomes numbers in `identify_didim`).
    """
    overrides = dict(overrides or {})
    notices = []
    ignored = sorted(k for k in overrides if k in IGNORED_SETTINGS)
    if ignored:
        notices.append(f"setting(s) {', '.join(ignored)} ignored: DIDIM builds the regressor from the "
                       "simulated states, whose derivatives are exact (no position filter)")
        for k in ignored:
            overrides.pop(k)
    overrides.pop("fs", None)
    unknown = sorted(set(overrides) - set(DIDIM_SETTINGS_HELP))
    if unknown:
        raise InputError(f"unknown DIDIM setting(s) {', '.join(unknown)}"
                         f"{did_you_mean(unknown[0], DIDIM_SETTINGS_HELP)}; known: "
                         + ", ".join(f"{k} ({v})" for k, v in DIDIM_SETTINGS_HELP.items()))
    fs = float(experiment.fs)
    wn = np.broadcast_to(np.asarray(controller.wn, dtype=float), (robot.n_joints,))
    transient = overrides.pop("transient", None)
    transient = 5.0 / float(np.min(wn)) if transient is None else _positive(transient, "transient",
                                                                               allow_zero=True)
    n_transient = int(math.ceil(transient * fs - 1e-9))
    if qr.shape[0] - n_transient < 10:
        raise DataError(f"{experiment.source}: {qr.shape[0]} samples; DIDIM drops the first "
                        f"{n_transient} ({transient:.3g} s, the closed-loop transient) and needs more")
    dec_keys = {k: overrides.pop(k) for k in ("nd", "f_decimation_cutoff", "bandwidth")
                if overrides.get(k) is not None}
    for k in ("nd", "f_decimation_cutoff", "bandwidth"):
        overrides.pop(k, None)
    proposed = default_settings(fs, qr[n_transient:], edge=0, **dec_keys)
    rate = overrides.pop("rate", None)
    rate = float(controller.rate) if rate is None else _positive(rate, "rate")
    substeps = overrides.pop("substeps", "auto")
    if substeps != "auto" and (isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer))
                               or substeps < 1):
        raise InputError(f"DIDIM setting substeps must be 'auto' or a positive integer, got {substeps!r}")
    s = {
        "fs": fs,
        "rate": rate,
        "nd": int(proposed["nd"]),
        "f_decimation_cutoff": float(proposed["f_decimation_cutoff"]),
        "bandwidth": float(proposed["bandwidth"]),
        "qd_threshold": overrides.pop("qd_threshold", "auto"),
        "dead_zone_guard": _positive(overrides.pop("dead_zone_guard", DEFAULT_GUARD),
                                     "dead_zone_guard", allow_zero=True),
        "transient": float(transient),
        "v_s": _v_s_setting(overrides.pop("v_s", DEFAULT_V_S)),
        "v_s_choice": "given",
        "substeps": substeps if substeps == "auto" else int(substeps),
        "feedforward": _bool(overrides.pop("feedforward", True), "feedforward"),
        "saturate": _bool(overrides.pop("saturate", False), "saturate"),
        "j_rate": _positive(overrides.pop("j_rate", DEFAULT_J_RATE), "j_rate"),
        "max_step_halvings": _count(overrides.pop("max_step_halvings", DEFAULT_HALVINGS),
                                    "max_step_halvings"),
        "descent_test": _bool(overrides.pop("descent_test", False), "descent_test"),
        # default: what the recording says of itself (a simulated one, 'centred'), else the paper's
        "torque_timing": _torque_timing(overrides.pop("torque_timing", None)
                                        or (getattr(experiment, "meta", None) or {}).get("torque_timing")
                                        or "held"),
    }
    return s, notices


def _torque_timing(value):
    if value not in TORQUE_TIMINGS:
        raise InputError(f"DIDIM setting torque_timing (--torque-timing) must be one of "
                         f"{', '.join(TORQUE_TIMINGS)}, got {value!r}")
    return value


# ----------------------------------------------------------------------------- initialisation

def initial_standard(robot) -> np.ndarray:
    """chi^0 of eq. (31) as standard parameters: 0 except `Ia_j = 1`, plus the coupled
    rotors' diagonal share `(c_k / c_m)^2` on the other joints `k` of a coupling with
    motor `m` (the TX40's `Ia5 = 2`; see the module docstring)."""
    n = robot.n_joints
    chi = np.zeros(robot.n_standard)
    ia = np.ones(n)
    for c in robot.couplings:
        coef = np.asarray(c.coefficients, dtype=float)
        joints = list(c.joints)
        cm = coef[joints.index(c.motor)] if c.motor in joints else 1.0
        for jk, ck in zip(joints, coef):
            if jk != c.motor:
                ia[jk - 1] += (ck / cm) ** 2 * 1.0
    for j in range(n):
        chi[14 * j + 10] = ia[j]
    return chi


def initial_parameters(robot, bp) -> np.ndarray:
    """chi^0 of eq. (31) as base parameters (`bp.from_standard(initial_standard(robot))`)."""
    return bp.from_standard(initial_standard(robot))


def _initial_beta(robot, bp, chi0):
    if chi0 is None:
        return initial_parameters(robot, bp), "eq. (31): 0 except Ia_j = 1 (coupled joints 1 + (c_k/c_m)^2)"
    if isinstance(chi0, dict):
        unknown = sorted(set(chi0) - set(bp.names) - set(robot.standard_names))
        if unknown:
            raise InputError(f"chi0 names {', '.join(unknown)} are neither base nor standard "
                             f"parameters of '{robot.name}'")
        if set(chi0) <= set(bp.names):
            return np.array([float(chi0.get(n, 0.0)) for n in bp.names]), "given (base parameters)"
        if set(chi0) <= set(robot.standard_names):
            return bp.from_standard(robot.standard_vector(chi0)), "given (standard parameters)"
        raise InputError("chi0 mixes base and standard parameter names; give one kind")
    try:
        v = np.asarray(chi0, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError("chi0 must be a vector of base or standard parameters, or a dict") from None
    if not np.all(np.isfinite(v)):
        raise InputError("chi0 holds non-finite values")
    if v.size == bp.n_base:
        return v.copy(), "given (base parameters)"
    if v.size == robot.n_standard:
        return bp.from_standard(v), "given (standard parameters)"
    raise InputError(f"chi0 has {v.size} values; robot '{robot.name}' has {bp.n_base} base and "
                     f"{robot.n_standard} standard parameters")


# ----------------------------------------------------------------------------- one step

def _simulate(robot, bp, beta, ctrl, t, qr, qdr, s, kd_scale):
    """Closed-loop simulation with chi = beta; states at the samples t."""
    chi = bp.to_standard(beta, "zero")
    rate = s["rate"]
    substeps = s["substeps"]
    if substeps == "auto":
        x = friction_stiffness(robot, chi, qr[0], 1.0 / rate, s["v_s"])
        substeps = max(1, int(math.ceil(x / STIFFNESS_TARGET))) if math.isfinite(x) else 1
    sim = simulate_closed_loop(robot, chi, t, qr, qdr, q0=qr[0], qd0=qdr[0], controller=ctrl,
                               kd_scale=kd_scale, substeps=substeps, v_s=s["v_s"],
                               feedforward=s["feedforward"], rate=rate, saturate=s["saturate"],
                               adaptive=True, crba=True)
    if sim.t.size == t.size and np.allclose(sim.t, t, rtol=0, atol=1e-9 / rate):
        return sim.q, sim.qd, sim.qdd, sim.tau, substeps, sim
    # controller grid differs from the sampling grid: states at the samples by interpolation
    def at(a):
        return np.column_stack([np.interp(t, sim.t, a[:, j]) for j in range(a.shape[1])])
    return at(sim.q), at(sim.qd), at(sim.qdd), at(sim.tau), substeps, sim


def _positive_definite(M):
    """True when every M[i] has its smallest eigenvalue above PD_MARGIN times its largest:
    a Cholesky factorisation of M[i] - PD_MARGIN trace(M[i]) I exists (trace >= largest
    eigenvalue of a positive definite M). One batched Cholesky costs ~1/9 of the eigenvalues
    (4001-20000 configurations per simulated estimate); False sends the caller to them (the
    exact test and the error message), so the outcome is theirs."""
    tr = np.maximum(np.trace(M, axis1=1, axis2=2), 0.0)
    try:
        np.linalg.cholesky(M - (PD_MARGIN * tr)[:, None, None] * np.eye(M.shape[-1]))
    except np.linalg.LinAlgError:
        return False
    return True


def _simulate_checked(robot, bp, beta, ctrl, t, qr, qdr, s, configs, J_ap, update_gains):
    """Check that `beta` can be simulated, set the derivative gains, simulate.

    M(q, chi) must be positive definite at `configs` (the previous simulation's
    configurations) and, with the gain update, `kd_scale = J / J_ap` with
    `J_j = max M_jj` (eq. (27)). Raises a DynidError when it cannot be simulated.
    """
    chi = bp.to_standard(beta, "zero")
    M = mass_matrix(robot, chi, configs)
    if not _positive_definite(M):
        ev = np.linalg.eigvalsh(M)
        ok = ev[:, 0] > PD_MARGIN * np.abs(ev[:, -1])
        if not np.all(ok):
            i = int(np.flatnonzero(~ok)[0])
            raise InputError(f"M(q) is not positive definite at {int((~ok).sum())} of {len(ok)} "
                             f"configurations (smallest eigenvalue {ev[i, 0]:.3g} at q = "
                             f"{np.array2string(configs[i], precision=3)})")
    if update_gains:
        kd = _gain_scale(M, J_ap)
    else:
        kd = np.ones(robot.n_joints)
    out = _simulate(robot, bp, beta, ctrl, t, qr, qdr, s, kd)
    return out + (kd,)


def _build_chunk(robot, bp, q, qd, qdd, tau, dead, lead=0):
    W = base_regressor(robot, bp, q, qd, qdd)
    # as dynid.analysis.processing.observation.push_chunk: zero both sides of the rows in the dead zone
    keep = None if dead is None else (~dead).astype(float)
    if lead:
        # a centred torque is the mean of the commands held over the two periods around t_k
        W = centred_rows(W, keep)
    elif keep is not None:
        zero_dead_rows(W, keep)
    if keep is None:
        return W, tau, np.ones(tau.shape)
    return W, tau * keep, keep


def _decimated_system(robot, bp, q, qd, qdd, tau, dead, s, workers, progress=None, lead=0):
    """Base regressor of the simulated states, decimated in parallel with tau (eq. (24)).

    The regressor chunks are built by `workers` threads (the compiled kernel
    releases the GIL) and pushed through the decimator in order. `lead = 1`: the states
    start one sample before tau, and each row is the mean of two (a centred torque).
    """
    n_kept = tau.shape[0]
    nd = s["nd"]
    slices = [slice(a, min(n_kept, a + CHUNK)) for a in range(0, n_kept, CHUNK)]

    def build(sl):
        states = slice(sl.start, sl.stop + lead)
        return _build_chunk(robot, bp, q[states], qd[states], qdd[states], tau[sl],
                            None if dead is None else dead[sl], lead)

    if nd <= 1:
        W, y, kept = build(slice(0, n_kept))
        return W, y, kept >= 0.5, np.arange(n_kept)
    dec = ParallelDecimator(nd, n_samples_total=n_kept, fs=s["fs"], cutoff=s["f_decimation_cutoff"])
    parts = []

    def push(res, sl):
        parts.append(dec.push(*res))
        if progress is not None:
            progress(sl.stop / n_kept)

    if workers <= 1 or len(slices) == 1:
        for sl in slices:
            push(build(sl), sl)
    else:
        with ThreadPoolExecutor(max_workers=workers) as ex:
            pending = []
            nxt = 0
            while nxt < len(slices) and len(pending) < workers + 1:
                pending.append((slices[nxt], ex.submit(build, slices[nxt])))
                nxt += 1
            while pending:
                sl, fut = pending.pop(0)
                res = fut.result()
                if nxt < len(slices):
                    pending.append((slices[nxt], ex.submit(build, slices[nxt])))
                    nxt += 1
                push(res, sl)
    dec.finish()
    Wd, taud, kept = (np.concatenate([p[k] for p in parts], axis=0) for k in range(3))
    # a decimated row made mostly of zeroed samples is dropped, as in dynid.analysis.processing.observation
    return Wd, taud, kept >= 0.5, dec.indices


def _data_do_not_excite(L, q_s, why):
    """An IdentificationError naming the cause when it is the recording or the controller, not the
    start: a joint whose reference does not move, or a simulation that diverged."""
    track = np.sqrt(np.mean((L.qr - q_s) ** 2, axis=0))
    if not np.all(np.isfinite(track)) or np.max(track) > DIVERGED_RMS:
        raise IdentificationError(
            "DIDIM: the closed-loop simulation diverged (tracking RMS "
            + ", ".join(f"{v:.3g}" for v in track) + " rad): the robot file's controller (its rate, wn, "
            "zeta, J_ap) cannot track this reference in simulation; check its [controller] table")
    still = [j + 1 for j in range(L.qr.shape[1]) if np.ptp(L.qr[L.n0:, j]) < STILL_REFERENCE]
    if still:
        raise IdentificationError(
            f"DIDIM: the reference of joint(s) {', '.join(map(str, still))} does not move (it spans less than "
            f"{STILL_REFERENCE:g} rad after the transient), so the recording cannot identify every parameter "
            f"({why}); record a trajectory that moves every joint")


def _masked_norm(r, mask):
    return float(np.sqrt(np.sum(np.where(mask, r, 0.0) ** 2)))


# ----------------------------------------------------------------------------- DIDIM

def _controller_of(robot, controller):
    """The controller DIDIM simulates (`controller` or the robot's), checked."""
    ctrl = controller if controller is not None else robot.controller
    if ctrl is None:
        raise InputError(f"DIDIM needs the controller of robot '{robot.name}': add a [controller] "
                         "table (kind, rate, wn, zeta, J_ap, g_ap) to its description or pass "
                         "controller=Controller(...)")
    if ctrl.J_ap is None or ctrl.wn is None or ctrl.zeta is None:
        raise InputError(f"the controller of robot '{robot.name}' needs wn, zeta and J_ap for DIDIM")
    return ctrl


def _check_iteration(tol, max_iter, update_gains):
    """tol_I, max_iter and update_gains, checked."""
    try:
        tol = float(tol)
    except (TypeError, ValueError):
        raise InputError(f"tol must be a number, got {tol!r}") from None
    if not (math.isfinite(tol) and tol > 0):
        raise InputError(f"tol must be a positive number, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise InputError(f"max_iter must be a positive integer, got {max_iter!r}")
    if isinstance(update_gains, (bool, np.bool_)):
        update_gains = bool(update_gains)
    return tol, int(max_iter), update_gains


def _reference_of(experiment, robot, reference):
    """The reference positions (N, n) the simulated robot tracks, and the notices about it."""
    if reference not in ("qr", "q"):
        raise InputError(f"reference must be 'qr' or 'q', got {reference!r}")
    qr = experiment.qr if reference == "qr" else experiment.q
    if qr is None:
        raise DataError(f"{experiment.source}: DIDIM needs the reference positions qr1..qrn (and "
                        "the torques); the data have none"
                        + (" (pass reference='q' to track the measured positions instead)"
                           if experiment.q is not None and reference == "qr" else ""))
    notes = []
    if reference == "q":
        notes.append("the measured positions q are used as the reference qr (the logged reference "
                     "is not available): the simulated robot tracks the actual motion")
    qr = np.ascontiguousarray(qr, dtype=float)
    if qr.shape[1] != robot.n_joints:
        raise DataError(f"{experiment.source}: robot '{robot.name}' has {robot.n_joints} joints "
                        f"but the reference has {qr.shape[1]}")
    return qr, notes


@dataclass
class _Loop:
    """What every Gauss-Newton step of DIDIM shares (fixed before the first one)."""

    robot: object
    bp: object
    ctrl: object
    s: dict
    t: np.ndarray
    qr: np.ndarray
    qdr: np.ndarray
    tau_k: np.ndarray             # torques after the transient
    n0: int                       # samples dropped as the closed-loop transient
    thr: np.ndarray               # velocity dead-zone thresholds
    guard: int
    j_stride: int
    J_ap: np.ndarray
    update_gains: object
    names: list
    info: dict
    workers: int
    max_iter: int
    progress: object = None

    def system(self, q_s, qd_s, qdd_s, k=None, qd_dead=None):
        """The decimated system (Wd, taud, mask, idx) of one simulation, after the transient
        (`qd_dead`: the velocities whose dead zone is used, default `qd_s`)."""
        sl = slice(self.n0, None)
        dead = None
        if np.any(self.thr > 0):
            dead = velocity_dead_zone((qd_s if qd_dead is None else qd_dead)[sl], self.thr, guard=self.guard,
                                      couplings=self.robot.couplings)
        progress, max_iter = self.progress, self.max_iter

        def inner(f):
            if progress is not None and k is not None:
                progress(min(1.0, (k - 1 + f) / max_iter))

        # a centred torque: one state before the first torque kept (the first again when none was dropped)
        lead = int(self.s.get("torque_timing") == "centred")
        rows = slice(self.n0 - lead, None) if self.n0 >= lead else np.r_[0, 0:len(q_s)]
        return _decimated_system(self.robot, self.bp, q_s[rows], qd_s[rows], qdd_s[rows], self.tau_k, dead,
                                 self.s, self.workers, inner, lead=lead)


def _prepare_loop(robot, bp, ctrl, s, t, qr, tau, update_gains, workers, max_iter, progress):
    """The `_Loop` of an identification and the notice describing the simulation."""
    fs = s["fs"]
    n0 = int(math.ceil(s["transient"] * fs - 1e-9))
    qdr = np.gradient(qr, t, axis=0, edge_order=2)
    # 'auto' from the reference speed, so the thresholds stay fixed over the iterations
    thr = dead_zone_thresholds(qdr[n0:], s["qd_threshold"])
    s["qd_threshold"] = [float(v) for v in thr]
    loop = _Loop(robot=robot, bp=bp, ctrl=ctrl, s=s, t=t, qr=qr, qdr=qdr, tau_k=tau[n0:], n0=n0, thr=thr,
                 guard=int(round(s["dead_zone_guard"] * fs)), j_stride=max(1, int(round(fs / s["j_rate"]))),
                 J_ap=np.broadcast_to(np.asarray(ctrl.J_ap, dtype=float), (robot.n_joints,)),
                 update_gains=update_gains, names=list(bp.names), info=dict(s), workers=workers,
                 max_iter=max_iter, progress=progress)
    return loop, _loop_notice(s, n0, update_gains)


def _loop_notice(s, n0, update_gains, continued_at=None):
    """The notice describing the simulation of a `_Loop`; `continued_at`: the width v_s of a run
    that continues another (without a gain update: the actual gains, kept from that one)."""
    head = "DIDIM: " if continued_at is None else f"DIDIM, continued at the chosen v_s = {continued_at:.3g} rad/s: "
    gains = ("; the actual derivative gains (kd_scale = 1)" if continued_at is not None and update_gains is False
             else _GAIN_TEXT[update_gains])
    return (f"{head}closed-loop simulation at {s['rate']:g} Hz from (qr(0), qdr(0)); first "
            f"{n0} samples ({s['transient']:.3g} s) dropped as the closed-loop transient; "
            f"parallel decimation by nd = {s['nd']} (low-pass {s['f_decimation_cutoff']:.3g} Hz){gains}")


_GAIN_TEXT = {True: "; derivative gains updated with J_j / J_ap_j (eq. (27)) at every step",
              "initial": "; derivative gains updated with J_j / J_ap_j (eq. (27)) for the "
                         "simulation of chi^0 only, the actual gains (kd_scale = 1) after",
              False: "; derivative gains NOT updated (kd_scale = 1)"}


def _loop_at(L, v_s, update_gains, max_iter, progress=None, uncertainty="classic"):
    """The `_Loop` of `identify_didim` at another width `v_s`, from a start given as base
    parameters, without resolving the settings again: the same settings, thresholds and
    reference as `L` (what a new call with the same data would compute)."""
    s = dict(L.s)
    s.update(v_s=float(v_s), update_gains=update_gains, max_iter=max_iter, uncertainty=uncertainty,
             initialisation="given (base parameters)")
    return dataclasses.replace(L, s=s, info=dict(s), update_gains=update_gains, max_iter=max_iter,
                               progress=progress)


def _gain_scale(M, J_ap):
    """The gain update's factor `J_j / J_ap_j`, `J_j = max M_jj` over the configurations (eq. (27))."""
    return np.max(np.diagonal(M, axis1=1, axis2=2), axis=0) / J_ap


def _loop_note(L, beta, configs, *, update):
    """Why an estimate could not be simulated, when its sampled loop is unstable: the
    controller, sampled at its rate, sees too little inertia somewhere along the motion
    (`dynid.dynamics.loop_stability`; simulated Pandas with thin wrist links: spectral radii of
    53-422 at the estimates DIDIM stopped on). "" when the loop is stable or cannot be judged."""
    try:
        chi = L.bp.to_standard(np.asarray(beta, dtype=float), "zero")
        kd = _gain_scale(mass_matrix(L.robot, chi, np.asarray(configs)), L.J_ap) if update else None
        rows, radius = radius_along(L.robot, chi, configs, controller=L.ctrl, rate=L.s["rate"], kd_scale=kd)
    except (DynidError, np.linalg.LinAlgError, ValueError):
        return ""
    bad = radius > 1.0
    if not np.any(bad) or not np.all(np.isfinite(radius)):
        return ""
    return (f"; its controller loop, sampled at {L.s['rate']:g} Hz, is unstable at {int(bad.sum())} of {rows.size} "
            f"configurations of the motion (spectral radius up to {float(radius.max()):.3g}): the estimate "
            f"leaves the controller too little inertia (a light wrist): try a heavier start (the paper's eq. (31), "
            f"DIDIM's start with the robot file's gains, or a-priori values: dynid identify --method didim "
            f"--didim-start apriori), or use "
            f"IDIM's model")


def _simulate_step(L, k, beta0, beta_sim, beta_ls, configs, physical, out_prev, tol):
    """Simulate step k's estimate, halving the step from the last simulated one when needed.

    Candidates: beta0 at step 1, else beta_sim + 0.5^h (beta_ls - beta_sim), h = 0..
    max_step_halvings. A candidate fails when it cannot be simulated, or (PC-DIDIM) when
    it raises the output error by more than `tol` (tol_I, relative: the descent test; a change
    within it is inside the noise, as for the stopping rule: at the iteration's fixed point a
    full step raises the error by that little about half of the time). Returns (lam, cand, sim_out, system,
    failure, first_failure) with `failure` the last candidate's error when none worked.
    """
    max_halvings = L.s["max_step_halvings"]
    if k == 1:
        candidates = [(1.0, beta0)]
    else:
        step = beta_ls - beta_sim
        candidates = [(0.5 ** h, beta_sim + 0.5 ** h * step) for h in range(max_halvings + 1)]
    failure = first_failure = None
    system = sim_out = None
    for lam, cand in candidates:  # noqa: B007 (lam, cand: the step taken, returned)
        try:
            sim_out = _simulate_checked(
                L.robot, L.bp, cand, L.ctrl, L.t, L.qr, L.qdr, L.s, configs, L.J_ap,
                L.update_gains is True or (L.update_gains == "initial" and k == 1))
        except DynidError as exc:
            failure = exc
            first_failure = first_failure or str(exc)
            continue
        failure = None
        if (physical or L.s["descent_test"]) and out_prev is not None and lam > 0.5 ** max_halvings:
            # PC-DIDIM: the projected step is a Gauss-Newton step of the linearised problem
            # only; a projected Gauss-Newton needs a descent test on the nonlinear one (the
            # output error). Halved steps stay physical: the set is convex and both ends are in it.
            q_s, qd_s, qdd_s = sim_out[:3]
            system = L.system(q_s, qd_s, qdd_s)
            oe = _masked_norm(system[1] - system[0] @ cand, system[2])
            if oe > out_prev * (1.0 + tol):
                first_failure = first_failure or (f"the output error grew ({oe:.4g} > "
                                                  f"{out_prev:.4g})")
                system = None
                continue
        break
    return lam, cand, sim_out, system, failure, first_failure


def _physical_start(L, beta0, failure):
    """The physically consistent base vector nearest chi0 (PC-WLS projection), and a notice.

    An initial estimate whose M(q) is not positive definite cannot be simulated
    (e.g. an IDIM estimate with a slightly negative rotor inertia); its projection on
    the physically consistent set (pc_wls; metric: 10 % of each |chi0_k|, at least
    10 % of the median |chi0|), moved 1 % towards eq. (31)'s start, can, and the
    iteration starts there.
    Needs the optional cvxpy + Clarabel; without them the original error stands.
    """
    try:
        require_cvxpy()
    except InputError as exc:
        raise InputError(f"DIDIM cannot simulate the initial estimate chi0: {failure}; projecting it on "
                         f"the physically consistent set needs cvxpy: {exc}") from None
    b = np.abs(np.asarray(beta0, dtype=float))
    floor = 0.1 * max(float(np.median(b[b > 0])) if np.any(b > 0) else 1.0, 1e-12)
    cov = np.diag(np.maximum(0.1 * b, floor) ** 2)
    pc = pc_wls(L.robot, L.bp, beta0, cov, n_boot=0)
    # The projection lies on the boundary of the set, where M(q) can be singular (a massless
    # wrist with Ia6 = 0); 1 % of the way towards eq. (31)'s start (M = I but for the coupled
    # wrist, strictly positive definite) puts it inside: M is linear in the parameters.
    start = 0.99 * np.asarray(pc.chi, dtype=float) + 0.01 * initial_parameters(L.robot, L.bp)
    L.s["initialisation"] = f"{L.s.get('initialisation', '')}; projected on the physically consistent set"
    moved = float(np.max(np.abs(start - beta0) / np.maximum(b, floor)))
    return start, (
        f"the initial estimate chi0 cannot be simulated ({failure}): DIDIM starts from its projection on "
        f"the physically consistent set (PC-WLS, largest change {100 * moved:.3g} % of a parameter's scale)")


def _history_row(L, k, lam, res, rho, rel_change, out_err, beta_sim, q_s, substeps, kd):
    """One row of DIDIMResult.history."""
    d = res.chi - beta_sim
    with np.errstate(divide="ignore", invalid="ignore"):
        good = res.rel_std.to_numpy() <= WELL_IDENTIFIED
        max_rel = float(np.max(np.abs(d[good]) / np.abs(res.chi[good]))) if good.any() else np.nan
        max_sig = float(np.max(np.abs(d) / res.bse.to_numpy()))
    sl = slice(L.n0, None)
    track = np.sqrt(np.mean((L.qr[sl] - q_s[sl]) ** 2, axis=0))
    row = {"iteration": k, "step_length": lam, "rho_norm": rho, "rel_change": rel_change,
           "output_error": out_err, "rel_error": res.rel_error, "max_rel_param_change": max_rel,
           "max_change_sigma": max_sig, "substeps": int(substeps), "v_s": float(L.s["v_s"])}
    for j in range(L.robot.n_joints):
        row[f"track_rms_{j + 1}"] = float(track[j])
    for j in range(L.robot.n_joints):
        row[f"kd_scale_{j + 1}"] = float(kd[j])
    return row


def _gauss_newton(L, beta0, tol, physical, pc_options, notices, resume=None):
    """DIDIM's iteration (eqs. (22)-(26)): simulate, build the system, solve by WLS, repeat.

    `resume` continues an iteration whose step `resume["k"] - 1` was done (its `last`, `rho`,
    `out_err` and `beta_ls`, the estimate the next step simulates): the automatic v_s search
    continues the step that scored the chosen width instead of simulating its estimate again
    from a fresh start. Up to `L.max_iter` more steps, numbered from `resume["k"]`.
    Appends its remarks to `notices`; returns (history, timings, last, converged, stop_reason).
    """
    history, timings = [], []
    configs = L.qr[::L.j_stride]
    rho_prev = None
    converged = False
    stop_reason = ""
    last = None
    beta_sim = beta0            # the last simulated estimate (always simulatable)
    beta_ls = None              # the last least-squares solution
    max_halvings = L.s["max_step_halvings"]
    out_prev = None             # output error of the last simulated estimate (PC-DIDIM's descent test)
    damped = []                 # (step, step length, why the full step was refused) of the damped steps
    max_iter = L.max_iter
    k0 = 1
    if resume is not None:
        last, rho_prev, out_prev, beta_ls = resume["last"], resume["rho"], resume["out_err"], resume["beta_ls"]
        beta_sim, configs, k0 = last["beta_sim"], last["q"][::L.j_stride], resume["k"]
    for k in range(k0, k0 + max_iter):
        t_start = time.perf_counter()
        lam, cand, sim_out, system, failure, first_failure = _simulate_step(
            L, k, beta0, beta_sim, beta_ls, configs, physical, out_prev, tol)
        if failure is not None and k == 1 and "not positive definite" in str(failure):
            beta0, note = _physical_start(L, beta0, failure)
            notices.append(note)
            beta_sim = beta0
            lam, cand, sim_out, system, failure, first_failure = _simulate_step(
                L, k, beta0, beta_sim, beta_ls, configs, physical, out_prev, tol)
        if failure is not None:
            if k == 1:
                raise InputError(f"DIDIM cannot simulate the initial estimate chi0: {failure}"
                                 f"{_loop_note(L, beta0, configs, update=L.update_gains in (True, 'initial'))}") from None
            stop_reason = (f"step {k}: the estimate of step {k - 1} cannot be simulated, even moved "
                           f"back to 1/{2 ** max_halvings} of its step from the last simulated one: "
                           f"{failure}{_loop_note(L, beta_ls, configs, update=L.update_gains is True)}")
            break
        q_s, qd_s, qdd_s, tau_ddm, substeps, sim, kd = sim_out
        if lam < 1.0:
            damped.append((k, lam, first_failure))
        beta_sim = cand
        for note in sim.notes:
            if note not in notices:
                notices.append(note)
        t_sim = time.perf_counter() - t_start
        configs = q_s[::L.j_stride]
        Wd, taud, mask, idx = system if system is not None else L.system(q_s, qd_s, qdd_s, k - k0 + 1)
        try:
            res = ls.wls(Wd, taud, L.names, row_mask=mask, settings=L.info)
        except IdentificationError as exc:
            # the simulated motion, not the recording, lacks excitation: the estimate simulated
            # drove the simulated robot away from the reference (e.g. eq. (31)'s unit inertias
            # under the actual, stiffer gains); IDIM's advice to excite more does not apply
            why = str(exc).splitlines()[0]
            if k == 1 or last is None:
                _data_do_not_excite(L, q_s, why)
                raise IdentificationError(
                    f"DIDIM: the closed-loop simulation of the initial estimate ({L.s.get('initialisation')}) "
                    f"does not excite every parameter ({why}); tracking RMS of that simulation "
                    + ", ".join(f"{v:.3g}" for v in np.sqrt(np.mean((L.qr - q_s) ** 2, axis=0)))
                    + " rad. Start from closer values: the robot file's a-priori values (chi0) or "
                    "IDIM's estimate (dynid identify --method didim --gains identify starts there)") from None
            stop_reason = (f"step {k}: the motion simulated with the estimate of step {k - 1} does not excite "
                           f"every parameter ({why}); the result is step {k - 1}'s")
            break
        rho = _masked_norm(res.residual, mask)
        out_err = _masked_norm(taud - Wd @ beta_sim, mask)
        out_prev = out_err
        rel_change = abs(rho - rho_prev) / rho_prev if rho_prev is not None and rho_prev > 0 else np.nan
        history.append(_history_row(L, k, lam, res, rho, rel_change, out_err, beta_sim, q_s, substeps, kd))
        timings.append({"iteration": k, "simulation_s": t_sim,
                        "total_s": time.perf_counter() - t_start})
        last = dict(res=res, Wd=Wd, taud=taud, mask=mask, idx=idx, q=q_s, qd=qd_s, qdd=qdd_s,
                    tau_ddm=tau_ddm, kd=kd.copy(), start=beta0, beta_sim=np.array(beta_sim))
        beta_ls = res.chi
        if physical:
            last["physical"] = pc_wls(L.robot, L.bp, res.chi, res.cov, n_boot=0, **pc_options)
            beta_ls = last["physical"].chi
        if L.progress is not None:
            L.progress(min(1.0, (k - k0 + 1) / max_iter))
        if rho_prev is not None and rel_change <= tol and lam == 1.0:
            converged = True
            stop_reason = (f"|(||rho_{k}|| - ||rho_{k - 1}||)| / ||rho_{k - 1}|| = {rel_change:.3g} "
                           f"<= tol_I = {tol:g}")
            break
        rho_prev = rho
    else:
        stop_reason = (_unmet_criterion(history[-1], max_iter, tol) if max_iter > 1 or resume is not None
                       else "max_iter = 1: one step cannot test the criterion (it compares two steps)")
    if damped:
        notices.append(_damped_notice(damped))
    return history, timings, last, converged, stop_reason


def _damped_notice(damped) -> str:
    """One notice for the damped Gauss-Newton steps `damped` [(step, length, why the full step was
    refused)]: a step per line read as a failure in the demo's first screen, four times."""
    steps = ", ".join(f"{k} ({lam:g})" for k, lam, _ in damped)
    grew = [why for _, _, why in damped if why.startswith("the output error grew")]
    failed = [(k, why) for k, _, why in damped if not why.startswith("the output error grew")]
    reasons = []
    if failed:
        reasons.append(f"could not be simulated (step {failed[0][0]}: {failed[0][1]})")
    if grew:
        reasons.append(f"did not lower the output error ({grew[0]})")
    return (f"damped Gauss-Newton steps {steps}: each simulated that fraction of its step from the previous "
            f"simulated estimate, because the full step's estimate {' or '.join(reasons)}; usual while far from "
            "the answer, and a damped step is never taken as convergence (history: step_length)")


def _unmet_criterion(row, max_iter, tol) -> str:
    """Why `max_iter` steps did not converge, from the last step's history `row`: its change of
    ||rho|| above tol_I, or a change within it on a damped step (convergence is declared after a
    full step only: a step cut to a fraction changes ||rho|| little whether or not the iteration
    has settled)."""
    change = row["rel_change"]
    if not change <= tol:
        return (f"max_iter = {max_iter} steps without meeting the criterion: last relative change of "
                f"||rho|| {change:.3g} > tol_I = {tol:g}")
    return (f"max_iter = {max_iter} steps without meeting the criterion: the last relative change of ||rho|| "
            f"{change:.3g} is within tol_I = {tol:g}, but on a damped step (step length {row['step_length']:.3g}, "
            "halved by the descent test or the step safeguard), and convergence is only declared after a "
            "full step")


def _convergence_notices(history, converged, stop_reason):
    if not converged:
        return [f"DIDIM did not converge: {stop_reason}"]
    if history[-1]["max_change_sigma"] > MOVING_SIGMA:
        return [f"the residual norm met the criterion, but the last step still moved a "
                f"parameter by {history[-1]['max_change_sigma']:.3g} standard deviations: the "
                "estimate is not a fixed point of the iteration (e.g. the simulated loop does not "
                "reproduce the actual one; see the gain update in the documentation)"]
    return []


def identify_didim(experiment, robot, *, settings=None, chi0=None, tol=DEFAULT_TOL,
                   max_iter=DEFAULT_MAX_ITER, update_gains=True, essential=True, progress=None,
                   bp=None, controller=None, reference="qr", max_error_growth=0.02,
                   workers=None, physical=False, prior=None, prior_weight=1.0, mass_tolerance=None,
                   n_boot=100, uncertainty="classic", gains=None) -> DIDIMResult:
    """Identify the base (and essential) parameters of `robot` by DIDIM (section 3).

    Parameters
    ----------
    experiment : `dynid.analysis.data.experiment.Experiment` with `t`, `qr` (the
        reference the actual robot tracked) and `tau`. Measured `q` is not used.
    robot : the robot, with its controller (`robot.controller` or `controller=`).
    settings : overrides of `DIDIM_SETTINGS_HELP` (see the module docstring).
    chi0 : initial parameters: None (eq. (31)), a base or standard vector, or a dict of
        base or standard names.
    tol : tol_I, the relative change of ||rho|| between two steps that stops the
        iteration. Default 1e-3: ||rho||^2 = ||noise||^2 + ||model error||^2, so a
        relative change below 1e-3 means the step changed the model error by less
        than sqrt(2e-3) ~ 4.5 % of the residual norm, i.e. well inside the noise.
    max_iter : most Gauss-Newton steps (least-squares solves).
    update_gains : True (paper: derivative gains times J_j / J_ap_j at every step),
        `"initial"` (only for the simulation of chi^0) or False (see the module doc).
    essential : also compute the essential parameters from the last step.
    progress : callable(fraction in [0, 1]) called while the steps run.
    bp : base parameters of the robot (computed if None).
    physical : PC-DIDIM: each Gauss-Newton step's WLS is refitted under physical consistency
        (`dynid.analysis.estimators.physical.pc_wls`), and the next step simulates that
        physically consistent estimate; `result.physical` is the last step's PC fit.
    prior, prior_weight, mass_tolerance : of each step's PC fit (`pc_wls`).
    n_boot : physical=True: parametric-bootstrap refits of the last step's PC fit (its sigma
        and intervals, as for PC-WLS; the steps before it need none). The bootstrap is that
        of the last Gauss-Newton step's linear problem, the simulated regressor held fixed:
        the uncertainty DIDIM's own sigma (eq. (16) on that step) describes.
    reference : `"qr"` (default) or `"q"`: track the measured positions instead
        (only when the reference was not logged; a notice says so).
    max_error_growth : criterion of the essential-parameter search.
    uncertainty : covariance of the last step's WLS (the reported sigma): "classic" (eq. (14),
        the paper's), "hac" or "bootstrap" (`dynid.analysis.estimators.least_squares`; the
        residual of the simulated-output error is correlated in time); see `didim_covariance`.
        The essential parameters keep eq. (14).
    gains : the `GainsResult` of controller gains identified from the data that `controller`
        holds: their covariance is propagated through the simulated loop and added to the
        reported one (one more simulation per gain); the result keeps it in `gains`.
    workers : threads building the regressor chunks (default 1; the compiled kernel
        releases the GIL, but on a busy 2-core machine 2 threads were slower).

    Returns a `DIDIMResult`; `converged` is False when `max_iter` steps
    did not meet the criterion or a simulation failed (`stop_reason` says which).
    The work is split: inputs (_controller_of, _check_iteration, _reference_of), the
    shared state (_prepare_loop), the iteration (_gauss_newton: _simulate_step, the WLS,
    _history_row) and the result (_didim_result).
    """
    bp = base_parameters(robot) if bp is None else bp
    ctrl = _controller_of(robot, controller)
    tol, max_iter, update_gains = _check_iteration(tol, max_iter, update_gains)
    ls.check_uncertainty(uncertainty)
    notices = list(getattr(experiment, "notices", []) or [])
    qr, more = _reference_of(experiment, robot, reference)
    notices += more
    tau = np.ascontiguousarray(experiment.tau, dtype=float)
    t = np.asarray(experiment.t, dtype=float)
    s, more = resolve_didim_settings(experiment, robot, ctrl, qr, settings)
    notices += more
    # ranges first (dynid.ranges): a tiny v_s makes the simulation stiff without end
    if s["v_s"] != "auto":
        s["v_s"] = check_range("v_s", s["v_s"])
    if physical:
        check_range("prior_weight", prior_weight)
        check_range("n_boot", n_boot)
    if not (isinstance(update_gains, bool) or update_gains == "initial"):
        raise InputError(f"update_gains must be True, False or 'initial', got {update_gains!r}")
    if s["v_s"] == "auto":
        return _identify_auto_v_s(experiment, robot, settings=settings, chi0=chi0, tol=tol,
                                  max_iter=max_iter, update_gains=update_gains, essential=essential,
                                  progress=progress, bp=bp, controller=controller, reference=reference,
                                  max_error_growth=max_error_growth, workers=workers, physical=physical,
                                  prior=prior, prior_weight=prior_weight, mass_tolerance=mass_tolerance,
                                  n_boot=n_boot, uncertainty=uncertainty, gains=gains)
    s["update_gains"] = update_gains
    s["tol"] = tol
    s["max_iter"] = max_iter
    s["uncertainty"] = uncertainty + ("+gains" if gains is not None else "")
    beta0, init_note = _initial_beta(robot, bp, chi0)
    s["initialisation"] = init_note
    workers = 1 if workers is None else max(1, min(int(workers), os.cpu_count() or 1))
    L, notice = _prepare_loop(robot, bp, ctrl, s, t, qr, tau, update_gains, workers, max_iter, progress)
    notices.append(notice)
    pc_options = dict(prior=prior, prior_weight=prior_weight, mass_tolerance=mass_tolerance)
    history, timings, last, converged, stop_reason = _gauss_newton(L, beta0, tol, physical, pc_options,
                                                                   notices)
    notices += _convergence_notices(history, converged, stop_reason)
    return _didim_result(L, experiment, beta0, tau, history, timings, last, converged, stop_reason, notices,
                         essential=essential, max_error_growth=max_error_growth, physical=physical,
                         n_boot=n_boot, pc_options=pc_options, uncertainty=uncertainty, gains_cov=gains)


def _gains_covariance(L, last, res, gains):
    """Covariance of the DIDIM estimate from the error of identified controller gains.

    The simulated loop runs with the gains `gains` identified from the data; their error moves
    the simulated motion, hence the regressor W(q_s) and the estimate. Sensitivity by one-sided
    differences: each gain g_i moved by its standard deviation s_i, the last simulated estimate
    simulated again and the step's WLS solved on the rows of the step that produced `res` (its
    dead zone), `J_i = (chi_i - chi) / s_i`; covariance `J C_g J'` with `C_g` the gains'
    covariance (correlated within a joint). One closed-loop simulation per gain. The estimate
    need not be a rigid body off the simulated motion: when the moved loop reaches a pose where
    its M(q) is not positive definite, the gain is moved the other way (-s_i), and when that
    fails too its share is left out (returned in `missing`).

    Returns
    -------
    cov : array (b, b)
    cols : list of str
        The gains propagated.
    missing : list of str
        The gains whose moved loops could not be simulated.
    """
    names_g = list(gains.names)
    sd = np.sqrt(np.maximum(np.diag(gains.cov), 0.0))
    J = np.zeros((res.chi.size, len(names_g)))
    s = dict(L.s)
    cols, missing = [], []
    for i in range(len(names_g)):
        if not sd[i] > 0:
            continue
        for step in (sd[i], -sd[i]):
            chi_g = np.array(gains.chi, dtype=float)
            chi_g[i] += step
            moved = dataclasses.replace(gains, chi=chi_g, cov=gains.cov)
            try:
                q_s, qd_s, qdd_s = _simulate(L.robot, L.bp, last["beta_sim"], moved.controller(L.robot),
                                             L.t, L.qr, L.qdr, s, last["kd"])[:3]
            except InputError:   # M(q) not positive definite where this loop goes, or a gain moved to <= 0
                continue
            # the rows of the last step (its velocity dead zone): a dead zone moving with the simulated
            # zero crossings makes the estimate jump between row sets, and the differences noise
            Wd, taud, mask, _ = L.system(q_s, qd_s, qdd_s, qd_dead=last["qd"])
            r = ls.wls(Wd, taud, L.names, row_mask=mask)
            J[:, i] = (r.chi - res.chi) / step
            cols.append(names_g[i])
            break
        else:
            missing.append(names_g[i])
    cov = J @ gains.cov @ J.T
    return 0.5 * (cov + cov.T), cols, missing


def _robust(L, last, uncertainty, gains, n_boot_cov, seed):
    """The last step's WLS with `uncertainty` and, with `gains`, the gains' share added."""
    res = last.get("res_classic", last["res"])    # eq. (14): the run may have replaced it already
    if uncertainty != "classic":
        res = ls.wls(last["Wd"], last["taud"], L.names, row_mask=last["mask"], settings=L.info,
                     uncertainty=uncertainty, n_boot=n_boot_cov, seed=seed)
    if gains is None:
        return res
    extra, cols, missing = _gains_covariance(L, last, res, gains)
    base = res.bse.to_numpy()
    res = dataclasses.replace(res, cov=res.cov + extra)
    grow = np.nanmedian(res.bse.to_numpy() / np.where(base > 0, base, np.nan))
    unc = dict(res.settings.get("least_squares", {}).get("uncertainty", {}))
    unc["controller_gains"] = (f"covariance of the {len(cols)} identified gains propagated through the "
                               "simulated loop (one simulation per gain, two when the first fails)")
    notes = [f"sigma includes the error of the identified controller gains ({len(cols)} gains propagated "
             f"through the simulated loop; median sigma x{grow:.3g})"]
    if missing:
        unc["controller_gains_missing"] = missing
        notes.append(f"the error of {len(missing)} identified gain(s) ({', '.join(missing)}) is not in sigma: the "
                     "loop could not be simulated with the gain moved by its sigma either way (it reaches poses "
                     "where the estimate's M(q) is not positive definite, or the moved gain is not positive); "
                     "sigma may be optimistic by their share")
    res.settings = {**res.settings, "least_squares": {**res.settings.get("least_squares", {}),
                                                      "uncertainty": unc}}
    res.notices = list(res.notices) + notes
    return res


def didim_covariance(result, uncertainty="bootstrap", *, gains=None, n_boot=300, seed=0):
    """The last Gauss-Newton step's WLS of a DIDIM result with another covariance.

    Parameters
    ----------
    result : DIDIMResult
        From `identify_didim` in this process (it keeps the loop it simulated).
    uncertainty : {"classic", "hac", "bootstrap"}
        Covariance of the last step's WLS on the simulated regressor (eq. (14), the
        Newey-West sandwich or the circular block bootstrap of `least_squares`): the
        residual of the simulated-output error is correlated in time, so eq. (14) is
        optimistic.
    gains : GainsResult, optional
        The identified controller gains the loop was simulated with: their covariance
        is propagated to the estimate (`_gains_covariance`) and added.
    n_boot, seed : int
        Replicates and seed of the bootstrap.

    Returns
    -------
    IdentificationResult
        The same estimate as `result.result`, another `cov`.

    Raises
    ------
    InputError
        An unknown `uncertainty`, or a result that does not hold its loop (read from JSON).
    """
    ls.check_uncertainty(uncertainty)
    if result._state is None:
        raise InputError("didim_covariance needs a DIDIMResult computed in this process by identify_didim")
    L, last = result._state
    return _robust(L, last, uncertainty, gains, n_boot, seed)


def _didim_result(L, experiment, beta0, tau, history, timings, last, converged, stop_reason, notices, *,
                  essential, max_error_growth, physical, n_boot, pc_options, uncertainty="classic",
                  gains_cov=None):
    """The DIDIMResult of the last step: essential set, simulated torques, provenance."""
    robot, bp, names = L.robot, L.bp, L.names
    if uncertainty != "classic" or gains_cov is not None:
        last["res_classic"] = last["res"]
        last["res"] = _robust(L, last, uncertainty, gains_cov, 300, 0)
    res = last["res"]
    if physical and n_boot:
        last["physical"] = _pc_of(robot, bp, res, last.get("res_classic"), n_boot, pc_options,
                                  uncertainty + ("+gains" if gains_cov is not None else ""))
    _pc_errors(last.get("physical"), res.chi, last["Wd"], last["taud"], last["mask"])
    h = experiment.data_hash() if hasattr(experiment, "data_hash") else ""
    res.data_hash, res.prismatic = h, tuple(getattr(bp, "prismatic", ()))
    ess = None
    if essential:
        ess = essential_parameters(last["Wd"], last["taud"], names, ls.wls,
                                   max_error_growth=max_error_growth, row_mask=last["mask"],
                                   settings=L.info)
        if uncertainty != "classic" or gains_cov is not None:   # the full model's covariance is not eq. (14)
            ess = with_base_covariance(ess, res)
        for r in (ess.result, ess.base):
            r.data_hash, r.prismatic = h, tuple(getattr(bp, "prismatic", ()))
    chi_final = bp.to_standard(res.chi, "zero")
    tau_sim = inverse_dynamics(robot, chi_final, last["q"], last["qd"], last["qdd"])
    hist = pd.DataFrame(history)
    t, n0 = L.t, L.n0
    return DIDIMResult(
        robot_name=robot.name, base=bp, result=res, essential=ess, history=hist,
        converged=converged, stop_reason=stop_reason, settings=L.s, initial=np.asarray(last['start']),
        kd_scale=last["kd"], t=t, q_sim=last["q"], qr=L.qr, tau=tau, tau_sim=tau_sim,
        tau_ddm=last["tau_ddm"], t_dec=t[n0:][last["idx"]], tau_dec=last["taud"],
        tau_est_dec=last["Wd"] @ res.chi, W_dec=last["Wd"], row_mask=last["mask"],
        transient_samples=n0, notices=notices, data_hash=h, source=str(experiment.source),
        joint_names=list(robot.joint_names), timings=timings, physical=last.get("physical"),
        gains=gains_cov, robot_signature=model_signature(robot),
        # without the run's progress callback (a closure): the result stays picklable
        _state=(dataclasses.replace(L, progress=None), last))


# ----------------------------------------------------------------------------- v_s from the data

def _parabola_vertex(f_lo, f_mid, f_hi):
    """Vertex of the parabola through three equally spaced points, in steps from the middle
    (clipped to half a step: a refinement between the grid's neighbours, not an extrapolation)."""
    curv = f_lo - 2.0 * f_mid + f_hi
    if not (math.isfinite(curv) and curv > 0):
        return 0.0
    return float(np.clip(0.5 * (f_lo - f_hi) / curv, -0.5, 0.5))


def _parabola_gain(f_lo, f_mid, f_hi, off):
    """How much lower than `f_mid` the parabola through three equally spaced points is at `off`
    steps from the middle (the vertex of `_parabola_vertex`); 0 when it does not curve upwards."""
    curv = f_lo - 2.0 * f_mid + f_hi
    if not (math.isfinite(curv) and curv > 0):
        return 0.0
    return float(-0.5 * off * (f_hi - f_lo) - 0.5 * off ** 2 * curv)


def _identify_auto_v_s(experiment, robot, *, settings, chi0, tol, max_iter, update_gains, essential,
                       progress, **kw):
    """DIDIM with the smooth-sign width `v_s` of the simulated Coulomb friction chosen from the data.

    `v_s` is a parameter of the simulated model like the others, but it enters the
    simulation nonlinearly, so it is chosen by the output-error criterion DIDIM itself
    minimises (section 3: `||Y - Y_s||`), profiled over the linear parameters: for each
    candidate, one Gauss-Newton step warm-started from the best estimate so far, and its
    least-squares residual `||rho||` (eq. (30)) as the candidate's score. The steps:

    1. DIDIM to convergence at `V_S_START` (0.05 rad/s, the former default), or, when it does
       not converge there, at `V_S_RETRY` (0.0125 rad/s) from the same start: a Coulomb
       friction far sharper than the smoothing can keep the iteration from settling (on
       simulated Pandas under a soft PD loop, 3 of the 9 runs that did not converge at 0.05
       converged at 0.0125); the walk then starts from there;
    2. a walk on the factor-2 grid from there, downwards first (halving `v_s`), upwards
       if the first halving does not help, for as long as `||rho||` falls by more than
       `tol` (tol_I: a smaller change is inside the noise, as for the stopping rule),
       within `[V_S_MIN, V_S_MAX]`;
    3. one candidate at the vertex of the parabola in `log v_s` through the best grid
       point and its two neighbours, unless the parabola predicts `||rho||` lower than the
       best grid point's by `tol` or less (the walk's rule; the residual is flat below the
       best width and steep above it, so the parabola over-predicts the fall);
    4. DIDIM at the best candidate's `v_s`, continuing the step that scored it (that step is
       the first of the final iteration, whose criterion compares the next step's `||rho||`
       with it): the width costs one simulation more, not two.

    Cost (benchmarks/didim_width.py): one closed-loop simulation per width, each warm-started
    from the best estimate so far, on the first run's loop (settings, thresholds and reference
    are not resolved again, no result object is built per width); the smaller widths need more
    RK4 substeps.

    Measured on the independent Pinocchio TX40 (`tests/support/independent_plant.py`, friction
    `tanh(qd / 0.01)`, development seeds): `||rho||` falls by a factor of 4-5 from 0.05 to
    0.0125 rad/s and is flat within ~10 % between 0.005 and 0.0125. The candidates cost one
    closed-loop simulation each, more substeps the smaller `v_s`
    (`dynid.dynamics.simulation.friction_stiffness`).
    """
    base = dict(settings or {})
    # PC-DIDIM: only the final run's PC fit is bootstrapped (the candidates are scored by ||rho||)
    n_boot = kw.pop("n_boot", 0)
    # so is the robust covariance (and the gains' share): the candidates need only the estimate
    final_cov = {"uncertainty": kw.pop("uncertainty", "classic"), "gains": kw.pop("gains", None)}

    def run(v, start, iters, ess, upd, prog=None, boot=0, cov=None):
        return identify_didim(experiment, robot, settings={**base, "v_s": v}, chi0=start, tol=tol,
                              max_iter=iters, update_gains=upd, essential=ess, progress=prog,
                              n_boot=boot, **(cov or {}), **kw)

    def part(a, b):
        return None if progress is None else (lambda f: progress(a + (b - a) * f))

    first = run(V_S_START, chi0, max_iter, False, update_gains, part(0.0, 0.5))
    pc_options = dict(prior=kw.get("prior"), prior_weight=kw.get("prior_weight", 1.0),
                      mass_tolerance=kw.get("mass_tolerance"))
    start = V_S_START
    if not first.converged:
        retry = run(V_S_RETRY, chi0, max_iter, False, update_gains)
        if not retry.converged:
            return _keep_start_width(first, robot, final_cov, n_boot, pc_options, essential,
                                     kw["max_error_growth"], bool(kw.get("physical")), retry)
        retry.notices.insert(0, f"DIDIM did not converge at the starting v_s = {V_S_START:g} rad/s "
                                f"({first.stop_reason}); it started again at {V_S_RETRY:g} rad/s")
        retry.settings["v_s_start_not_converged"] = first.stop_reason
        first, start = retry, V_S_RETRY
    # the later runs continue the first one: "initial" updated the gains for chi^0 only
    cont = False if update_gains == "initial" else update_gains
    L0 = first._state[0]
    physical = bool(kw.get("physical"))
    search = _WidthSearch(L0, first, cont, tol, physical, pc_options, progress, start)
    search.walk()
    refined = search.refine()
    chosen = search.best()
    final_run = dict(update_gains=cont, tol=tol, max_iter=max_iter, essential=essential, physical=physical,
                     pc_options=pc_options, n_boot=n_boot, max_error_growth=kw["max_error_growth"],
                     **final_cov)
    final, h2, t2 = _continue_at(experiment, L0, first, chosen, search.steps[chosen], search.scan[chosen][1],
                                 final_run, part(0.85, 1.0))
    if progress is not None:
        progress(1.0)
    return _with_width_choice(final, first, h2, t2, search, chosen, refined, update_gains)


def _keep_start_width(first, robot, final_cov, n_boot, pc_options, essential, max_error_growth, physical,
                      retry=None):
    """The first run, unconverged at `V_S_START` (and `retry`, at `V_S_RETRY`, too), finished as
    the result: the walk compares converged residuals, and from an unconverged estimate it
    would compare the iteration's progress, not the friction model. The robust covariance, the
    PC fit and the essential set the final run would have made are made here."""
    if final_cov["uncertainty"] != "classic" or final_cov["gains"] is not None:
        L, last = first._state
        last["res_classic"] = last["res"]
        last["res"] = first.result = _robust(L, last, final_cov["uncertainty"], final_cov["gains"], 300, 0)
        first.gains = final_cov["gains"]
        first.settings["uncertainty"] = (final_cov["uncertainty"]
                                         + ("+gains" if final_cov["gains"] is not None else ""))
    if physical and n_boot:
        first.physical = _pc_of(robot, first.base, first.result, (first._state[1] if first._state else {}).get("res_classic"), n_boot,
                                pc_options, first.settings.get("uncertainty", "classic"))
        _pc_errors(first.physical, first.result.chi, first.W_dec, first.tau_dec, first.row_mask)
    if essential:
        first.essential = essential_parameters(
            first.W_dec, first.tau_dec, list(first.base.names), ls.wls,
            max_error_growth=max_error_growth, row_mask=first.row_mask, settings=first.settings)
        if final_cov["uncertainty"] != "classic" or final_cov["gains"] is not None:
            first.essential = with_base_covariance(first.essential, first.result)
        for r in (first.essential.result, first.essential.base):
            r.data_hash, r.prismatic = first.data_hash, tuple(getattr(first.base, "prismatic", ()))
    again = "" if retry is None else f" nor at {V_S_RETRY:g} rad/s ({retry.stop_reason})"
    first.settings["v_s_choice"] = (f"auto, not searched: DIDIM did not converge at the "
                                    f"starting {V_S_START:g} rad/s{again}")
    first.notices.append(f"v_s was not chosen from the data: DIDIM did not converge at the "
                         f"starting v_s = {V_S_START:g} rad/s{again}; the result is the run at "
                         f"{V_S_START:g}")
    return first


def _next_estimate(last):
    """The estimate the next Gauss-Newton step simulates: PC-DIDIM continues from the physical
    one (the last step's unconstrained WLS can have M(q) indefinite and not be simulable)."""
    return last["res"].chi if last.get("physical") is None else last["physical"].chi


class _WidthSearch:
    """Steps 2 and 3 of `_identify_auto_v_s`: the factor-2 walk over v_s and the parabola.

    `scan`: width -> (||rho||, estimate, substeps); `steps`: width -> (history row, timings
    row, last) of the Gauss-Newton step that scored it, kept for the best width only, so that
    the final run continues it (one simulation less than a fresh start); `failed`: the
    widths whose step failed, with the reason."""

    def __init__(self, L0, first, cont, tol, physical, pc_options, progress, start=V_S_START):
        self.L0, self.cont, self.tol, self.start = L0, cont, tol, start
        self.physical, self.pc_options, self.progress = physical, pc_options, progress
        h1 = first.history
        self.scan = {start: (float(h1["rho_norm"].iloc[-1]), _next_estimate(first._state[1]),
                             int(h1["substeps"].iloc[-1]))}
        self.steps = {start: None}
        self.failed = []

    def best(self):
        return min(self.scan, key=lambda v: self.scan[v][0])

    def evaluate(self, v):
        """One Gauss-Newton step at width v from the best estimate so far (warm start): its ||rho||."""
        scan, steps = self.scan, self.steps
        try:
            Lv = _loop_at(self.L0, check_range("v_s", v), self.cont, 1)
            hist, tim, last, _, _ = _gauss_newton(Lv, scan[self.best()][1], self.tol, self.physical,
                                                  self.pc_options, [])
        except DynidError as exc:
            self.failed.append(f"v_s = {v:.3g}: {exc}")
            scan[v] = (math.inf, None, 0)
            return math.inf
        scan[v] = (float(hist[-1]["rho_norm"]), _next_estimate(last), int(hist[-1]["substeps"]))
        steps[v] = (hist[-1], tim[-1], last)
        for w in [w for w in steps if w != self.best() and steps[w] is not None]:
            steps[w] = None
        if self.progress is not None:   # the walk's length is not known ahead: each candidate closes part of the gap
            self.progress(0.5 + 0.35 * (1.0 - 0.6 ** (len(scan) - 1)))
        return scan[v][0]

    def walk(self):
        """Halve v_s from the start width while ||rho|| falls by more than tol_I (within
        V_S_MIN), else double it (within V_S_MAX) while it does."""
        for factor, bound in ((0.5, V_S_MIN), (2.0, V_S_MAX)):
            v = self.start
            while True:
                nxt = v * factor
                if (factor < 1 and nxt < bound * (1 - 1e-9)) or (factor > 1 and nxt > bound * (1 + 1e-9)):
                    break
                if self.evaluate(nxt) >= self.scan[v][0] * (1.0 - self.tol):
                    break
                v = nxt
            if v != self.start:
                break           # the downward walk helped: no need to look upwards

    def refine(self) -> str:
        """The parabola in log v_s through the best grid width and its two neighbours; its
        vertex is simulated unless the gain it predicts is within tol_I. What was done, as text."""
        scan = self.scan
        b = self.best()
        lo, hi = b / 2.0, b * 2.0
        if not (lo in scan and hi in scan):
            return ""
        off = _parabola_vertex(scan[lo][0], scan[b][0], scan[hi][0])
        gain = _parabola_gain(scan[lo][0], scan[b][0], scan[hi][0], off)
        v = b * 2.0 ** off
        if abs(off) > 0.05 and gain > self.tol * scan[b][0]:
            self.evaluate(v)
            return f"; parabola in log v_s through {lo:.3g}, {b:.3g}, {hi:.3g} rad/s gave {v:.3g}"
        if abs(off) > 0.05:
            # the walk's own rule: a change of ||rho|| below tol_I is inside the noise. Measured
            # (seed 5 of benchmarks/didim_width.py, tests/analysis/estimators/test_didim.py) the
            # parabola over-predicts the gain (the residual is flat below the best width and steep
            # above it), so a vertex predicted inside the noise does not win either
            return (f"; parabola in log v_s through {lo:.3g}, {b:.3g}, {hi:.3g} rad/s: its vertex "
                    f"{v:.3g} predicted ||rho|| lower by {100 * gain / scan[b][0]:.2g} % <= tol_I, "
                    "not simulated")
        return ""


def _with_width_choice(final, first, h2, t2, search, chosen, refined, update_gains):
    """The final run's result with the width search recorded: settings `v_s_choice` and
    `v_s_scan`, a notice with every width's ||rho||, both runs' history and timings."""
    scan = search.scan
    rows = [{"v_s": float(v), "rho_norm": scan[v][0], "substeps": scan[v][2]} for v in sorted(scan)]
    at_edge = chosen <= V_S_MIN * (1 + 1e-9) or chosen >= V_S_MAX * (1 - 1e-9)
    how = (f"auto: smallest DIDIM residual ||rho|| over {len(rows)} candidate(s) "
           f"({V_S_MIN:.3g}-{V_S_MAX:.3g} rad/s, factor-2 walk from {search.start:g}{refined})")
    note = (f"v_s (the simulated Coulomb friction's smooth-sign width) chosen from the data: "
            f"{chosen:.3g} rad/s, ||rho|| {scan[chosen][0]:.4g} against {scan[search.start][0]:.4g} at "
            f"{search.start:g} (" + ", ".join(f"{r['v_s']:.3g}: {r['rho_norm']:.4g}" for r in rows) + ")"
            + ("; at the end of the range searched: the friction may be sharper (or smoother) still"
               if at_edge else ""))
    s = dict(final.settings)
    s["v_s_choice"] = how
    s["v_s_scan"] = rows
    s["initialisation"] = first.settings.get("initialisation")
    s["update_gains"] = update_gains
    notices = list(first.notices) + [note] + [f"v_s candidate failed ({f})" for f in search.failed]
    notices += [n for n in final.notices if n not in notices]
    final.history = pd.concat([first.history, pd.DataFrame(h2)], ignore_index=True)
    final.settings = s
    final.notices = notices
    final.initial = first.initial
    final.timings = list(first.timings) + t2
    final.stop_reason = f"at v_s = {chosen:.3g} rad/s: {final.stop_reason}"
    return final


def _continue_at(experiment, L0, first, v, step, start, final_run, progress):
    """DIDIM at the chosen width `v` to convergence, continuing the step that scored it.

    `step` = (history row, timings row, last) of the candidate's Gauss-Newton step at `v`, which
    started from the best estimate at another width; its estimate `start` is the one the next
    step simulates, so the iteration goes on from there (step `n1 + 1` of the whole history) and
    its criterion compares the next step's ||rho|| with the candidate's, as any DIDIM step does
    with the previous one. At the start width the first run's last step is continued (`step` None).
    `final_run`: the run's options (update_gains, tol, max_iter, essential, physical, pc_options,
    n_boot, max_error_growth, uncertainty, gains). Returns (DIDIMResult of the final steps, their
    history rows, their timings), the steps numbered as steps of the whole history.
    """
    o = final_run
    n1 = len(first.history)
    unc = o["uncertainty"] + ("+gains" if o["gains"] is not None else "")
    Lf = _loop_at(L0, v, o["update_gains"], o["max_iter"], progress, uncertainty=unc)
    if step is None:
        row, last, rows, timings = first.history.iloc[-1].to_dict(), first._state[1], [], []
        k = n1 + 1
    else:
        row, trow, last = step
        rows = [dict(row, iteration=n1 + 1)]
        timings = [dict(trow, iteration=n1 + 1)]
        k = n1 + 2
    # the run continues the one above at the chosen width: with "initial" gain updates, that one
    # simulated chi^0 with the updated gains, and this one goes on with the actual ones
    notices = [_loop_notice(Lf.s, Lf.n0, o["update_gains"], continued_at=v)]
    resume = dict(k=k, last=last, rho=float(row["rho_norm"]), out_err=float(row["output_error"]), beta_ls=start)
    history, tim, last, converged, stop_reason = _gauss_newton(Lf, start, o["tol"], o["physical"],
                                                               o["pc_options"], notices, resume=resume)
    rows += history
    timings += tim
    notices += _convergence_notices(rows, converged, stop_reason)
    tau = np.ascontiguousarray(experiment.tau, dtype=float)
    res = _didim_result(Lf, experiment, start, tau, rows, timings, last, converged, stop_reason, notices,
                        essential=o["essential"], max_error_growth=o["max_error_growth"],
                        physical=o["physical"], n_boot=o["n_boot"], pc_options=o["pc_options"],
                        uncertainty=o["uncertainty"], gains_cov=o["gains"])
    return res, rows, timings


def _pc_errors(pc, chi_wls, Wd, taud, mask) -> None:
    """Set the PC fit `pc`'s relative errors ||Y - W beta|| / ||Y|| (its own and the last step's
    WLS `chi_wls`'s) on the last step's system, as IDIM's PC fit reports them; None: nothing."""
    if pc is None:
        return
    norm = _masked_norm(taud, mask)
    for attr, chi in (("rel_error", pc.chi), ("wls_rel_error", chi_wls)):
        err = _masked_norm(taud - Wd @ np.asarray(chi, float), mask)
        setattr(pc, attr, err / norm if norm > 0 else math.nan)


def _pc_of(robot, bp, res, res_classic, n_boot, pc_options, uncertainty):
    """The PC fit of DIDIM's estimate, as IDIM's: the metric is eq. (14)'s covariance (so the
    estimate does not depend on the covariance option), the intervals are the reported one's."""
    metric = res.cov if res_classic is None else res_classic.cov
    return pc_wls(robot, bp, res.chi, metric, n_boot=n_boot, interval_cov=res.cov, uncertainty=uncertainty,
                  **pc_options)
