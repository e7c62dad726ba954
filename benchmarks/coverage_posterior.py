"""Coverage of the posterior's 95 % credible intervals on the independent closed-loop plant (issue 26).

The plant, the record and the truth are those of ``benchmarks/coverage_independent.py``
(imported from it: ``tests/support/independent_plant.py``, TX40 Table 2 with the coupled wrist,
controller at 5 kHz logged at 1 kHz, ``DURATION`` s, torque noise AR(1) with coefficient
``PHI`` at the logging rate, and a position ripple on joint 1 the model does not have).
For each seed dynid's IDIM runs once, then ``sample_idim`` samples (emcee) the
posterior of the essential parameters (the default of ``dynid sample``) with each noise model
of ``--noise`` (``sandwich``, the default, and ``neff``); ``--which base,essential`` samples the
base parameters too (66 dimensions: minutes per chain on a loaded machine). Beside it, for the
base and the essential parameters, the Gaussian closed form of each posterior (``sandwich``,
``neff``, ``white``) with σ_j fixed at the WLS σ_j (``known_noise_posterior`` of the model's
statistics; ``closed_*`` keys): the sampler's draws match it (tests/analysis/sampling), and it
costs nothing, so both sets are covered on every seed. Coverage: the fraction of (parameter,
seed) pairs whose equal-tailed 95 % interval holds the truth; width: the interval over the
classic WLS interval 2 · 1.96 · σ_WLS of the same parameters (median). Chains that did not
converge are counted. The cause keys (``*_rms_z_bias``, ``*_rms_z_noise_part``): the same WLS
on the seed's noise-free torque (same trajectory, rows and weights) is the pseudo-true value;
the rms over (parameter, seed) of (pseudo − truth)/σ is the model's bias (removed parameters,
ripple, coupled wrist), of (estimate − pseudo)/σ the noise part (1 for a calibrated σ without bias).

Seeds below 1000 were used while developing ``neff``, 5000-5099 held out for it (neff: base
94.3 %, essential 85.1 %); 7000-7049 were used while developing ``sandwich`` (issue 26, the
essential posterior's under-coverage), 7500-7599 held out for it (results/coverage_posterior_7500.txt:
closed forms, sandwich base 93.9 % at 1.36 times the classic width, essential 93.7 % at 1.91;
neff 94.5 % and 85.5 %; results/coverage_posterior_7500_emcee.txt: emcee, sandwich, essential,
seeds 7500-7548, 94.7 % at 2.07, all converged):

    cd benchmarks
    nice -n 10 ../.venv/bin/python coverage_posterior.py --seeds 100 --start 7500 --workers 1 \
        --which "" --out results/coverage_posterior_7500.jsonl
    nice -n 10 ../.venv/bin/python coverage_posterior.py --seeds 100 --start 7500 --noise sandwich \
        --tau-multiple 20 --out results/coverage_posterior_7500_emcee.jsonl

(the first: closed forms only; the second: emcee as well, stopped after 49 seeds). The same
closed forms on 5000-5099 (results/coverage_posterior_5000_sandwich.txt, ``--start 5000
--workers 2``): sandwich base 93.8 % (1.35), essential 94.5 % (1.85); neff 94.3 % and 85.1 %.

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
from campaign_rows import append, resume

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "benchmarks", ROOT / "tests" / "support"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

import coverage_independent as ci  # noqa: E402  (the same plant, record and truth)

NOISES = ("sandwich", "neff", "white")
WHICH = ("essential",)


def record(seed, noise_free=False):
    """The seed's record, as coverage_independent.run_seed makes it (`noise_free`: the same
    trajectory's torque without the AR(1) noise, for the pseudo-true values)."""
    import independent_plant as ip

    from dynid.analysis.data.experiment import Experiment
    plant = ip.tx40_plant("table2", coupled_wrist=True,
                          effects=[ip.position_ripple(ci.RIPPLE["joint"], ci.RIPPLE["A"], ci.RIPPLE["k"])])
    rec = ip.run(plant, ci.DURATION, ci.RATE, seed, sensor=ip.Sensor(tau_noise=0.0),
                 log_every=ci.LOG_EVERY, n_harmonics=10)
    rng = np.random.default_rng(10_000 + seed)
    tau = rec["tau"] + ci.ar1_noise(rng, rec["tau"].shape, ci.PHI, ci.NOISE)
    exp = Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=tau, fs=rec["rate"],
                     source=f"independent plant seed {seed}", name=f"cov-{seed}")
    if not noise_free:
        return exp
    return exp, Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=rec["tau"], fs=rec["rate"],
                           source=f"independent plant seed {seed}, noise-free", name=f"cov0-{seed}")


