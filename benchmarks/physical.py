"""Benchmark and acceptance figures of PC-WLS (analysis/estimators/physical.py), real data.

* One SDP solve (cvxpy + Clarabel) for the TX40 (86 standard parameters,
  ``examples/staubli_tx40``) and the KUKA LWR4+ (98, recordings 2 + 3 of
  ``examples/kuka_lwr4``), timed beside the unconstrained WLS of the same
  observation system in the same run: ``solve_s`` is the solver's call,
  ``total_s`` adds building the problem (cvxpy's compilation), the goal is
  under 2 s per solve.
* LWR4+ held-out relative error ||tau - tau_hat|| / ||tau|| over all
  decimated samples (``dynid.validate``): identified on 2 + 3, validated on 1,
  and FloBaRoID's split 1 -> 2; PC-WLS beside the unconstrained WLS of all
  base parameters and the IDIM essential model (the bar of issue 15: PC no
  more than 0.2 points above the unconstrained fit, every link consistent;
  FloBaRoID's published held-out error on 1 -> 2 is 2.81 %).
* What each constraint family costs on the held-out recording (chi2, error, per-joint RMS)
  and the held-out error with the a-priori prior at a few weights. Measured (2026-12-02):
  with the robot file's mass bounds (+-50 %, FloBaRoID's) and the pseudo-inertias alone, PC
  is +0.095 points (2+3 -> 1) and +0.061 (1 -> 2) above the unconstrained WLS, within the
  bar; Ia >= 0 brings it to +0.22 / +0.31, Fv >= 0 adds the rest (+0.29 / +0.36 in all).
  The data want Ia3 = -1.7 (9 sigma), Ia7 = -0.29 (10 sigma) and Fv2 = -1.8 (12 sigma):
  a negative inertia on the joint's own acceleration and a negative viscous friction are
  no rigid-body or friction effect. The LWR4+'s link-side torque sensors see no rotor
  inertia at all, but the model without Ia (``link_side_model``: unconstrained 2.120 %, PC
  2.430 % on 2+3 -> 1) has the same gap. Neither the recording script's 2 Hz torque filter
  applied to the regressor (measured outside this script: WLS 2.05 %, PC 2.33 %) nor the
  a-priori prior (worse at every weight) closes it. The gap is an unmodelled effect on
  the data (for the residual diagnosis), not a cost of the SDP; the mass bounds cost
  0.002 points and keep the masses real (<= 4.05 kg instead of 557 and 1313 kg).
* The same with effect columns (``effects_model``, ``dynid.analysis.diagnosis.physical_fit``):
  the unconstrained WLS and the PC-WLS of one model, the rigid body plus a linear spring
  ``Ks_j q_j`` on every joint (and variants with the first position harmonic of joint 7), so
  the gap is measured between two fits of the same model. Measured (2026-12-02): springs on
  every joint take the negative ZZ1R/Ia3 the unconstrained fit wanted on 2 + 3 (ZZ1R
  -3.0 -> +1.6, Ia3 -1.74 -> +1.02), the PC cost on the identification data falls from chi2
  1562 to 883 (2 + 3) and 2802 to 804 (1), and the held-out gap from +0.289 / +0.358 to
  +0.175 / +0.030 points. Fv2 stays at -1.8 (12 sigma): its Fv >= 0 is most of what is left.
* Which springs, chosen from the identification recordings alone (``--effects-cv``,
  ``effects_cv``): blocked cross-validation inside them (5 time blocks per recording, 0.5 s
  gap, PC-WLS error over all samples of the left-out blocks), among none, each single joint,
  every joint and a forward stepwise path; the held-out recording is loaded only after the
  choice is printed. Measured (2026-12-02, rule fixed before it was run): 2 + 3 -> 1 chooses
  springs on joints 1, 3, 5, 6, 7 (held-out WLS 2.064 %, PC 2.258 %, gap +0.194 points), 1 -> 2
  joints 1, 2, 3, 7 (1.793 %, 1.869 %, +0.076); neither chooses every joint. On recording 1
  alone the CV is dominated by its middle block (unconstrained WLS 104 %, PC 10.8 % there
  without springs), which the rest of the recording does not excite.
* TX40 real data: the well-identified base parameters (WLS %sigma < 5): is
  the PC value within 1 sigma (WLS) of the unconstrained one?

* A time shift between torque and motion (``--delays``, ``delay_scan``) does not explain the
  negative Fv2 and Ia3: over +-20 ms they stay at -1.1 .. -2.5 and -1.3 .. -2.2 on 2 + 3, the
  identification data choose no common shift (best -10 ms on 2 + 3, +20 ms or more on 1)
  and the gap never falls below +0.26 points.

* The a-priori priors (``--priors``, ``prior_table``): LWR4+ held-out error (all samples) and
  chi2 of PC-WLS with no prior, the Euclidean prior and the geometric one (entropic divergence
  of the pseudo-inertias, Lee, Wensing & Park 2020) at weights 1e-3 .. 1, and the SDP time of
  both priors on the LWR4+ and the TX40 (whose robot file has no a-priori inertials: its
  reference set there is the tie-break PC-WLS set lifted to PD, for timing only). Measured
  (2026-12-02): no prior 2.400 % (2+3 -> 1) / 2.155 % (1 -> 2); Euclidean 2.428 / 2.428 /
  2.449 / 2.897 % and geometric 2.428 / 2.429 / 2.451 / 2.893 % at 1e-3 / 1e-2 / 1e-1 / 1 on
  2+3 -> 1; 2.163 / 2.158 / 2.202 / 3.076 % and 2.163 / 2.163 / 2.208 / 3.090 % on 1 -> 2.
  Both priors share the Euclidean term of Ia (scale 1e-5, a-priori 0): at 1e-3 they add ~450
  to chi2 (1562 -> 2011 on 2+3 -> 1), and with that Ia term made negligible (a diagnostic run
  outside this script) chi2 is 1552, so it is all Ia's. SDP build + first solve at weight 0.1
  (two runs, shared 2-core machine): LWR4+ 0.11-0.21 s Euclidean, 0.49-0.50 s geometric
  (re-solve 0.04 / 0.05-0.07 s); TX40 0.10-0.14 / 0.26-0.43 s: under the 2 s goal.

Run from the repository root: python benchmarks/physical.py  (``--effects``: only the
LWR4+ effects table, ~10 s; ``--effects --delays`` adds the time-shift scan, ~30 s;
``--priors``: only the prior table and its timings, ~20 s; ``--effects-cv``: the springs
chosen by cross-validation, ~1.5 min on 2 cores; ``--tilt``: the held-out table without and
with the gravity tilt, ``tilt_only``)
The last line is a JSON object with the figures.
"""
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
GOAL_S = 2.0
FLOBAROID_HELD_OUT = 0.0281


