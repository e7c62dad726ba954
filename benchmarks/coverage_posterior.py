"""Coverage of the posterior's 95 % credible intervals on the independent closed-loop plant (issue 26).

The plant, the record and the truth are those of ``benchmarks/coverage_independent.py``
(imported from it: ``tests/support/independent_plant.py``, TX40 Table 2 with the coupled wrist,
controller at 5 kHz logged at 1 kHz, ``DURATION`` s, torque noise AR(1) with coefficient
``PHI`` at the logging rate, and a position ripple on joint 1 the model does not have).
For each seed dynid's default IDIM runs once, then ``sample_idim`` samples (emcee) the
posterior of the essential parameters (the default of ``dynid sample``) with each noise model
(``neff``, the default, and ``white``); ``--which base,essential`` samples the base parameters
too (66 dimensions: minutes per chain on a loaded machine). Beside it, for the base and the
essential parameters, the Gaussian closed form of each posterior with σ_j fixed at the WLS
σ_j (``known_noise_posterior`` of the tempered statistics; ``closed_*`` keys): the sampler's
draws match it (tests/analysis/sampling), and it costs nothing, so the base parameters (no
selection bias: the noise model's own test) are covered on every seed. Coverage: the fraction of (parameter, seed) pairs whose equal-tailed
95 % interval holds the truth; width: the interval over the classic WLS interval
2 · 1.96 · σ_WLS of the same parameters (median). Chains that did not converge are counted.

Seeds below 1000 were used while developing the noise model; 5000-5099 are held out:

    nice -n 10 python benchmarks/coverage_posterior.py --seeds 100 --start 5000 --workers 2 \\
        --out benchmarks/results/coverage_posterior.jsonl

The last line is a JSON object with the headline figures.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from campaign_rows import resume

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "benchmarks", ROOT / "tests" / "support"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

import coverage_independent as ci  # noqa: E402  (the same plant, record and truth)

NOISES = ("neff", "white")
WHICH = ("essential",)


def record(seed):
    """The seed's record, as coverage_independent.run_seed makes it."""
    import independent_plant as ip

    from dynid.analysis.data.experiment import Experiment
    plant = ip.tx40_plant("table2", coupled_wrist=True,
                          effects=[ip.position_ripple(ci.RIPPLE["joint"], ci.RIPPLE["A"], ci.RIPPLE["k"])])
    rec = ip.run(plant, ci.DURATION, ci.RATE, seed, sensor=ip.Sensor(tau_noise=0.0),
                 log_every=ci.LOG_EVERY, n_harmonics=10)
    rng = np.random.default_rng(10_000 + seed)
    tau = rec["tau"] + ci.ar1_noise(rng, rec["tau"].shape, ci.PHI, ci.NOISE)
    return Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=tau, fs=rec["rate"],
                      source=f"independent plant seed {seed}", name=f"cov-{seed}")


def run_seed(seed, which=WHICH, noises=NOISES, tau_multiple=50.0, sample=True):
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.sampling.noise import noise_model, temper
    from dynid.analysis.sampling.posterior import known_noise_posterior, sample_idim, sufficient_statistics
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    t0 = time.time()
    exp = record(seed)
    robot = load_robot("tx40")
    bp = base_parameters(robot)
    beta = ci.truth(robot, bp)
    res = identify_idim(exp, robot, bp=bp)
    row = {"seed": seed, "sim_idim_seconds": time.time() - t0}
    obs = res.observation
    for w in ("base", "essential"):
        ls = res.wls if w == "base" else res.essential.result
        idx = [bp.names.index(n) for n in ls.names]
        W = obs.W[:, :, res.columns(ls.names)]
        st = sufficient_statistics(W, obs.tau, ls.names, row_mask=obs.row_mask, ref=ls.chi)
        for nz in NOISES:
            nm = noise_model(nz, W, obs.tau, obs.row_mask, ls.chi)
            mean, cov = known_noise_posterior(temper(st, nm), ls.joint_sigma)
            half = 1.96 * np.sqrt(np.diag(cov))
            row[f"closed_{w}_{nz}_inside"] = [bool(v) for v in np.abs(mean - beta[idx]) <= half]
            row[f"closed_{w}_{nz}_width_vs_classic"] = [float(v) for v in half / (1.96 * ls.bse.to_numpy())]
        row[f"closed_{w}_classic_inside"] = [bool(v) for v in np.abs(ls.chi - beta[idx]) <= 1.96 * ls.bse.to_numpy()]
    if not sample:
        which = ()
    for w in which:
        ls = res.wls if w == "base" else res.essential.result
        idx = [bp.names.index(n) for n in ls.names]
        truth = beta[idx]
        classic = 2 * 1.96 * ls.bse.to_numpy()
        for nz in noises:
            t = time.time()
            post = sample_idim(res, which=w, seed=seed, noise=nz, criteria={"tau_multiple": tau_multiple})
            b = len(ls.names)
            ci95 = post.ci95[:b]
            key = f"{w}_{nz}"
            row[f"{key}_inside"] = [bool(v) for v in (ci95[:, 0] <= truth) & (truth <= ci95[:, 1])]
            row[f"{key}_width_vs_classic"] = [float(v) for v in (ci95[:, 1] - ci95[:, 0]) / classic]
            row[f"{key}_converged"] = bool(post.converged)
            row[f"{key}_steps"] = int(post.n_steps)
            row[f"{key}_seconds"] = time.time() - t
            if nz == "neff":
                row[f"{w}_tau_int"] = [float(v) for v in post.settings["noise_model"]["tau_int"]]
        row[f"{w}_classic_inside"] = [bool(v) for v in np.abs(ls.chi - truth) <= 1.96 * ls.bse.to_numpy()]
    row["seconds"] = time.time() - t0
    return row


