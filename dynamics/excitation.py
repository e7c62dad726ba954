"""Optimal excitation: Fourier coefficients that minimise cond(W) (Bona & Curatella 2005).

Eq. (20) of Bona & Curatella 2005 (after Presse & Gautier 1993 and Swevers et
al. 1997): choose, for every joint `i`, the `2 N + 1` parameters
`delta_i = [a_i(1..N), b_i(1..N), q_i0]` of the finite Fourier series of
eqs. (17)-(19) (`dynid.dynamics.trajectories.FourierTrajectory`) so that the
base regressor `W` stacked over one period is as well conditioned as the
limits allow::

    delta = argmin cond(W(q(t), qd(t), qdd(t)))
    s.t.  |q - q_mid| <= margin (q_max - q_min) / 2,  |qd| <= margin qd_max,
          |qdd| <= margin qdd_max,  |tau(q, qd, qdd; chi)| <= margin tau_max

The fundamental `f0` and the number of harmonics `N` are *given*: they fix
the period (`1 / f0`, a whole number of periods avoids leakage and allows
period averaging, section 2.3) and the bandwidth `N f0` (kept below the first
resonance, section 3.3: 0.1 Hz and 5 harmonics on the COMAU Smart-3 S2).

Which condition number
----------------------
`cond(W)` in SI units (`cond_raw`) depends on the units of the parameters
(kg m^2 vs g mm^2 changes it by orders of magnitude) and is dominated by the
ratio of the largest to the smallest column norm. dynid therefore reports and,
by default, minimises the condition number of `W S^-1` where `S` is a
*fixed* diagonal of column scales (`scaling="envelope"`): the RMS of each
base-regressor column over random states drawn uniformly inside the robot's
limit box (`q` in its range, `|qd| <= qd_max`, `|qdd| <= qdd_max`; a fixed
seed, so `S` depends on the robot only). That is the regressor in units where
every parameter contributes O(1) torque at full-range motion: the number is
independent of the parameters' units, and still rewards a trajectory that
excites a weak column more (unlike the column-normalised `cond_unit`, where
every column of `W` is scaled to unit norm *for that trajectory*, a pure
collinearity measure, also reported). `scaling="none"` reproduces the paper's
`kappa(Phi)` in SI units, `"columns"` optimises `cond_unit`. A-priori
magnitudes were not used as scales: most base parameters (36 of the TX40's 60)
have no a-priori value. With `criterion="logdet"` (D-optimality, Swevers
1997) `-log det(W_s^T W_s) / b` is minimised instead; it does not depend on the
column scales (they add a constant) and the three condition numbers are still
reported.

`W` is sampled on `samples_per_harmonic` (default 20) points per period of
the highest harmonic, uniformly over one period (`20 N` samples; 100 for
`N = 5`). Every condition number reported is computed on that grid.

Constraints and their check
---------------------------
Positions, velocities and accelerations are linear in `delta`: the limits
are imposed as linear inequalities on `n_constraint` points per period
(default `max(200, 40 N)`), tightened by the factor `1 - (pi N / m)^2 / 2`.
For `qd` and `qdd` (trigonometric polynomials of degree `N` without a
constant) that is Bernstein's bound, so those limits hold at every time, not
only on the grid; for `q` (whose constant `q0` is free) it is the same
tightening without that guarantee. Torques are computed with a-priori
parameters (`chi`; default the robot's `[apriori]` values mapped to base
parameters, unknown ones zero, see `apriori_parameters`) by the compiled
inverse dynamics and imposed on the same grid with the same tightening; the
torque is not band-limited (Coulomb friction jumps), so between grid points it
can exceed `margin tau_max` by a fraction of a percent (0.3 % seen with tight
TX40 torque limits) -- never the limit itself, which the dense check enforces. Every candidate is then checked
against the *actual* limits on a dense grid (`n_check`, default 20 000
points per period, offset by half a step, torque included):
`ExcitationResult.margins`; a candidate that fails the check is
discarded. `margin` (default 0.95) leaves 5 % of every limit for the
tracking error of the controller and for the a-priori torque model's error.

Optimiser
---------
SLSQP (scipy) on variables normalised by the velocity limits and the joint
half-ranges, from `n_starts` random feasible starts
(`dynid.dynamics.trajectories.random_fourier_trajectory` with the same
`margin`; a start whose torque is out of bounds is shrunk towards `q0`);
the best feasible result is kept. The objective is `log cond` (half the log
of the ratio of the extreme eigenvalues of `W_s^T W_s`). Gradients are
analytic in the Fourier basis (chain rule through `q, qd, qdd`) with the
partial derivatives of the regressor with respect to `q_j`, `qd_j`,
`qdd_j` taken by finite differences of the compiled regressor, all samples
at once (`5 n + 1` regressor evaluations of the grid per gradient instead of
`n (2 N + 1)`; line-search points cost one evaluation). The velocity
difference is one-sided away from zero, so the Coulomb `sign(qd)` column
never jumps inside a difference. SLSQP can end on an infeasible point
("Inequality constraints incompatible"); the best grid-feasible iterate seen
is kept instead.

What to expect
--------------
`cond` is not smooth where the extreme singular values cross, and SLSQP
stops at such a kink. On the TX40 (f0 = 0.1 Hz, 5 harmonics, margin 0.95; 4
starts, 5-10 s) the design reaches an envelope-scaled cond of 8.3-9.2 (seeds
0-3), a floor set by the bandwidth: at 0.5 Hz the accelerations cannot exceed
about `2 pi N f0 qd_max`, a third of `qdd_max`, so the inertia columns stay
weak next to the friction columns (an epigraph formulation constraining the 20
smallest eigenvalues reached 8.8-9.0 at ten times the cost; 8 starts give
8.4-9.1). Random feasible trajectories of the same class have envelope-scaled
cond 31-170, median 54 (200 draws): the design is about 6x better than a
typical (median) random trajectory, 3.4-3.8x better than the best of those 200
draws, and 4-6x better than the best of its own starts. The unit-column cond
drops from ~9 to ~5.7; the raw SI cond, not optimised, *rises* (110-170 to
250-320): it is dominated by unit-dependent column magnitudes.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from dynid.errors import InputError
from dynid.outputs import atomic_write_text
from dynid.provenance import dumps_json, json_safe
from dynid.ranges import check_range

from .base_parameters import base_parameters
from .blas_threads import limit_blas_threads
from .excitation_measures import (
    DEFAULT_N_CHECK,
    DEFAULT_SAMPLES_PER_HARMONIC,
    SCALINGS,
    apriori_parameters,
    column_scales,
    limit_margins,
    regressor_conditioning,
    spectrum_check,
    within_limits,
)
from .excitation_problem import ExcitationProblem, shrink_to_torque
from .trajectories import FourierTrajectory, _rng, check_f0, check_harmonics, random_fourier_trajectory

# the measures, the problem and the BLAS limit live in their own modules (one concept each);
# their public names stay importable from here, where they were first published
__all__ = ["ExcitationResult", "design_excitation", "limit_blas_threads", "apriori_parameters", "column_scales",
           "regressor_conditioning", "limit_margins", "spectrum_check", "SCALINGS", "CRITERIA"]

CRITERIA = ("cond", "logdet")


# ----------------------------------------------------------------------------- result
@dataclass
class ExcitationResult:
    """An optimised excitation trajectory and the evidence that it is one.

    `cond_result` / `cond_start`: the reported condition number (see
    `cond_name`: `cond` = envelope-scaled W unless `scaling` says otherwise)
    of the result and of the best random start (the lowest of `cond_starts`).
    `conditioning` / `start_conditioning`: all the variants (raw, scaled,
    unit columns, log det) for the result and that best start. `margins`:
    `limit_margins` of the result on the dense grid; `spectrum`:
    `spectrum_check`. `runs`: one dict per start (start and final cond,
    iterations, time, optimiser message, feasible).
    """

    trajectory: FourierTrajectory
    robot_name: str
    joint_names: list
    criterion: str
    scaling: str
    margin: float
    cond_name: str
    cond_result: float
    cond_start: float
    cond_starts: list
    conditioning: dict
    start_conditioning: dict
    start_trajectory: FourierTrajectory
    margins: object                      # pandas DataFrame
    start_margins: object
    spectrum: dict
    runs: list
    n_samples: int
    n_check: int
    torque_parameters: str
    elapsed: float
    notices: list = field(default_factory=list)

    @property
    def f0(self):
        return self.trajectory.f0

    @property
    def harmonics(self):
        return self.trajectory.harmonics

    @property
    def improvement(self):
        """cond_start / cond_result (> 1 when the optimisation helped)."""
        return self.cond_start / self.cond_result

    def improvement_text(self) -> str:
        """The design's cond against the best random start's, in words.

        Returns
        -------
        str
            `"x2.76 lower"` or `"x1.29 higher"`, and, for another criterion than cond, that cond
            is not what the design optimised.
        """
        text = (f"x{self.improvement:.2f} lower" if self.improvement >= 1 else
                f"x{1 / self.improvement:.2f} higher")
        if self.criterion != "cond":
            text += f"; the design optimised {self.criterion}, not cond, which a random start can beat"
        return text

    def torque_text(self) -> str:
        """What the torque limits were checked with, or why they were not.

        Returns
        -------
        str
            `"torque with the robot's a-priori values"`, or the reason there was no check.
        """
        return (self.torque_parameters if self.torque_parameters.startswith("no ") else
                f"torque with {self.torque_parameters}")

    @property
    def feasible(self):
        return within_limits(self.margins)

    def __repr__(self):
        return (f"<ExcitationResult robot {self.robot_name!r}: f0 {self.f0:g} Hz, {self.harmonics} harmonics, "
                f"cond {self.cond_result:.4g} (best start {self.cond_start:.4g})"
                f"{'' if self.feasible else ', NOT within the limits'}>")

    def to_frame(self, fs=None, n_periods=1):
        """Reference `t, qr1..n, qdr1..n, qddr1..n` at the controller rate `fs` (Hz, required).

        `n_periods` whole periods, `round(n_periods fs / f0)` samples from t = 0
        (the end point, equal to the start, is not repeated).

        Returns
        -------
        pandas.DataFrame
            One row per sample.
        """
        if fs is None:
            raise InputError("ExcitationResult.to_frame needs fs, the controller rate in Hz at which the "
                             "reference is sampled (for example to_frame(fs=5000.0))")
        fs = float(fs)
        if not np.isfinite(fs) or fs <= 0:
            raise InputError(f"fs must be a positive sampling rate in Hz, got {fs!r}")
        m = int(round(n_periods * fs * self.trajectory.period))
        t = np.arange(m) / fs
        return self.trajectory.to_frame(t)

    def to_csv(self, path=None, fs=None, n_periods=1) -> str:
        """`to_frame(fs, n_periods)` as CSV (full precision), written atomically to `path` when
        given (all or nothing). `fs` (Hz), the controller rate the reference is written at, is
        required.

        Returns
        -------
        str
            The CSV text.
        """
        if fs is None:
            raise InputError("ExcitationResult.to_csv needs fs, the controller rate in Hz at which the "
                             "reference is written (for example to_csv(path, fs=5000.0))")
        text = self.to_frame(fs, n_periods).to_csv(index=False, lineterminator="\n", float_format="%.17g")
        if path is not None:
            atomic_write_text(path, text)
        return text

    def to_json(self, path=None) -> str:
        """`to_dict` as JSON, written atomically to `path` when given (all or nothing).

        Returns
        -------
        str
            The JSON text.
        """
        text = dumps_json(self.to_dict())
        if path is not None:
            atomic_write_text(path, text)
        return text

    def to_dict(self):
        tr = self.trajectory
        return json_safe({
            "robot": self.robot_name, "f0": tr.f0, "harmonics": tr.harmonics,
            "period": tr.period, "bandwidth": tr.bandwidth,
            "a": tr.a, "b": tr.b, "q0": tr.q0,
            "criterion": self.criterion, "scaling": self.scaling, "margin": self.margin,
            "cond_name": self.cond_name, "cond_result": self.cond_result,
            "cond_start": self.cond_start, "cond_starts": list(self.cond_starts),
            "improvement": self.improvement,
            "conditioning": self.conditioning, "start_conditioning": self.start_conditioning,
            "margins": {str(k): v for k, v in self.margins.to_dict(orient="index").items()},
            "feasible": self.feasible,
            "spectrum": {"lines_hz": self.spectrum["lines"], "off_grid": self.spectrum["off_grid"],
                         "bandwidth_hz": self.spectrum["bandwidth"], "ok": self.spectrum["ok"]},
            "runs": self.runs, "n_samples": self.n_samples, "n_check": self.n_check,
            "torque_parameters": self.torque_parameters, "elapsed_s": self.elapsed,
            "notices": self.notices,
        })

    def summary(self):
        tr = self.trajectory
        c, cs = self.conditioning, self.start_conditioning
        lines = [
            f"Excitation of {self.robot_name}: f0 = {tr.f0:g} Hz, {tr.harmonics} harmonics "
            f"(period {tr.period:g} s, bandwidth {tr.bandwidth:g} Hz), criterion {self.criterion}, "
            f"scaling {self.scaling}, margin {self.margin:g}",
            f"  {self.cond_name}: {self.cond_result:.4g} (best of {len(self.cond_starts)} random "
            f"starts {self.cond_start:.4g}; {self.improvement_text()})",
            f"  cond envelope-scaled {c['cond']:.4g} (start {cs['cond']:.4g}), raw SI {c['cond_raw']:.4g} "
            f"(start {cs['cond_raw']:.4g}), unit columns {c['cond_unit']:.4g} (start {cs['cond_unit']:.4g}); "
            f"computed on {self.n_samples} samples per period (the CSV holds the controller rate)",
            f"  limits on {self.n_check} points per period: {'all respected' if self.feasible else 'VIOLATED'}"
            + f" ({self.torque_text()})",
            "  joint   q_low  q_high     qd    qdd    tau   (relative margin to each limit)",
        ]
        for name, row in self.margins.iterrows():
            vals = [row.get(k, np.nan) for k in ("q_low", "q_high", "qd", "qdd", "tau")]
            lines.append(f"  {name:>5} " + " ".join(f"{v:6.3f}" if np.isfinite(v) else "     -"
                                                     for v in vals))
        sp = self.spectrum
        lines.append(f"  spectrum: lines at {', '.join(f'{f:g}' for f in sp['lines'])} Hz; "
                     f"off-grid {sp['off_grid']:.2e}; {'ok' if sp['ok'] else 'NOT band-limited'}")
        lines.append(f"  designed in {self.elapsed:.1f} s")
        lines += [f"  note: {m}" for m in self.notices]
        return "\n".join(lines)


# ----------------------------------------------------------------------------- design
#: a design whose (scaled) condition number is above this is rank-deficient, not poor: the
#: optimised designs of the module docstring reach 8-9 and random ones 31-170
MAX_COND = 1e8
#: rad (or m): an excitation whose every joint moves less than this within one period is pinned by
#: the limits (a high f0), not short of harmonics
SMALL_SPAN = 0.05


def design_excitation(robot, f0, n_harmonics, *, n_starts=4, criterion="cond", chi=None, rng=None,
                      max_iter=150, margin=0.95, scaling="envelope",
                      samples_per_harmonic=DEFAULT_SAMPLES_PER_HARMONIC, n_constraint=None,
                      n_check=DEFAULT_N_CHECK, bp=None, ftol=1e-7, blas_threads=1,
                      progress=None) -> ExcitationResult:
    """Optimise a Fourier excitation (eq. (20)) of `robot`; see the module docstring.

    `chi`: standard parameters for the torque limits (default
    `apriori_parameters`); `chi=False` ignores the torque limits.
    `rng`: Generator or seed of the random starts. `max_iter`: SLSQP
    iterations per start. `blas_threads`: OpenBLAS threads during the design
    (default 1, see `limit_blas_threads`; None leaves them alone).
    `progress(fraction)` is called after each start.
    """
    with limit_blas_threads(blas_threads):
        return _design(robot, f0, n_harmonics, n_starts=n_starts, criterion=criterion, chi=chi,
                       rng=rng, max_iter=max_iter, margin=margin, scaling=scaling,
                       samples_per_harmonic=samples_per_harmonic, n_constraint=n_constraint,
                       n_check=n_check, bp=bp, ftol=ftol, progress=progress)


def _design(robot, f0, n_harmonics, *, n_starts, criterion, chi, rng, max_iter, margin, scaling,
            samples_per_harmonic, n_constraint, n_check, bp, ftol, progress=None):
    t_start = time.perf_counter()
    f0 = check_f0(f0)
    N = check_harmonics(n_harmonics)
    if criterion not in CRITERIA:
        raise InputError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    if scaling not in SCALINGS:
        raise InputError(f"scaling must be one of {', '.join(SCALINGS)}, got {scaling!r}")
    margin = float(margin)
    if not 0 < margin <= 1:
        raise InputError(f"margin must be in (0, 1], got {margin!r}")
    n_starts = check_range("n_starts", n_starts)        # --starts 1e9 would run for ever
    rng = _rng(rng)
    bp = base_parameters(robot) if bp is None else bp
    notices = []
    if chi is None:
        chi_st, _, missing = apriori_parameters(robot, bp)
        torque_src = "the robot's a-priori values"
        if len(missing) >= bp.n_base:
            # a torque of zero everywhere would pass any limit: the check would say nothing
            chi_st, torque_src = None, "no torque check: the robot file has no a-priori values"
            notices.append(f"torque limits not checked: robot '{robot.name}' has no a-priori parameter values "
                           "(add an [apriori] table to its robot file, or pass chi= the parameters to check with)")
        elif missing:
            torque_src += f" ({len(missing)} of {bp.n_base} base parameters without one, taken as 0)"
    elif chi is False:
        chi_st, torque_src = None, "no torque limits"
        notices.append("torque limits ignored (chi=False)")
    else:
        chi_st = np.asarray(chi, dtype=float)
        if chi_st.shape == (bp.n_base,):
            chi_st = bp.to_standard(chi_st)
        if chi_st.shape != (robot.n_standard,):
            raise InputError(f"chi must hold {robot.n_standard} standard or {bp.n_base} base "
                             f"parameters of '{robot.name}', got shape {chi_st.shape}")
        torque_src = "the given parameters"
    if n_constraint is None:
        n_constraint = max(200, 40 * N)
    prob = ExcitationProblem(robot, bp, f0, N, chi_st, criterion, scaling, margin, samples_per_harmonic,
                    n_constraint)
    cond_key = {"envelope": "cond", "none": "cond_raw", "columns": "cond_unit"}[scaling]
    cond_name = {"cond": "cond(W S^-1), envelope column scales",
                 "cond_raw": "cond(W), SI units", "cond_unit": "cond(W), unit-norm columns"}[cond_key]

    def conditioning(tr):
        return regressor_conditioning(robot, bp, tr, samples_per_harmonic=samples_per_harmonic,
                                      scales=prob.scales)

    runs, candidates, starts = [], [], []
    for k in range(n_starts):
        t0 = time.perf_counter()
        start = random_fourier_trajectory(robot, f0, N, rng, margin=margin)
        start, shrink = shrink_to_torque(prob, start)
        c_start = conditioning(start)
        starts.append((c_start[cond_key], start, c_start))
        z0 = prob.to_x(start) / prob.xs
        z, fbest, res = prob.optimise(z0, max_iter, ftol)
        tr = prob.to_traj(z * prob.xs)
        c_end = conditioning(tr)
        marg = limit_margins(robot, tr, chi_st, n_check=n_check)
        ok = within_limits(marg)
        runs.append({"start": k, "cond_start": c_start[cond_key], "cond_result": c_end[cond_key],
                     "criterion_value": float(fbest), "iterations": int(res.nit),
                     "evaluations": int(res.nfev), "message": str(res.message),
                     "start_shrink": shrink, "feasible": ok,
                     "seconds": time.perf_counter() - t0})
        if ok:
            key = c_end[cond_key] if criterion == "cond" else float(fbest)
            candidates.append((key, tr, c_end, marg))
        if progress is not None:
            progress((k + 1) / n_starts)
    best_start = min(starts, key=lambda s: s[0])
    if candidates:
        _, traj, c_res, marg = min(candidates, key=lambda c: c[0])
    else:
        notices.append("no optimised trajectory passed the dense limit check; the best random "
                       "start is returned")
        traj, c_res = best_start[1], best_start[2]
        marg = limit_margins(robot, traj, chi_st, n_check=n_check)
    if not c_res[cond_key] <= MAX_COND:
        span = np.ptp(traj.evaluate(np.linspace(0.0, 1.0 / f0, 400))[0], axis=0)
        why = (f"its {N} harmonic(s) per joint cannot move the {bp.n_base} base parameters' columns "
               f"independently, and no recording along it could identify them; raise the harmonics "
               f"(--harmonics, n_harmonics=)")
        if float(np.max(span)) < SMALL_SPAN:
            # at a high f0 the speed and acceleration limits leave no room: more harmonics would not help
            why = (f"within the robot file's speed and acceleration limits (qd_max, qdd_max) the joints move "
                   f"over {float(np.max(span)):.2g} rad at most at this f0, too little to separate the "
                   f"{bp.n_base} base parameters; lower f0 (--f0, f0=), or check those limits")
        raise InputError(f"robot {robot.name}: the best excitation of {N} harmonic(s) at f0 = {f0:g} Hz leaves "
                         f"the regressor rank-deficient (cond {c_res[cond_key]:.2g}): {why}")
    return ExcitationResult(
        trajectory=traj, robot_name=robot.name, joint_names=list(robot.joint_names),
        criterion=criterion, scaling=scaling, margin=margin, cond_name=cond_name,
        cond_result=c_res[cond_key], cond_start=best_start[0],
        cond_starts=[s[0] for s in starts], conditioning=c_res, start_conditioning=best_start[2],
        start_trajectory=best_start[1], margins=marg,
        start_margins=limit_margins(robot, best_start[1], chi_st, n_check=n_check),
        spectrum=spectrum_check(traj), runs=runs, n_samples=prob.G, n_check=int(n_check),
        torque_parameters=torque_src, elapsed=time.perf_counter() - t_start, notices=notices)