def _timed(fn, repeat=3):
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def solve_times(res, robot):
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.sdp import build_sdp, whitening
    from dynid.analysis.estimators.standard_set import apriori_standard, scales
    obs = res.observation
    wls_s, _ = _timed(lambda: ls.wls(obs.W, obs.tau, list(res.base.names), row_mask=obs.row_mask))
    ap = apriori_standard(robot)
    R = whitening(res.wls.cov)

    def total():
        pb = build_sdp(robot, res.base, R, ap, scales(robot, ap), 1e-8, None)
        return pb, pb.solve(R @ res.wls.chi)
    total_s, (pb, _) = _timed(total)
    solve_s, _ = _timed(lambda: pb.solve(R @ res.wls.chi))
    return {"n_standard": robot.n_standard, "n_base": res.base.n_base, "wls_s": round(wls_s, 4),
            "sdp_solve_s": round(solve_s, 4), "sdp_total_s": round(total_s, 4),
            "ratio_solve_to_wls": round(solve_s / wls_s, 1), "ratio_total_to_wls": round(total_s / wls_s, 1),
            "under_goal": bool(total_s < GOAL_S)}


def constraint_costs(res, robot, held):
    """What each family of constraints costs on the held-out recording (all samples): chi2,
    relative error and per-joint RMS with the pseudo-inertias alone, + Ia >= 0, + Fv >= 0, all
    (Ia, Fv, Fc >= 0), each with the robot file's mass bounds, and all without them. This is the
    measured explanation of the held-out gap of PC-WLS against the unconstrained WLS."""
    import numpy as np

    import dynid
    from dynid.analysis.estimators.physical import identify_physical
    from dynid.analysis.estimators.sdp import build_sdp, whitening
    from dynid.analysis.estimators.standard_set import apriori_standard, scales
    ap = apriori_standard(robot)
    R = whitening(res.wls.cov)
    pc = identify_physical(res, robot, n_boot=0)
    out = {}
    cases = (("pseudo_inertia_only", (), robot.mass_tolerance), ("plus_Ia", ("Ia",), robot.mass_tolerance),
             ("plus_Fv", ("Fv",), robot.mass_tolerance),
             ("plus_Ia_Fv_Fc", ("Ia", "Fv", "Fc"), robot.mass_tolerance),
             ("plus_Ia_Fv_Fc_no_mass_bounds", ("Ia", "Fv", "Fc"), None))
    for label, kinds, tol in cases:
        pb = build_sdp(robot, res.base, R, ap, scales(robot, ap), 1e-8, tol, nonneg_kinds=kinds)
        chi = pb.solve(R @ res.wls.chi)
        pc.chi = res.base.matrix @ chi
        v = dynid.validate(pc, held, robot)
        masses = [float(chi[robot.standard_names.index(f"M{j + 1}")]) for j in range(robot.n_joints)]
        out[label] = {"chi2": round(float(np.sum((R @ (pc.chi - res.wls.chi)) ** 2)), 1),
                      "held_out": round(v.rel_error, 5), "rms_per_joint": [round(float(x), 3) for x in v.rms],
                      "max_mass_kg": round(max(masses), 2)}
        print(f"  constraints {label}: chi2 {out[label]['chi2']}, held-out {100 * v.rel_error:.3f} %, "
              f"RMS per joint {out[label]['rms_per_joint']} N m, largest link mass {max(masses):.3g} kg",
              flush=True)
    return out


