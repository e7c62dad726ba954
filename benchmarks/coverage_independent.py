"""Coverage of IDIM's 95 % intervals on the independent closed-loop plant, coloured noise (issue 26).

Plant: ``tests/support/independent_plant.py`` (Pinocchio, its own integrator, PID loop), the
TX40 with the Table 2 parameters and the coupled wrist, i.e. dynid's ``tx40`` model
with the Table 2 values, so the true base parameters are the plant's standard parameters
(``tx40_table2_parameters``, motor-6 friction 0.8, 1.6, offsets 0) mapped by the
base-parameter relations. Each seed: its own
multisine reference (10 harmonics), controller at 5 kHz, logged at 1 kHz
(``log_every=5``, a subsampled plant: the campaign has to fit on a shared 2-core
machine), ``DURATION`` s. The torque record gets coloured noise, AR(1) at the
logging rate with coefficient ``PHI`` (marginal std ``NOISE`` N m), in place of the
simulator's white noise (both only enter the record, not the loop), and the plant one
small unmodelled effect, a position ripple ``A sin(k q1)`` on joint 1 (``RIPPLE``).

The essential set's robust σ is the full WLS's σ of the same parameters with the
bias of the removed parameters added in quadrature (essential.py: σ_wls,e² + d², d the
essential minus the full WLS estimate; chosen on seeds 1000-1099):
``essential_<opt>+bias`` (rows recorded before that rule get it from their z and σ).

For each seed the decimated system of dynid's default IDIM (``observe``) is fitted once
per covariance option (``classic``, ``hac``, ``bootstrap``; WLS of all base parameters
and the essential set, as ``identify_idim`` does): the estimates are identical, only the
intervals change. ``--cache DIR`` keeps each seed's system (``seed_N.npz``), so the
simulation, most of a seed's cost, runs once (``--methods simulate`` only fills the
cache). Coverage: the fraction of (parameter, seed) pairs whose estimate ± 1.96 σ holds
the truth, with the median interval width relative to classic.

``--methods`` adds, on the same record:

* ``candidates``: the covariances evaluated in benchmarks/uncertainty.py and not
  shipped (fixed-b HAC, EWC, bootstrap variants, the Gaussian-process discrepancy),
  from the classic fits; ``--candidates`` picks some (the discrepancy ones need the
  state (q, qd, qdd), which the cache keeps since 2026-12-03: older caches skip them);
* ``pc``: PC-WLS (``pc_wls`` on the WLS estimate, classic metric as ``dynid identify
  --physical`` runs it) whose bootstrap draws from each option's covariance
  (``--pc-options``, default all), its ``conf_int()`` (bootstrap percentiles with the
  WLS half-width, cut at the physical bound) against the truth, width relative to the
  classic WLS interval;
* ``didim``: DIDIM (section 3) from eq. (31)'s start with the robot file's gains (the
  plant's PID is the robot file's), its last Gauss-Newton step's WLS with each
  covariance option recomputed on that step's regressor (the estimate is the same,
  asserted); seeds where DIDIM did not converge are counted and kept.

Seeds: 0-4 were used while developing the first options; 1000-1099 held out for the
first campaign (and then used to choose the essential rule); 3000-3099 held out for
the pc/didim campaign; 0-20 used while developing the bootstrap's block rule and
percentile σ (2026-12-03); 4000-4099 held out for that campaign; 9050-9052 used while
developing the discrepancy candidates, 9100-9199 held out for them
(results/coverage_independent_gp_9100.jsonl, _gp_model_9100.jsonl):

    nice -n 10 python benchmarks/coverage_independent.py --methods simulate --cache CACHE \
        --seeds 100 --start 4000
    nice -n 10 python benchmarks/coverage_independent.py --methods idim,candidates --cache CACHE \
        --seeds 100 --start 4000 --out benchmarks/results/coverage_independent_4000.jsonl
    nice -n 10 python benchmarks/coverage_independent.py --methods idim,pc --pc-options classic,bootstrap \
        --cache CACHE --seeds 100 --start 4000 --out benchmarks/results/coverage_independent_pc_4000.jsonl

The last line is a JSON object with the headline figures.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np
from campaign_rows import append, resume

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "tests" / "support"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

DURATION = 4.0
RATE = 5000.0
LOG_EVERY = 5
PHI = 0.9
NOISE = 0.3
RIPPLE = dict(joint=1, A=0.5, k=6.0)
OPTIONS = ("classic", "hac", "bootstrap")


def ar1_noise(rng, shape, phi, std):
    """AR(1) noise along axis 0 with coefficient ``phi`` and marginal std ``std``."""
    from scipy.signal import lfilter
    e = rng.standard_normal(shape) * std * np.sqrt(1 - phi**2)
    x0 = rng.standard_normal(shape[1]) * std   # stationary start
    return lfilter([1.0], [1.0, -phi], e, axis=0, zi=(phi * x0)[None, :])[0]


def truth(robot, bp):
    """True base parameters of the plant: its standard parameters through the relations."""
    import independent_plant as ip
    links, Ia, Fv, Fc = ip.tx40_table2_parameters()
    val = {"Fvm6": 0.8, "Fcm6": 1.6}   # tx40_plant(coupled_wrist=True)'s motor-6 friction
    for j in range(6):
        for k, sym in enumerate(("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M")):
            val[f"{sym}{j + 1}"] = links[j, k]
        val.update({f"Ia{j + 1}": Ia[j], f"Fv{j + 1}": Fv[j], f"Fc{j + 1}": Fc[j]})
    chi = np.array([val.get(n, 0.0) for n in robot.standard_names])
    return bp.from_standard(chi)


def simulate(seed):
    """The seed's record: (Experiment, robot, base parameters, true base parameters, seconds)."""
    import independent_plant as ip

    from dynid.analysis.data.experiment import Experiment
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    t0 = time.time()
    plant = ip.tx40_plant("table2", coupled_wrist=True,
                          effects=[ip.position_ripple(RIPPLE["joint"], RIPPLE["A"], RIPPLE["k"])])
    sensor = ip.Sensor(tau_noise=0.0)
    rec = ip.run(plant, DURATION, RATE, seed, sensor=sensor, log_every=LOG_EVERY, n_harmonics=10)
    rng = np.random.default_rng(10_000 + seed)
    tau = rec["tau"] + ar1_noise(rng, rec["tau"].shape, PHI, NOISE)
    exp = Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=tau, fs=rec["rate"],
                     source=f"independent plant seed {seed}", name=f"cov-{seed}")
    robot = load_robot("tx40")
    bp = base_parameters(robot)
    return exp, robot, bp, truth(robot, bp), time.time() - t0


