"""DIDIM: identification from the joint torques and the reference only (section 3).

Gautier, Janot, Vandanjon (2010), *Dynamic identification of a 6 dof
industrial robot without joint position data*, section 3. DIDIM is a
closed-loop output-error method: the robot is simulated in closed loop under
the same control law and with the same reference as the actual robot, and the
parameters minimise ``||Y(tau) - Y_s(tau_ddm)||``. The Gauss-Newton step is
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

So ``k`` counts least-squares solves ("steps"). The paper's TX40 needs 1 step
for the optimum and a second one to see that the residual no longer changes
(Table 2 is "after 2 steps"). The result reports the estimate of the last
step, with the statistics of its WLS (eqs. (13)-(16)); optionally the
essential parameters (Pham & Gautier) by the same backward elimination as
IDIM, on the last step's W.

Documented choices (all in ``DIDIMResult.settings``, all overridable through
``settings=``):

* **Initialisation** (eqs. (31)-(32)): chi^0 = 0 except ``Ia_j = 1``. A motor
  ``m`` coupled with joints ``k != m`` with coefficients ``c`` (rotor speed
  ``sum c_k qd_k``) adds ``Ia_m c_k c_l / c_m^2`` off the diagonal of M; dynid
  absorbs its diagonal share ``(c_k / c_m)^2 Ia_m`` into ``Ia_k``. So joint
  ``k`` gets ``Ia_k = 1 + (c_k / c_m)^2``: the rotor of ``k`` keeps a unit
  inertia of its own and the coupled rotor adds the positive semi-definite
  ``c c^T / c_m^2``, so ``M(q, chi^0) = I + c c^T / c_m^2`` (restricted to the
  coupled joints) is positive definite. With ``Ia_k = 1`` instead the TX40
  wrist block would be ``[[1, 1], [1, 1]]``, singular. For the TX40
  (``c = (1, 1)``, motor 6) this gives the paper's ``Ia5 = 2`` and the wrist
  block ``[[2, 1], [1, 1]]`` (eigenvalues 0.38 and 2.62); all other joints see
  ``M = I``.
* **Gain update** (section 3.2): before simulating with chi^{k-1}, ``kd_scale_j
  = J_j / J_ap_j`` with ``J_j = max_q M_jj(q, chi^{k-1})`` (eq. (27) with dynid's
  M, which already contains ``ZZ_j + Ia_j``), the maximum taken over the
  configurations of the previous simulation (of the reference ``qr`` for the
  first one), sampled every ``1 / j_rate`` s. ``update_gains=False`` keeps
  ``kd_scale = 1`` (the actual controller's gains, unchanged).
* **Initial state and transient**: the simulation starts at ``(qr(0),
  qdr(0))``; the first ``transient`` seconds (default ``5 / min(wn)``, the
  text after eq. (32)) are dropped from the identification data.
* **Simulation**: the robot's controller (``robot.controller`` or
  ``controller=``) with velocity feedforward by default (``feedforward``, as
  :mod:`analysis.synthetic` records its data), no torque saturation for the
  simulated robot (``saturate=False``: the initial robot ``M = I`` needs far more
  torque than the real one; the actual drive's limits say nothing about it),
  Coulomb friction smoothed over ``v_s = 0.05`` rad/s, and as many RK4
  substeps as keep ``h * lambda_friction <= 1.5`` (``substeps="auto"``). The
  reference velocity is the second-order finite difference of ``qr``.
* **Decimation and dead zone**: ``nd`` and the low-pass cut-off as IDIM
  derives them from the data (:func:`analysis.signals.default_settings` on
  ``qr``; the paper's 100 and 20 Hz at 5 kHz); the velocity dead zone of
  :mod:`analysis.observation` (``qd_threshold``, default ``"auto"`` = 1 % of
  each joint's peak *reference* speed, so the thresholds stay fixed over the
  iterations) applied to the simulated velocities, widened by
  ``dead_zone_guard`` s on each side (default 5 ms: the simulated and the
  actual velocity cross zero at slightly different times).
* ``fc_position``, ``order`` and ``edge`` (IDIM's position filter) do not
  apply: the simulated derivatives are exact. They are accepted and ignored
  with a notice so that IDIM's processing settings can be passed as they are.

Convergence: ``converged`` is True only when the criterion was met within
``max_iter`` steps; otherwise (or when a simulation fails) the result says
why in ``stop_reason`` and never pretends to have converged (the command line
maps that to exit code 3).
"""
from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from analysis import least_squares as ls
from analysis.decimation import ParallelDecimator
from analysis.essential import essential_parameters
from analysis.observation import _dead_zone
from analysis.provenance import atomic_write_text, dumps_json, json_safe, versions
from analysis.signals import default_settings
from dynamics.base_parameters import base_parameters, base_regressor
from dynamics.dynamic_model import inverse_dynamics, mass_matrix
from dynamics.simulation import friction_stiffness, simulate_closed_loop
from dynamics.errors import DataError, DynidError, IdentificationError, InputError

__all__ = ["identify_didim", "DIDIMResult", "initial_parameters", "DIDIM_SETTINGS_HELP",
           "resolve_didim_settings"]