def link_side_model(res, robot, held):
    """The LWR4+'s torque sensors are link-side: the rotor inertia is not in the measured torque.
    The model without Ia: the base parameters that are a lone Ia_j dropped from the
    unconstrained WLS (same per-joint weights), every Ia_j fixed at 0 in the SDP (the regrouped
    Ia1, Ia2 too). Held-out error of both, the same way as the other figures."""
    import numpy as np

    import dynid
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.physical import identify_physical
    from dynid.analysis.estimators.sdp import build_sdp, whitening
    from dynid.analysis.estimators.standard_set import apriori_standard, scales
    obs = res.observation
    names = list(res.base.names)
    keep = [k for k, n in enumerate(names) if not (n.startswith("Ia") and not n.endswith("R"))]
    wls = ls.wls(obs.W[:, :, keep], obs.tau, [names[k] for k in keep], row_mask=obs.row_mask)
    pc = identify_physical(res, robot, n_boot=0)
    full = np.zeros(len(names))
    full[keep] = wls.chi
    pc.chi = full
    v_wls = dynid.validate(pc, held, robot).rel_error

    class _Reduced:
        matrix = res.base.matrix[keep]
    ap = apriori_standard(robot)
    R = whitening(wls.cov)
    pb = build_sdp(robot, _Reduced, R, ap, scales(robot, ap), 1e-8, robot.mass_tolerance, zero_kinds=("Ia",))
    chi = pb.solve(R @ wls.chi)
    pc.chi = res.base.matrix @ chi
    v_pc = dynid.validate(pc, held, robot).rel_error
    chi2 = float(np.sum((R @ (_Reduced.matrix @ chi - wls.chi)) ** 2))
    out = {"wls": round(v_wls, 5), "pc_wls": round(v_pc, 5), "pc_minus_wls_points": round(100 * (v_pc - v_wls), 3),
           "chi2": round(chi2, 1), "n_base": len(keep)}
    print(f"  link-side model (no Ia): held-out WLS {100 * v_wls:.3f} %, PC {100 * v_pc:.3f} %, chi2 {chi2:.1f}",
          flush=True)
    return out


def prior_weights(res, robot, held, weights=(1e-4, 1e-2, 1.0)):
    """Held-out error of PC-WLS regularised toward the a-priori values (Euclidean prior) at a
    few weights: measured, not used to choose one (that would tune on the validation data)."""
    import dynid
    from dynid.analysis.estimators.physical import identify_physical
    out = {}
    for w in weights:
        pc = identify_physical(res, robot, n_boot=0, prior="apriori", prior_weight=w)
        out[f"{w:g}"] = {"held_out": round(dynid.validate(pc, held, robot).rel_error, 5), "chi2": round(pc.chi2, 1)}
    print(f"  a-priori prior, held-out by weight: {out}", flush=True)
    return out


PRIOR_WEIGHTS = (1e-3, 1e-2, 1e-1, 1.0)


def prior_table(res, robot, held, weights=PRIOR_WEIGHTS):
    """Held-out relative error (all samples, ``dynid.validate``) and chi2 of PC-WLS with no prior
    (tie-break), the Euclidean prior and the geometric one (Lee, Wensing & Park 2020) at each
    weight. Measured, not used to choose a weight (that would tune on the validation data)."""
    import dynid
    from dynid.analysis.estimators.physical import identify_physical
    rows = [(None, None)] + [(p, w) for p in ("apriori", "geometric") for w in weights]
    out = {}
    for prior, w in rows:
        pc = identify_physical(res, robot, n_boot=0, prior=prior, prior_weight=1.0 if w is None else w)
        v = dynid.validate(pc, held, robot).rel_error
        key = "none" if prior is None else f"{prior} {w:g}"
        out[key] = {"held_out": round(v, 5), "chi2": round(pc.chi2, 1), "solve_s": round(pc.solve_seconds, 3),
                    "status_optimal": not any("status" in n for n in pc.notices)}
        print(f"  {key:<16} held-out {100 * v:.3f} %  chi2 {pc.chi2:9.1f}  first solve {pc.solve_seconds:.3f} s"
              + ("" if out[key]["status_optimal"] else "  (solver: optimal_inaccurate)"), flush=True)
    return out


def prior_solve_times(res, robot, weight=0.1, apriori=None):
    """Building + first solve and a re-solve (best of 3) of the SDP with the Euclidean and with the
    geometric prior at ``weight``; ``apriori``: the reference set instead of the robot file's."""
    from dynid.analysis.estimators.sdp import build_sdp, whitening
    from dynid.analysis.estimators.standard_set import apriori_standard, scales
    ap = apriori_standard(robot) if apriori is None else apriori
    R = whitening(res.wls.cov)
    out = {}
    for prior in ("apriori", "geometric"):
        def total(prior=prior):
            pb = build_sdp(robot, res.base, R, ap, scales(robot, ap), weight, robot.mass_tolerance, prior=prior)
            return pb, pb.solve(R @ res.wls.chi)
        total_s, (pb, _) = _timed(total)
        solve_s, _ = _timed(lambda pb=pb: pb.solve(R @ res.wls.chi))
        out[prior] = {"sdp_total_s": round(total_s, 4), "sdp_solve_s": round(solve_s, 4),
                      "status": pb.prob.status, "under_goal": bool(total_s < GOAL_S)}
    print(f"  {robot.name} SDP, weight {weight:g}: Euclidean total {out['apriori']['sdp_total_s']:.3f} s, "
          f"re-solve {out['apriori']['sdp_solve_s']:.3f} s; geometric total {out['geometric']['sdp_total_s']:.3f} s, "
          f"re-solve {out['geometric']['sdp_solve_s']:.3f} s", flush=True)
    return out