def observed_system(seed, cache=None):
    """The seed's decimated system (W, tau, row_mask, true base parameters), cached in `cache`.

    The simulation is most of a seed's cost and does not depend on the covariance
    option: with a cache folder, every option is evaluated on the same stored system.
    """
    from dynid.analysis.processing.observation import observe
    f = None if cache is None else Path(cache) / f"seed_{seed}.npz"
    if f is not None and f.exists():
        z = np.load(f)
        return z["W"], z["tau"], z["mask"], z["beta"], float(z["sim_seconds"])
    exp, robot, bp, beta, t_sim = simulate(seed)
    obs = observe(exp, robot, bp)
    if f is not None:
        f.parent.mkdir(parents=True, exist_ok=True)
        tmp = f.with_suffix(f".{os.getpid()}.tmp.npz")   # two campaigns may fill one cache
        np.savez(tmp, W=obs.W, tau=obs.tau, mask=obs.row_mask, beta=beta, sim_seconds=t_sim,
                 q=obs.q, qd=obs.qd, qdd=obs.qdd)   # the state, for the discrepancy candidates
        tmp.replace(f)
    return obs.W, obs.tau, obs.row_mask, beta, t_sim


def observed_state(seed, cache):
    """(q, qd, qdd) of the seed's decimated samples from the cache, or None (caches made before they were kept)."""
    f = None if cache is None else Path(cache) / f"seed_{seed}.npz"
    if f is None or not f.exists():
        return None
    z = np.load(f)
    return (z["q"], z["qd"], z["qdd"]) if "q" in z.files else None