def run_seed(seed, which=WHICH, noises=NOISES, tau_multiple=50.0, sample=True):
    from dynid.analysis.estimators import least_squares as lsq
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.processing.observation import observe
    from dynid.analysis.sampling.noise import noise_model, sandwich_model, temper
    from dynid.analysis.sampling.posterior import known_noise_posterior, sample_idim, sufficient_statistics
    from dynid.analysis.sampling.sample import idim_robust_cov
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    t0 = time.time()
    exp, exp0 = record(seed, noise_free=True)
    robot = load_robot("tx40")
    bp = base_parameters(robot)
    beta = ci.truth(robot, bp)
    res = identify_idim(exp, robot, bp=bp)
    row = {"seed": seed, "sim_idim_seconds": time.time() - t0}
    obs = res.observation
    obs0 = observe(exp0, robot, bp, obs.settings)
    for w in ("base", "essential"):
        ls = res.wls if w == "base" else res.essential.result
        idx = [bp.names.index(n) for n in ls.names]
        W = obs.W[:, :, res.columns(ls.names)]
        st = sufficient_statistics(W, obs.tau, ls.names, row_mask=obs.row_mask, ref=ls.chi)
        # the cause: the same WLS on the noise-free torque (pseudo-true) splits the error
        # into the model's bias (pseudo - truth) and the noise part (estimate - pseudo)
        pseudo = lsq.wls(obs0.W[:, :, res.columns(ls.names)], obs0.tau, ls.names, row_mask=obs.row_mask,
                         joint_sigma=ls.joint_sigma).chi
        row[f"{w}_bias"] = [float(v) for v in pseudo - beta[idx]]
        row[f"{w}_noise_part"] = [float(v) for v in ls.chi - pseudo]
        for nz in NOISES:
            if nz == "sandwich":
                nm = sandwich_model(st, idim_robust_cov(res, w)[0], ls.joint_sigma)
            else:
                nm = noise_model(nz, W, obs.tau, obs.row_mask, ls.chi)
            mean, cov = known_noise_posterior(temper(st, nm), ls.joint_sigma)
            row[f"closed_{w}_{nz}_sd"] = [float(v) for v in np.sqrt(np.diag(cov))]
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
            if nz == "neff" and "tau_int" in post.settings["noise_model"]:
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
                rb = [r for r in rows if f"{w}_bias" in r and f"{k}_sd" in r]
                if rb:
                    sd = np.concatenate([r[f"{k}_sd"] for r in rb])
                    out[f"{k}_rms_z_bias"] = float(np.sqrt(np.mean((np.concatenate(
                        [r[f"{w}_bias"] for r in rb]) / sd) ** 2)))
                    out[f"{k}_rms_z_noise_part"] = float(np.sqrt(np.mean((np.concatenate(
                        [r[f"{w}_noise_part"] for r in rb]) / sd) ** 2)))
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
    ap.add_argument("--noise", default="sandwich,neff", help="noise models sampled, comma-separated: "
                    "sandwich, neff, white (the closed forms are computed for all)")
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
        append(a.out, row)

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