def _physical_reference(res, robot):
    """A positive-definite reference set for timing on a robot file without a-priori inertials
    (the TX40's): the tie-break PC-WLS standard set, each link's pseudo-inertia lifted by 1 % of
    its trace (so J0 is PD). For timing only: it is no a-priori knowledge."""
    import numpy as np

    from dynid.analysis.estimators.physical import identify_physical
    from dynid.dynamics.urdf_writer import inertial_slice, pseudo_inertia, pseudo_inertia_basis
    chi = identify_physical(res, robot, n_boot=0).standard.copy()
    E = pseudo_inertia_basis().reshape(10, 16)
    for j in range(robot.n_joints):
        sl = inertial_slice(robot, j)
        J = pseudo_inertia(chi[sl])
        J = J + 0.01 * max(np.trace(J), 1e-3) * np.eye(4)
        chi[sl] = np.linalg.lstsq(E.T, J.ravel(), rcond=None)[0]
    return chi


def priors_only():
    import dynid
    kuka = dynid.load_robot("kuka_lwr4")
    here = ROOT / "examples" / "kuka_lwr4"
    rec = {i: dynid.load_experiment(here / f"recording_{i}.toml", kuka) for i in (1, 2, 3)}
    out = {"weights": list(PRIOR_WEIGHTS), "goal_s": GOAL_S}
    for train, held in (((2, 3), 1), ((1,), 2)):
        key = "+".join(map(str, train)) + f"->{held}"
        res = dynid.identify([rec[i] for i in train], kuka)
        print(f"LWR4+ {key}: held-out relative error (all samples) of PC-WLS by prior and weight", flush=True)
        out.setdefault("kuka_lwr4_held_out", {})[key] = prior_table(res, kuka, rec[held])
        if train == (2, 3):
            out["kuka_lwr4_prior_timing"] = prior_solve_times(res, kuka)
    tx40 = dynid.load_robot("tx40")
    res = dynid.identify(dynid.load_experiment(ROOT / "examples" / "staubli_tx40" / "experiment.toml", tx40), tx40)
    print("TX40 (no a-priori inertials: the reference is the tie-break PC-WLS set, lifted to PD)", flush=True)
    out["tx40_prior_timing"] = prior_solve_times(res, tx40, apriori=_physical_reference(res, tx40))
    out["tx40_prior_timing"]["reference"] = "tie-break PC-WLS set, each J + 1 % tr(J) I (timing only)"
    return out


def export_comparison(res, robot, max_nfev=2000):
    """The URDF export's choice (all base parameters as the target): SDP against the log-Cholesky
    local search it replaced, with the same constraints (J_l, Ia >= 0)."""
    import numpy as np

    from dynid.analysis.estimators.sdp import build_sdp, whitening
    from dynid.analysis.estimators.standard_set import apriori_standard, choose_standard_set, scales
    b, cov = res.wls.chi, res.wls.cov
    t = time.perf_counter()
    local = choose_standard_set(robot, res.base, b, cov, solver="log-cholesky", max_nfev=max_nfev)
    t_local = time.perf_counter() - t
    ap = apriori_standard(robot)
    R = whitening(cov)
    t = time.perf_counter()
    pb = build_sdp(robot, res.base, R, ap, scales(robot, ap), 1e-8, None, nonneg_kinds=("Ia",))
    chi = pb.solve(R @ b)
    t_sdp = time.perf_counter() - t
    chi2 = float(np.sum((R @ (res.base.matrix @ chi - b)) ** 2))
    print(f"  export: SDP chi2 {chi2:.1f} in {t_sdp:.2f} s; log-Cholesky chi2 {local.chi2:.1f} after "
          f"{max_nfev} evaluations in {t_local:.1f} s", flush=True)
    return {"sdp_chi2": round(chi2, 1), "sdp_s": round(t_sdp, 2), "log_cholesky_chi2": round(local.chi2, 1),
            "log_cholesky_s": round(t_local, 1), "log_cholesky_max_nfev": max_nfev}


EFFECT_MODELS = ("", "spring:all", "position_ripple:7:1", "spring:all,position_ripple:7:1")