def run_seed(seed, methods=("idim",), cache=None, options=None, pc_options=None, candidates=None):
    """One seed's rows: z and sigma of WLS and the essential set for every option (and PC, DIDIM)."""
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.essential import essential_parameters
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    options = OPTIONS if options is None else tuple(options)
    t0 = time.time()
    if "didim" in methods:
        exp, robot, bp, beta, t_sim = simulate(seed)
        from dynid.analysis.processing.observation import observe
        obs = observe(exp, robot, bp)
        W, tau, mask = obs.W, obs.tau, obs.row_mask
    else:
        W, tau, mask, beta, t_sim = observed_system(seed, cache)
        robot = load_robot("tx40")
        bp = base_parameters(robot)
    row = {"seed": seed, "sim_seconds": t_sim}
    if "simulate" in methods:
        row["seconds"] = time.time() - t0
        return row
    names = list(bp.names)
    groups = np.zeros(W.shape[0], dtype=int)
    ref, fits = None, {}
    for opt in options:
        # what identify_idim does with this system (one recording)
        unc = {"uncertainty": opt, "groups": groups}
        wls = ls.wls(W, tau, names, row_mask=mask, **unc)
        ess = essential_parameters(W, tau, names, ls.wls, row_mask=mask, **unc).result
        if ref is None:
            ref = (wls, ess)
        assert np.array_equal(wls.chi, ref[0].chi) and np.array_equal(ess.chi, ref[1].chi)
        fits[opt] = wls
        for part, r in (("wls", wls), ("essential", ess)):
            idx = [names.index(n) for n in r.names]
            sig = r.bse.to_numpy()
            row[f"{part}_{opt}_z"] = [float(v) for v in (r.chi - beta[idx]) / sig]
            row[f"{part}_{opt}_sigma"] = [float(v) for v in sig]
        row[f"essential_{opt}_bias_included"] = "selection_bias" in ess.settings.get(
            "least_squares", {}).get("uncertainty", {})
        row["essential_names"] = list(ess.names)
    if "candidates" in methods:
        _candidate_rows(row, W, tau, mask, names, beta, *ref,
                        state=(obs.q, obs.qd, obs.qdd) if "didim" in methods else observed_state(seed, cache),
                        only=candidates)
    if "pc" in methods:
        for opt in pc_options or options:
            _pc_rows(row, fits[opt], fits["classic"], robot, bp, beta, opt)
    if "didim" in methods:
        _didim_rows(row, exp, robot, bp, beta)
    row["seconds"] = time.time() - t0
    return row


def _candidate_rows(row, W, tau, mask, names, beta, wls, ess, state=None, only=None):
    """z and sigma of the covariances evaluated in benchmarks/uncertainty.py and not shipped.

    Computed from the classic fits (same estimates); the essential set gets the robust
    options' rule: the full model's covariance of its parameters plus d d'.
    """
    from uncertainty import candidate_sigmas
    idx = [names.index(n) for n in ess.names]
    d = ess.chi - wls.chi[idx]
    for cand, (cov, sig) in candidate_sigmas(wls, W, tau, mask, state=state, only=only).items():
        row[f"wls_{cand}_z"] = [float(v) for v in (wls.chi - beta) / sig]
        row[f"wls_{cand}_sigma"] = [float(v) for v in sig]
        se = np.sqrt(np.diag(cov)[idx] + d**2)
        row[f"essential_{cand}_z"] = [float(v) for v in (ess.chi - beta[idx]) / se]
        row[f"essential_{cand}_sigma"] = [float(v) for v in se]
        row[f"essential_{cand}_bias_included"] = True


def _pc_rows(row, wls, classic, robot, bp, beta, opt):
    """PC-WLS from the WLS estimate with option `opt`'s covariance: does its conf_int hold the truth?

    Its parametric bootstrap draws from that covariance (as `dynid identify --physical`
    does from the IDIM result it is given); width relative to the classic WLS interval.
    """
    from dynid.analysis.estimators.physical import pc_wls
    t = time.time()
    pc = pc_wls(robot, bp, wls.chi, classic.cov, n_boot=100, interval_cov=wls.cov, uncertainty=opt)
    ci = np.asarray(pc.conf_int(), dtype=float)
    idx = [list(bp.names).index(n) for n in pc.names]
    b = beta[idx]
    key = "pc" if opt == "classic" else f"pc_{opt}"
    row[f"{key}_inside"] = [bool(v) for v in (ci[:, 0] <= b) & (b <= ci[:, 1])]
    row[f"{key}_width_vs_classic"] = [float(v) for v in (ci[:, 1] - ci[:, 0])
                                      / (2 * 1.96 * classic.bse.to_numpy()[idx])]
    row[f"{key}_seconds"] = time.time() - t