def headline(rows, which=WHICH, noises=NOISES):
    out = {"seeds": len(rows)}
    for w in ("base", "essential"):
        for nz in NOISES:
            k = f"closed_{w}_{nz}"
            if any(f"{k}_inside" in r for r in rows):
                rc = [r for r in rows if f"closed_{w}_classic_inside" in r]
                out[f"closed_{w}_classic_wls_coverage95"] = float(np.mean(np.concatenate(
                    [r[f"closed_{w}_classic_inside"] for r in rc]))) if rc else None
                out[f"{k}_coverage95"] = float(np.mean(np.concatenate([r[f"{k}_inside"] for r in rows])))
                out[f"{k}_median_width_vs_classic"] = float(np.median(np.concatenate(
                    [r[f"{k}_width_vs_classic"] for r in rows])))
    for w in which:
        if not any(f"{w}_classic_inside" in r for r in rows):
            continue
        rr = [r for r in rows if f"{w}_classic_inside" in r]
        out[f"{w}_sampled_seeds"] = len(rr)
        out[f"{w}_classic_wls_coverage95"] = float(np.mean(np.concatenate([r[f"{w}_classic_inside"] for r in rr])))
        for nz in noises:
            k = f"{w}_{nz}"
            rk = [r for r in rr if f"{k}_inside" in r]
            if not rk:
                continue
            out[f"{k}_coverage95"] = float(np.mean(np.concatenate([r[f"{k}_inside"] for r in rk])))
            out[f"{k}_median_width_vs_classic"] = float(np.median(np.concatenate(
                [r[f"{k}_width_vs_classic"] for r in rk])))
            out[f"{k}_not_converged"] = int(sum(not r[f"{k}_converged"] for r in rk))
            ok = [r for r in rk if r[f"{k}_converged"]]
            if ok and len(ok) < len(rk):
                out[f"{k}_coverage95_converged_only"] = float(np.mean(np.concatenate([r[f"{k}_inside"] for r in ok])))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--which", default=",".join(WHICH), help="comma-separated: base, essential")
    ap.add_argument("--noise", default=",".join(NOISES), help="comma-separated: neff, white")
    ap.add_argument("--tau-multiple", type=float, default=50.0,
                    help="convergence rule: chain after burn-in >= this many autocorrelation times")
    ap.add_argument("--sample-every", type=int, default=1, metavar="K",
                    help="run the sampler on every K-th seed only (the closed forms on all): "
                         "the plant and the chains of every seed do not fit a shared 2-core machine")
    ap.add_argument("--out", default=None, help="JSON lines, one per seed (appended; seeds done are skipped)")
    a = ap.parse_args(argv)
    which = tuple(x.strip() for x in a.which.split(",") if x.strip())
    noises = tuple(x.strip() for x in a.noise.split(",") if x.strip())
    seeds = list(range(a.start, a.start + a.seeds))
    rows, seeds = resume(a.out, seeds)
    t0 = time.time()

    def keep(row):
        rows.append(row)
        print(f"seed {row['seed']}: " + ", ".join(
            f"{w} {nz} {np.mean(row[f'{w}_{nz}_inside']):.2f}" for w in which for nz in noises
            if f"{w}_{nz}_inside" in row)
            + "".join(f", closed base {nz} {np.mean(row[f'closed_base_{nz}_inside']):.2f}" for nz in NOISES)
            + "".join(f", {w} classic {np.mean(row[f'closed_{w}_classic_inside']):.2f}" for w in which)
            + f" ({row['seconds']:.0f} s)", flush=True)
        if a.out:
            with open(a.out, "a") as f:
                f.write(json.dumps(row) + "\n")

    args = [(s, which, noises, a.tau_multiple, (s - a.start) % a.sample_every == 0) for s in seeds]
    if a.workers > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(a.workers) as ex:
            for row in ex.map(run_seed, *zip(*args)):
                keep(row)
    else:
        for arg in args:
            keep(run_seed(*arg))
    out = headline(rows, which, noises)
    out.update({"duration_s": ci.DURATION, "log_rate_hz": ci.RATE / ci.LOG_EVERY, "ar1": ci.PHI,
                "noise_std": ci.NOISE, "ripple": ci.RIPPLE, "tau_multiple": a.tau_multiple,
                "sample_every": a.sample_every, "campaign_seconds": time.time() - t0, "first_seed": a.start,
                "last_seed": a.start + a.seeds - 1})
    print(json.dumps(out))


if __name__ == "__main__":
    main()