def effects_model(train, held, robot, specs=EFFECT_MODELS):
    """Unconstrained WLS and PC-WLS of the base model plus effect columns (``specs``, the text
    of :func:`~dynid.analysis.diagnosis.physical_fit.effect_candidates`; "" = none) on the
    identification recordings ``train``; held-out error (all samples) of both on ``held``, the
    PC cost chi2 on the identification data, and the parameters the constraints bind."""
    import numpy as np

    import dynid
    from dynid.analysis.diagnosis.physical_fit import effect_candidates, held_out_errors, identify_physical_effects
    res = dynid.identify(list(train), robot)
    out = {}
    for spec in specs:
        fit = identify_physical_effects(list(train), robot, res, effect_candidates(spec, robot.n_joints), n_boot=0)
        e = held_out_errors(fit, held, robot, res.base)
        sd = np.sqrt(np.diag(fit.wls.cov))
        watch = {n: [round(float(fit.x_wls[k]), 3), round(float(fit.x_wls[k] / sd[k]), 1)]
                 for k, n in enumerate(fit.names) if n in ("ZZ1R", "Ia3", "Ia7", "Fv2")}
        out[spec or "none"] = {"wls": round(e["wls"], 5), "pc_wls": round(e["pc"], 5),
                               "pc_minus_wls_points": round(100 * (e["pc"] - e["wls"]), 3),
                               "chi2_identification": round(float(fit.physical.chi2), 1),
                               "every_link_consistent": fit.physical.consistent,
                               "unconstrained_value_and_t": watch}
        print(f"  effects {spec or 'none'}: held-out WLS {100 * e['wls']:.3f} %, PC {100 * e['pc']:.3f} % "
              f"(gap {100 * (e['pc'] - e['wls']):+.3f} points), PC chi2 on the identification data "
              f"{fit.physical.chi2:.0f}, consistent {fit.physical.consistent}; unconstrained (value, t) {watch}",
              flush=True)
    return out


# Effects chosen by blocked cross-validation inside the identification data (issue 15). Fixed
# before any CV or held-out figure of this option was seen:
CV_BLOCKS = 5           # contiguous time blocks per identification recording
CV_GAP_S = 0.5          # s between training and test raw samples: the recording script's 2-3 Hz
                        # zero-phase filter couples samples over about 0.3 s
CV_REL_STEP = 0.01      # stepwise: add a spring only if it lowers the CV error by >= 1 % relative;
                        # choice: the fewest springs within 1 % relative of the lowest CV error


def _spring_spec(joints, n_joints):
    joints = sorted(joints)
    if len(joints) == n_joints:
        return "spring:all"
    return ",".join(f"spring:{j}" for j in joints)