def _didim_rows(row, exp, robot, bp, beta):
    """DIDIM's last step, with each covariance option on that step's WLS."""
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.didim import identify_didim
    t = time.time()
    try:
        d = identify_didim(exp, robot, bp=bp, essential=False)
    except Exception as exc:   # a failed run is a result of the campaign, not a crash of it
        row["didim_error"] = str(exc).splitlines()[0]
        row["didim_seconds"] = time.time() - t
        return
    row["didim_converged"] = bool(d.converged)
    names = list(d.result.names)
    idx = [list(bp.names).index(n) for n in names]
    for opt in OPTIONS:
        r = ls.wls(d.W_dec, d.tau_dec, names, row_mask=d.row_mask, uncertainty=opt)
        assert np.allclose(r.chi, d.result.chi, rtol=1e-9, atol=1e-12), "the last step's WLS is not reproduced"
        row[f"didim_{opt}_z"] = [float(v) for v in (r.chi - beta[idx]) / r.bse.to_numpy()]
        row[f"didim_{opt}_sigma"] = [float(v) for v in r.bse.to_numpy()]
    row["didim_seconds"] = time.time() - t


def _essential_with_bias(row, opt):
    """z of the essential estimate with sigma_wls,e^2 + d^2, d = chi_e - chi_wls,e (essential.py's rule).

    Rows recorded before that rule (no `essential_<opt>_bias_included`) get it here from
    their z and sigma: chi - truth = z sigma for both the essential and the WLS estimate.
    """
    ze, se = np.asarray(row[f"essential_{opt}_z"]), np.asarray(row[f"essential_{opt}_sigma"])
    if row.get(f"essential_{opt}_bias_included"):
        return ze, se
    zw, sw = np.asarray(row[f"wls_{opt}_z"]), np.asarray(row[f"wls_{opt}_sigma"])
    names = _base_names()   # the WLS rows are in base-parameter order
    idx = [names.index(n) for n in row["essential_names"]]
    d = ze * se - zw[idx] * sw[idx]
    s = np.sqrt(sw[idx] ** 2 + d**2)
    return ze * se / s, s


@functools.lru_cache(maxsize=1)
def _base_names():
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    return list(base_parameters(load_robot("tx40")).names)