def effects_cv(train, robot):
    """Choose the springs ``Ks_j q_j`` from the identification recordings ``train`` alone.

    Candidates, fixed in advance: none, a spring on each single joint, a spring on every joint,
    and the sets of a forward stepwise search from none (add the spring that lowers the CV error
    most while it lowers it by ``CV_REL_STEP`` relative or more). Score: blocked cross-validation
    (:func:`dynid.analysis.data.split.blocked_folds`, ``CV_BLOCKS`` blocks per recording, fold
    ``i`` leaves out block ``i`` of every recording, ``CV_GAP_S`` between training and test
    samples): the relative error ||tau - tau_hat|| / ||tau|| of the PC-WLS fit
    (``identify_physical_effects``, n_boot = 0) over all samples of all left-out blocks pooled
    (no dead zone, as ``held_out_errors``), beside the unconstrained WLS's. Processing settings
    and base parameters are those of ``dynid.identify(train)`` in every fold (the settings come
    from the positions only). Chosen: the fewest springs whose CV error is within
    ``CV_REL_STEP`` relative of the lowest. Nothing but ``train`` is read."""
    import numpy as np

    import dynid
    from dynid.analysis.data.split import blocked_folds
    from dynid.analysis.diagnosis.physical_fit import effect_candidates, held_out_errors, identify_physical_effects
    from dynid.analysis.processing.observation import observe
    n = robot.n_joints
    res = dynid.identify(list(train), robot)
    every = dict(res.observation.settings, qd_threshold=0.0)
    per_rec, edges = [], {"n_recorded": 0, "n_scored": 0, "scored_times_in_blocks": True, "overlap": False}
    for e in train:
        whole = observe(e, robot, res.base, every)
        margin = float(whole.t[0] - e.t[0])      # position-filter edge + decimation transient
        folds = blocked_folds(e, CV_BLOCKS, margin=margin, gap=CV_GAP_S)
        scored = [observe(f.test, robot, res.base, every).t for f in folds]
        edges["n_recorded"] += int(whole.n_samples)
        edges["n_scored"] += int(sum(len(ts) for ts in scored))
        half = 0.5 / e.fs
        edges["scored_times_in_blocks"] &= all(f.span[0] - half <= ts[0] and ts[-1] < f.span[1] + half
                                              for f, ts in zip(folds, scored))
        edges["overlap"] |= bool(np.any(np.diff(np.concatenate(scored)) <= 0))
        edges.setdefault("margin_s", []).append(round(margin, 4))
        per_rec.append(folds)
    # each block's decimation grid starts afresh, so the blocks together may hold a sample or
    # two per block more (or fewer) than the whole recording processed at once
    edges["scored_over_whole"] = round(edges["n_scored"] / edges["n_recorded"], 4)
    print(f"  blocked CV: {CV_BLOCKS} blocks per recording, margin {edges['margin_s']} s, gap {CV_GAP_S} s; "
          f"{edges['n_scored']} samples scored over the blocks, {edges['n_recorded']} in the whole recordings "
          f"processed at once, every scored sample in its block: {edges['scored_times_in_blocks']}, none "
          f"scored twice: {not edges['overlap']}", flush=True)
    cache = {}

    def cv(joints):
        key = frozenset(joints)
        if key in cache:
            return cache[key]
        spec = _spring_spec(key, n)
        cands = effect_candidates(spec, n)
        # per fold: squared residual norms of both fits and squared torque norm, all samples
        sse = np.zeros((CV_BLOCKS, 3))
        for i in range(CV_BLOCKS):
            pieces = [p for folds in per_rec for p in folds[i].train]
            fit = identify_physical_effects(pieces, robot, res, cands, n_boot=0)
            for folds in per_rec:
                d = held_out_errors(fit, folds[i].test, robot, res.base, detail=True)
                r2 = [d["n_samples"] * float(np.sum(np.square(d[f"rms_{k}"]))) for k in ("wls", "pc")]
                sse[i] += r2 + [r2[0] / d["rel_error_wls"] ** 2]
        e_w, e_p = np.sqrt(sse[:, :2].sum(axis=0) / sse[:, 2].sum())
        cache[key] = {"spec": spec or "none", "n_springs": len(key), "cv_wls": round(e_w, 5),
                      "cv_pc_wls": round(e_p, 5), "cv_gap_points": round(100 * (e_p - e_w), 3),
                      "per_block_wls": [round(float(x), 5) for x in np.sqrt(sse[:, 0] / sse[:, 2])],
                      "per_block_pc_wls": [round(float(x), 5) for x in np.sqrt(sse[:, 1] / sse[:, 2])],
                      "_pc": float(e_p)}
        print(f"  CV {spec or 'none':<40} WLS {100 * e_w:.3f} %, PC {100 * e_p:.3f} % "
              f"(gap {100 * (e_p - e_w):+.3f} points)", flush=True)
        return cache[key]

    fixed = [()] + [(j,) for j in range(1, n + 1)] + [tuple(range(1, n + 1))]
    for joints in fixed:
        cv(joints)
    state, path = frozenset(), ["none"]
    while len(state) < n:
        here = cv(state)["_pc"]
        best = min((state | {j} for j in range(1, n + 1) if j not in state), key=lambda s: cv(s)["_pc"])
        if here - cv(best)["_pc"] < CV_REL_STEP * here:
            break
        state = best
        path.append(cache[state]["spec"])
    low = min(r["_pc"] for r in cache.values())
    chosen = min((r for r in cache.values() if r["_pc"] <= (1 + CV_REL_STEP) * low),
                 key=lambda r: (r["n_springs"], r["_pc"]))
    table = sorted(cache.values(), key=lambda r: (r["n_springs"], r["spec"]))
    print(f"  stepwise path: {' -> '.join(path)}; lowest CV PC error {100 * low:.3f} %; chosen: "
          f"{chosen['spec']} (CV PC {100 * chosen['_pc']:.3f} %)", flush=True)
    for r in (cache[frozenset()], chosen):
        print(f"  per block, {r['spec']}: WLS {[round(100 * x, 2) for x in r['per_block_wls']]} %, PC "
              f"{[round(100 * x, 2) for x in r['per_block_pc_wls']]} %", flush=True)
    return {"blocks": CV_BLOCKS, "gap_s": CV_GAP_S, "rel_step": CV_REL_STEP, "edges": edges,
            "cv": [{k: v for k, v in r.items() if k != "_pc"} for r in table], "stepwise_path": path,
            "chosen": chosen["spec"], "chosen_n_springs": chosen["n_springs"]}


def effects_cv_only():
    """``--effects-cv``: each split's springs chosen by :func:`effects_cv` on its identification
    recordings, which are all that is loaded until the choice is printed; then, once, the
    held-out error of that choice and of the rigid body alone (:func:`effects_model`)."""
    import dynid
    kuka = dynid.load_robot("kuka_lwr4")
    here = ROOT / "examples" / "kuka_lwr4"
    out = {}
    for train, held in (((2, 3), 1), ((1,), 2)):
        key = "+".join(map(str, train)) + f"->{held}"
        print(f"LWR4+ {key}: springs chosen by blocked CV on recording(s) {'+'.join(map(str, train))} alone",
              flush=True)
        t0 = time.perf_counter()
        ident = [dynid.load_experiment(here / f"recording_{i}.toml", kuka) for i in train]
        sel = effects_cv(ident, kuka)
        sel["selection_s"] = round(time.perf_counter() - t0, 1)
        chosen = "" if sel["chosen"] == "none" else sel["chosen"]
        print(f"LWR4+ {key}: held-out recording {held} read now, once, for the chosen set", flush=True)
        held_exp = dynid.load_experiment(here / f"recording_{held}.toml", kuka)
        sel["held_out"] = effects_model(ident, held_exp, kuka, specs=tuple(dict.fromkeys((chosen, ""))))
        out[key] = sel
    return out


def delay_scan(train, held, robot, delays=(-0.02, -0.01, 0.0, 0.01, 0.02)):
    """Hypothesis "the torque is late (or early) by d against the motion": every recording's
    torque re-sampled at t + d (cubic spline), the model re-identified; identification error
    (the data that would choose d), held-out WLS and PC errors, and Fv2, Ia3."""
    import dataclasses

    import numpy as np
    from scipy.interpolate import CubicSpline

    import dynid
    from dynid.analysis.estimators.physical import identify_physical

    def shifted(e, d):
        tau = CubicSpline(e.t, e.tau, axis=0)(np.clip(e.t + d, e.t[0], e.t[-1]))
        return dataclasses.replace(e, tau=tau)
    out = {}
    for d in delays:
        res = dynid.identify([shifted(e, d) for e in train], robot)
        h = shifted(held, d)
        v_pc = dynid.validate(identify_physical(res, robot, n_boot=0), h, robot).rel_error
        ident = res.wls.rel_error
        res.essential.result = res.wls
        v_wls = dynid.validate(res, h, robot).rel_error
        names = list(res.wls.names)
        vals = {n: round(float(res.wls.chi[names.index(n)]), 3) for n in ("Fv2", "Ia3")}
        out[f"{1e3 * d:g} ms"] = {"identification_wls": round(ident, 5), "wls": round(v_wls, 5),
                                   "pc_wls": round(v_pc, 5), **vals}
        print(f"  torque shifted by {1e3 * d:+g} ms: identification {100 * ident:.3f} %, held-out WLS "
              f"{100 * v_wls:.3f} %, PC {100 * v_pc:.3f} % (gap {100 * (v_pc - v_wls):+.3f}); {vals}", flush=True)
    return out


def effects_only():
    import dynid
    kuka = dynid.load_robot("kuka_lwr4")
    here = ROOT / "examples" / "kuka_lwr4"
    rec = {i: dynid.load_experiment(here / f"recording_{i}.toml", kuka) for i in (1, 2, 3)}
    out = {}
    for train, held in (((2, 3), 1), ((1,), 2)):
        key = "+".join(map(str, train)) + f"->{held}"
        print(f"LWR4+ {key}: the same model fitted with and without the physical constraints", flush=True)
        out[key] = effects_model([rec[i] for i in train], rec[held], kuka)
        if "--delays" in sys.argv[1:]:
            out[key + " delays"] = delay_scan([rec[i] for i in train], rec[held], kuka)
    return out


def tilt_only():
    """LWR4+ held-out table without and with the gravity tilt (issue 15): the tilt
    (:func:`~dynid.analysis.estimators.gravity_tilt.gravity_tilt`) is fitted on each split's
    identification recordings only, then :func:`effects_model` (rigid body and ``spring:all``,
    WLS and PC-WLS, held-out error over all samples) runs with the level and the tilted robot."""
    import dynid
    from dynid.analysis.estimators.gravity_tilt import gravity_tilt
    kuka = dynid.load_robot("kuka_lwr4")
    here = ROOT / "examples" / "kuka_lwr4"
    out = {}
    for train, held in (((2, 3), 1), ((1,), 2)):
        key = "+".join(map(str, train)) + f"->{held}"
        ident = [dynid.load_experiment(here / f"recording_{i}.toml", kuka) for i in train]
        tilt = gravity_tilt(ident, kuka)
        print(f"LWR4+ {key}: " + tilt.summary(), flush=True)
        row = {"tilt_mrad": [round(1e3 * float(v), 3) for v in tilt.chi],
               "std_mrad": [round(1e3 * float(v), 3) for v in tilt.bse.to_numpy()],
               "lr_chi2": round(tilt.lr_statistic, 1), "lr_dof": tilt.lr_dof,
               "rel_error_identification": [round(tilt.rel_error_before, 5), round(tilt.rel_error_after, 5)]}
        for name, robot in (("level", kuka), ("tilted", tilt.robot)):
            print(f"LWR4+ {key}, {name} gravity:", flush=True)
            row[name] = effects_model([dynid.load_experiment(here / f"recording_{i}.toml", robot) for i in train],
                                      dynid.load_experiment(here / f"recording_{held}.toml", robot), robot,
                                      specs=("", "spring:all"))
        out[key] = row
    return out