def headline(rows, options=OPTIONS):
    out = {"seeds": len(rows)}
    options = [o for o in options if all(f"wls_{o}_z" in r for r in rows)]
    for part in ("wls", "essential"):
        for opt in options:
            z = np.concatenate([r[f"{part}_{opt}_z"] for r in rows])
            out[f"{part}_{opt}_coverage95"] = float(np.mean(np.abs(z) <= 1.96))
            if opt != "classic":
                ratio = np.concatenate([np.asarray(r[f"{part}_{opt}_sigma"]) / np.asarray(r[f"{part}_classic_sigma"])
                                        for r in rows])
                out[f"{part}_{opt}_median_width_vs_classic"] = float(np.median(ratio))
    for opt in options[1:]:
        zs = [_essential_with_bias(r, opt) for r in rows]
        out[f"essential_{opt}+bias_coverage95"] = float(np.mean(np.abs(np.concatenate([z for z, _ in zs])) <= 1.96))
        out[f"essential_{opt}+bias_median_width_vs_classic"] = float(np.median(np.concatenate(
            [s / np.asarray(r["essential_classic_sigma"]) for (_, s), r in zip(zs, rows)])))
    for opt in options:
        key = "pc" if opt == "classic" else f"pc_{opt}"
        pc = [r for r in rows if f"{key}_inside" in r]
        if pc:
            out[f"{key}_seeds"] = len(pc)
            out[f"{key}_coverage95"] = float(np.mean(np.concatenate([r[f"{key}_inside"] for r in pc])))
            out[f"{key}_median_width_vs_classic"] = float(np.median(np.concatenate(
                [r[f"{key}_width_vs_classic"] for r in pc])))
    dd = [r for r in rows if "didim_classic_z" in r]
    if dd or any("didim_error" in r for r in rows):
        out["didim_seeds"] = len(dd)
        out["didim_failed"] = sum("didim_error" in r for r in rows)
        out["didim_converged"] = sum(r.get("didim_converged", False) for r in dd)
        for opt in OPTIONS if dd else ():
            z = np.concatenate([r[f"didim_{opt}_z"] for r in dd])
            out[f"didim_{opt}_coverage95"] = float(np.mean(np.abs(z) <= 1.96))
            ok = [r for r in dd if r.get("didim_converged")]
            if ok:
                zc = np.concatenate([r[f"didim_{opt}_z"] for r in ok])
                out[f"didim_{opt}_coverage95_converged"] = float(np.mean(np.abs(zc) <= 1.96))
            if opt != "classic":
                ratio = np.concatenate([np.asarray(r[f"didim_{opt}_sigma"]) / np.asarray(r["didim_classic_sigma"])
                                        for r in dd])
                out[f"didim_{opt}_median_width_vs_classic"] = float(np.median(ratio))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default=None, help="JSON lines, one per seed (appended; seeds done are skipped)")
    ap.add_argument("--methods", default="idim",
                    help="comma-separated: idim (always), pc, didim; or simulate (only fill --cache)")
    ap.add_argument("--cache", default=None, help="folder of the seeds' decimated systems (reused when present)")
    ap.add_argument("--options", default=",".join(OPTIONS), help="comma-separated covariance options")
    ap.add_argument("--pc-options", default=None, help="options PC-WLS draws from (default: --options)")
    ap.add_argument("--candidates", default=None,
                    help="comma-separated candidates of benchmarks/uncertainty.py (default all)")
    a = ap.parse_args(argv)
    methods = tuple(m.strip() for m in a.methods.split(",") if m.strip())
    options = tuple(o.strip() for o in a.options.split(",") if o.strip())
    if "classic" not in options:
        options = ("classic",) + options
    pc_options = None if a.pc_options is None else tuple(o.strip() for o in a.pc_options.split(",") if o.strip())
    candidates = None if a.candidates is None else tuple(c.strip() for c in a.candidates.split(",") if c.strip())
    seeds = list(range(a.start, a.start + a.seeds))
    rows, seeds = resume(a.out, seeds)
    t0 = time.time()

    def record(row):
        rows.append(row)
        if "simulate" in methods:
            print(f"seed {row['seed']}: simulated ({row['seconds']:.0f} s)", flush=True)
            return
        line = (f"seed {row['seed']}: " + ", ".join(
            f"{p} {o} {np.mean(np.abs(row[f'{p}_{o}_z']) <= 1.96):.2f}" for p in ("wls", "essential") for o in options
            if f"{p}_{o}_z" in row)
            + "".join(f", {k[:-7].replace('_', ' ')} {np.mean(v):.2f}" for k, v in row.items()
                      if k.startswith("pc") and k.endswith("_inside"))
            + "".join(f", didim {o} {np.mean(np.abs(row[f'didim_{o}_z']) <= 1.96):.2f}" for o in OPTIONS
                      if f"didim_{o}_z" in row)
            + "".join(f", didim failed ({row['didim_error']})" for _ in [0] if "didim_error" in row)
            + f" ({row['seconds']:.0f} s)")
        print(line, flush=True)
        append(a.out, row)

    if a.workers > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(a.workers) as ex:
            for row in ex.map(run_seed, seeds, [methods] * len(seeds), [a.cache] * len(seeds),
                              [options] * len(seeds), [pc_options] * len(seeds), [candidates] * len(seeds)):
                record(row)
    else:
        for s in seeds:
            record(run_seed(s, methods, a.cache, options, pc_options, candidates))
    if "simulate" in methods:
        return
    if "candidates" in methods:
        from uncertainty import CANDIDATES
        options = options + (tuple(CANDIDATES) if candidates is None else candidates)
    out = headline(rows, options)
    out.update({"duration_s": DURATION, "log_rate_hz": RATE / LOG_EVERY, "ar1": PHI, "noise_std": NOISE,
                "ripple": RIPPLE, "campaign_seconds": time.time() - t0, "first_seed": a.start})
    print(json.dumps(out))


if __name__ == "__main__":
    main()