def main():
    import numpy as np

    import dynid
    from dynid.analysis.estimators.physical import identify_physical
    from dynid.dynamics.base_parameters import base_parameters  # noqa: F401  (warm import)
    out = {"goal_s": GOAL_S}

    kuka = dynid.load_robot("kuka_lwr4")
    here = ROOT / "examples" / "kuka_lwr4"
    rec = {i: dynid.load_experiment(here / f"recording_{i}.toml", kuka) for i in (1, 2, 3)}
    splits = {}
    for train, held in (((2, 3), 1), ((1,), 2)):
        res = dynid.identify([rec[i] for i in train], kuka)
        pc = identify_physical(res, kuka, n_boot=0)
        key = "+".join(map(str, train)) + f"->{held}"
        if train == (2, 3):
            out["kuka_lwr4_timing"] = solve_times(res, kuka)
            out["kuka_lwr4_export_vs_log_cholesky"] = export_comparison(res, kuka)
        print(f"LWR4+ {'+'.join(map(str, train))}->{held}: what each constraint family costs", flush=True)
        out.setdefault("kuka_lwr4_constraint_costs", {})["+".join(map(str, train)) + f"->{held}"] = \
            constraint_costs(res, kuka, rec[held])
        out.setdefault("kuka_lwr4_link_side_no_Ia", {})["+".join(map(str, train)) + f"->{held}"] = \
            link_side_model(res, kuka, rec[held])
        out.setdefault("kuka_lwr4_prior_weights", {})["+".join(map(str, train)) + f"->{held}"] = \
            prior_weights(res, kuka, rec[held])
        wls_model = dynid.identify([rec[i] for i in train], kuka)
        v_pc = dynid.validate(pc, rec[held], kuka).rel_error
        v_ess = dynid.validate(res, rec[held], kuka).rel_error
        # the unconstrained WLS of all base parameters, validated the same way
        wls_model.essential.result = wls_model.wls
        v_wls = dynid.validate(wls_model, rec[held], kuka).rel_error
        wls_v = dynid.validate(wls_model, rec[held], kuka)
        splits[key] = {"pc_wls": round(v_pc, 5), "wls_rms_per_joint": [round(float(x), 3) for x in wls_v.rms],
                       "mass_tolerance": kuka.mass_tolerance, "wls_all_base": round(v_wls, 5), "idim_essential": round(v_ess, 5),
                       "pc_minus_wls_points": round(100 * (v_pc - v_wls), 3),
                       "pc_minus_essential_points": round(100 * (v_pc - v_ess), 3),
                       "every_link_consistent": pc.consistent, "unconstrained_physical": pc.wls_consistent,
                       "chi2": round(pc.chi2, 1), "dof": pc.dof, "p_value": pc.p_value,
                       "n_active": len(pc.active)}
        print(f"LWR4+ {key}: held-out PC {100 * v_pc:.3f} %, WLS (all base) {100 * v_wls:.3f} %, IDIM "
              f"essential {100 * v_ess:.3f} %; consistent {pc.consistent}; chi2 {pc.chi2:.1f} on "
              f"{pc.dof} directions", flush=True)
    splits["flobaroid_published_1->2"] = FLOBAROID_HELD_OUT
    out["kuka_lwr4_with_effects"] = effects_only()
    out["kuka_lwr4_held_out"] = splits
    print("LWR4+ timing", out["kuka_lwr4_timing"], flush=True)

    tx40 = dynid.load_robot("tx40")
    exp = dynid.load_experiment(ROOT / "examples" / "staubli_tx40" / "experiment.toml", tx40)
    res = dynid.identify(exp, tx40)
    out["tx40_timing"] = solve_times(res, tx40)
    print("TX40 timing", out["tx40_timing"], flush=True)
    pc = identify_physical(res, tx40, n_boot=0)
    comp = pc.comparison()
    well = comp[comp["wls_rel_std_percent"] < 5]
    within = well["shift_sigma"].abs() <= 1.0
    out["tx40_real"] = {"every_link_consistent": pc.consistent, "unconstrained_physical": pc.wls_consistent,
                        "chi2": round(pc.chi2, 3), "dof": pc.dof, "p_value": pc.p_value, "active": pc.active,
                        "n_well_identified": int(len(well)), "n_within_1_sigma": int(within.sum()),
                        "outside": {n: round(float(s), 2) for n, s in well["shift_sigma"][~within].items()},
                        "max_abs_shift_sigma_well_identified": round(float(well["shift_sigma"].abs().max()), 3),
                        "rel_error_pc": round(pc.rel_error, 5), "rel_error_wls": round(pc.wls_rel_error, 5)}
    print(f"TX40: {int(within.sum())}/{len(well)} well-identified parameters (%sigma < 5) within 1 sigma; "
          f"chi2 {pc.chi2:.3f}, active {pc.active}", flush=True)
    out["versions"] = {"numpy": np.__version__, "cvxpy": __import__("cvxpy").__version__,
                       "clarabel": __import__("clarabel").__version__}
    print(json.dumps(out, default=float))


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    if "--tilt" in sys.argv[1:]:
        print(json.dumps({"kuka_lwr4_gravity_tilt": tilt_only()}, default=float))
    elif "--effects-cv" in sys.argv[1:]:
        print(json.dumps({"kuka_lwr4_effects_cv": effects_cv_only()}, default=float))
    elif "--effects" in sys.argv[1:]:
        print(json.dumps({"kuka_lwr4_with_effects": effects_only()}, default=float))
    elif "--priors" in sys.argv[1:]:
        print(json.dumps({"priors": priors_only()}, default=float))
    else:
        main()
