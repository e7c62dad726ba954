"""Benchmark of the Bayesian posterior (dynid.analysis.sampling.posterior).

1. The simulated TX40 of the demo (dynid.analysis.demo.demo_data(1, 20 s)), identified
   by IDIM; emcee on its essential parameters plus one noise level per joint
   (6), 64 walkers, run until the chain after burn-in is >= 50 integrated
   autocorrelation times long for every parameter (dynid.analysis.sampling.convergence).
   Target: under 30 s for the sampling.
2. Cost does not grow with the number of samples: a 6-joint, 25-parameter
   system with 1 k and 1 M rows (equations). Time to compute the sufficient
   statistics once (one pass over the rows), and time per vectorised
   log-probability evaluation of 64 walkers from those statistics (must be
   the same for both), against a naive evaluation that recomputes the
   residuals over every row.

Times are also printed as ratios to a reference workload run in the same
process (a fixed 1500x1500 matrix product), since the machines are noisy.

Issue 30's figure, sampling time / (steps x 2 log-prob calls of 64 walkers), is printed on
wall time and on the process's CPU time (user + system): on a shared machine the wall time
of the run is its CPU time plus the time it waited in the run queue for a core (Linux
/proc/self/schedstat, printed with the voluntary context switches, which count sleeps, I/O,
locks and thread pools: none, so the difference is the other processes' load). A floor:
emcee's own step and dynid's step on a trivial vectorised log-prob of the same dimension and
walkers (the sampler's cost without the posterior).
The sampler's compiled kernels (dynid.analysis.sampling.draws) are loaded from numba's cache
(compiled on the first run of an installation) before the timed run, and that time is printed
beside it, with the figure that includes it. The sampling CPU is split into the log-prob calls,
the stepping (draws, proposals, acceptance, storage), the convergence checks and the setup.
The last line is a JSON object with the headline figures.
Run from the repository root: python benchmarks/bayes.py [--seed S] [--rows-large N]
"""
import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")     # CPU times below are one thread's

import argparse
import json
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402


def reference_seconds():
    a = np.random.default_rng(0).standard_normal((1500, 1500))
    t0 = time.perf_counter()
    for _ in range(3):
        a @ a
    return (time.perf_counter() - t0) / 3


def best_of(fn, repeat=5, number=1):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def usage():
    """(wall, user + system CPU, system CPU, run-queue wait, voluntary and involuntary switches)."""
    t, ru = os.times(), resource.getrusage(resource.RUSAGE_SELF)
    try:
        with open("/proc/self/schedstat") as f:       # on-CPU ns, run-queue wait ns, slices (Linux)
            wait = int(f.read().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        wait = float("nan")
    return np.array([time.perf_counter(), t.user + t.system, t.system, wait, ru.ru_nvcsw, ru.ru_nivcsw])


class _Timed:
    """Wraps LinearPosterior.log_prob to add up the CPU time spent inside it during a run."""

    def __init__(self, cls):
        self.cls, self.orig, self.cpu, self.calls = cls, cls.log_prob, 0.0, 0

    def __enter__(self):
        orig = self.orig

        def log_prob(model, X):
            t0 = time.process_time()
            try:
                return orig(model, X)
            finally:
                self.cpu += time.process_time() - t0
                self.calls += 1
        self.cls.log_prob = log_prob
        return self

    def __exit__(self, *exc):
        self.cls.log_prob = self.orig


class _Sections:
    """CPU time spent inside some module functions during a run, one bucket per group (a call
    nested in another of the same group is not counted twice)."""

    def __init__(self, groups):
        self.groups, self.cpu, self._saved = groups, {g: 0.0 for g in groups}, []

    def __enter__(self):
        for group, targets in self.groups.items():
            depth = [0]
            for mod, name in targets:
                orig = getattr(mod, name)

                def wrapped(*a, _orig=orig, _group=group, _depth=depth, **k):
                    _depth[0] += 1
                    t0 = time.process_time()
                    try:
                        return _orig(*a, **k)
                    finally:
                        _depth[0] -= 1
                        if _depth[0] == 0:
                            self.cpu[_group] += time.process_time() - t0
                self._saved.append((mod, name, orig))
                setattr(mod, name, wrapped)
        return self

    def __exit__(self, *exc):
        for mod, name, orig in reversed(self._saved):
            setattr(mod, name, orig)


def warm_up():
    """Load (or, on a fresh installation, compile) the sampler's numba kernels: (seconds, compiled)."""
    from dynid.analysis.sampling import draws
    from dynid.analysis.sampling.ensemble import make_sampler

    t0 = time.perf_counter()
    sampler = make_sampler(lambda X: -0.5 * np.einsum("ij,ij->i", X, X), 8, 2, "de", np.random.default_rng(0))
    for _ in sampler.advance(np.random.default_rng(1).standard_normal((8, 2)), 2):
        pass
    compiled = any(sum(f.stats.cache_misses.values()) for f in (draws._de_draws, draws.propose, draws.accept))
    return time.perf_counter() - t0, compiled


def tx40(seed, noise=None):
    from dynid.analysis.demo import demo_data
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.sampling import convergence, sample
    from dynid.analysis.sampling import posterior as bayes

    t0 = time.perf_counter()
    robot, bp, beta, ident, valid = demo_data(1, 20.0)
    res = identify_idim(ident, robot, bp=bp)
    prep = time.perf_counter() - t0
    # after the identification, as in dynid sample: numba itself is loaded by then (its
    # start-up, ~0.2 s, is the identification's), only the sampler's kernels remain
    warm = warm_up()
    u0 = usage()
    sections = _Sections({"run": [(sample, "run_until_converged")],
                          "checks": [(convergence, "diagnose"), (convergence, "_kept_rank_rhat")]})
    with _Timed(bayes.LinearPosterior) as timed, sections:
        post = bayes.sample_idim(res, seed=seed, n_walkers=64, **({} if noise is None else {"noise": noise}))
    use = usage() - u0
    timed.sections = sections.cpu
    return prep, use[0], post, use[1], timed, use, warm


def scaling_setup(n_rows, n_joints=6, b=25, walkers=64, seed=0):
    """A system of n_rows equations (n_rows / n_joints samples); (stats_s, model, X, naive_s)."""
    from dynid.analysis.sampling import posterior as bayes

    rng = np.random.default_rng(seed)
    N = n_rows // n_joints
    W3 = rng.standard_normal((N, n_joints, b))
    chi = rng.standard_normal(b)
    tau = W3 @ chi + 0.1 * rng.standard_normal((N, n_joints))
    names = [f"p{i}" for i in range(b)]
    t_stats = best_of(lambda: bayes.sufficient_statistics(W3, tau, names, ref=chi), repeat=3 if N > 1e4 else 7)
    st = bayes.sufficient_statistics(W3, tau, names, ref=chi)
    model = bayes.LinearPosterior(st)
    X = np.hstack([chi + 0.01 * rng.standard_normal((walkers, b)),
                   np.log(0.1) + 0.01 * rng.standard_normal((walkers, n_joints))])

    def naive():                               # residuals of every row, every walker
        u = X[:, b:]
        out = np.zeros(walkers)
        for j in range(n_joints):
            R = tau[:, j][None, :] - X[:, :b] @ W3[:, j, :].T   # (walkers, N)
            out += -N * u[:, j] - 0.5 * np.einsum("kn,kn->k", R, R) * np.exp(-2 * u[:, j])
        return out

    t_naive = best_of(naive, repeat=3 if N > 1e4 else 7)
    np.testing.assert_allclose(naive(), model.log_prob(X), rtol=1e-7)
    return t_stats, model, X, t_naive


def logprob_times(models, rounds=25, number=200):
    """Best wall and best CPU time per log_prob call of each (model, X), measured alternately
    (fair under load): ([wall...], [cpu...])."""
    best = [np.inf] * len(models)
    best_cpu = [np.inf] * len(models)
    for _ in range(rounds):
        for i, (model, X) in enumerate(models):
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(number):
                model.log_prob(X)
            best[i] = min(best[i], (time.perf_counter() - t0) / number)
            best_cpu[i] = min(best_cpu[i], (time.process_time() - c0) / number)
    return best, best_cpu


def sampler_floor(dims, walkers=64, steps=1000, rounds=3):
    """CPU seconds per step of emcee's own sampler (DEMove, vectorize=True, store=False) and of
    dynid's (dynid.analysis.sampling.ensemble) on a trivial vectorised log-prob of `dims`
    dimensions: what stepping costs without the posterior. Best of `rounds`, alternately."""
    import emcee

    from dynid.analysis.sampling.ensemble import make_sampler

    def trivial(X):
        return -0.5 * np.einsum("ij,ij->i", X, X)

    p0 = np.random.default_rng(0).standard_normal((walkers, dims))
    best = {"emcee": np.inf, "dynid": np.inf}
    for _ in range(rounds):
        ref = emcee.EnsembleSampler(walkers, dims, trivial, vectorize=True, moves=emcee.moves.DEMove())
        ref.random_state = np.random.RandomState(1).get_state()
        c0 = time.process_time()
        ref.run_mcmc(p0, steps, store=False)
        best["emcee"] = min(best["emcee"], (time.process_time() - c0) / steps)
        ours = make_sampler(trivial, walkers, dims, "de", np.random.default_rng(1))
        c0 = time.process_time()
        for _ in ours.advance(p0, steps, check=True):
            pass
        best["dynid"] = min(best["dynid"], (time.process_time() - c0) / steps)
    return best


def loadavg():
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rows-large", type=int, default=1_000_000)
    ap.add_argument("--noise", choices=["sandwich", "neff", "white"], default=None,
                    help="the posterior's noise model (default: the library's)")
    args = ap.parse_args()
    ref = reference_seconds()
    print(f"reference workload (1500x1500 matmul): {ref * 1e3:.1f} ms")

    load0 = loadavg()
    prep, sampling, post, cpu, timed, use, (warm_s, compiled) = tx40(args.seed, args.noise)
    load1 = loadavg()
    dg = post.diagnostics
    print(f"TX40 demo (20 s at 5 kHz): simulation + IDIM {prep:.1f} s (not counted)")
    print(f"sampler kernels {'compiled (first run of this installation)' if compiled else 'loaded from numba cache'}"
          f" in {warm_s:.3f} s (not counted in the sampling time; once per process, compiled once per installation)")
    print(f"emcee on {len(post.names) - 6} essential parameters + 6 noise levels = {len(post.names)} "
          f"dimensions, {dg.n_walkers} walkers: {sampling:.2f} s (target 30 s; {sampling / ref:.0f} x "
          f"reference), {dg.n_steps} steps, {1e6 * dg.elapsed / dg.n_steps:.0f} us/step")
    print(f"  converged: {post.converged} - {dg.reason}")
    print(f"  max tau {dg.tau_max:.1f} steps, chain after burn-in / max tau = {dg.chain_over_tau:.1f}, "
          f"max split R-hat {dg.rhat_max:.4f}, acceptance {dg.acceptance_mean:.3f}, "
          f"{post.n_samples} kept draws (burn-in {dg.burn_in}, thin {dg.thin}), "
          f"tau history {[(int(n), round(t, 1)) for n, t in dg.history]}")
    worst = int(np.nanargmax(np.abs(post.mean - post.ls_value)[:len(post.names) - 6] /
                             post.std[:len(post.names) - 6]))
    print(f"  largest |posterior mean - WLS| / posterior std: {post.names[worst]} "
          f"{abs(post.mean[worst] - post.ls_value[worst]) / post.std[worst]:.3f}")
    print(f"  where the wall time went: {sampling:.2f} s wall = {cpu:.2f} s on CPU (of which system "
          f"{use[2]:.2f} s) + {use[3]:.2f} s waiting in the run queue for a core (+ {sampling - cpu - use[3]:.2f} s "
          f"else); {int(use[4])} voluntary context switches (sleep, I/O, locks, thread pools), "
          f"{int(use[5])} involuntary (preempted); load average {load0:.1f} before, {load1:.1f} after")
    chain_hash = __import__("hashlib").sha256(np.ascontiguousarray(post.chain).tobytes()).hexdigest()[:16]
    print(f"  chain sha256 {chain_hash} (same seed, same chain bit for bit)")

    rows = [1000, args.rows_large]
    setups = {r: scaling_setup(r) for r in rows}
    lp, lp_cpu = logprob_times([(setups[r][1], setups[r][2]) for r in rows])
    res = {r: (setups[r][0], lp[i], setups[r][3]) for i, r in enumerate(rows)}
    for r in rows:
        s, t, nv = res[r]
        print(f"{r:>9,} rows (6 joints x {r // 6:,} samples, 25 parameters): sufficient statistics once "
              f"{s * 1e3:8.2f} ms; log-prob of 64 walkers from them {t * 1e6:6.1f} us; "
              f"naive log-prob over the rows {nv * 1e3:8.2f} ms")
    small, large = res[rows[0]], res[rows[1]]
    ratio = large[1] / small[1]
    # issue 30's figure: the sampling time over its log-probability work (2 calls of 64 walkers a
    # step, measured alone on statistics of the same shape, 25 parameters x 6 joints)
    step_ratio = sampling / (dg.n_steps * 2 * small[1])
    print(f"sampling time / (steps x 2 log-prob calls of 64 walkers): {step_ratio:.1f} "
          f"({(sampling + warm_s) / (dg.n_steps * 2 * small[1]):.1f} with the kernels' loading)")
    # the same on CPU time, numerator and denominator: what the run costs without the run-queue wait
    step_ratio_cpu = cpu / (dg.n_steps * 2 * lp_cpu[0])
    print(f"sampling CPU time / (steps x 2 log-prob calls of 64 walkers, CPU {lp_cpu[0] * 1e6:.1f} us each): "
          f"{step_ratio_cpu:.1f}")
    floor = sampler_floor(len(post.names))
    work = 2 * lp_cpu[0]
    print(f"stepping alone (trivial log-prob, {len(post.names)} dimensions, 64 walkers), CPU per step: emcee's own "
          f"sampler {floor['emcee'] * 1e6:.0f} us = {floor['emcee'] / work:.1f} x the log-prob work of a step; "
          f"dynid's {floor['dynid'] * 1e6:.0f} us = {floor['dynid'] / work:.1f} x")
    # the same ratio from CPU time measured inside the run (robust on a loaded, shared machine):
    # the sampling's CPU time over the CPU time of its own log-prob calls
    inrun = cpu / timed.cpu if timed.cpu > 0 else float("nan")
    print(f"sampling CPU {cpu:.2f} s / CPU inside its {timed.calls} log-prob calls {timed.cpu:.2f} s: {inrun:.1f}")
    sec = timed.sections
    setup_cpu = cpu - sec["run"]
    stepping_cpu = sec["run"] - sec["checks"] - timed.cpu
    print(f"where the sampling CPU went: log-prob {timed.cpu:.2f} s, stepping (draws, proposals, acceptance, "
          f"storage) {stepping_cpu:.2f} s, convergence checks {sec['checks']:.2f} s, setup and result "
          f"(noise model, start, summary) {setup_cpu:.2f} s; in units of the in-run log-prob CPU: 1 + "
          f"{stepping_cpu / timed.cpu:.2f} + {sec['checks'] / timed.cpu:.2f} + {setup_cpu / timed.cpu:.2f}")
    print(f"log-prob time ratio {rows[1]:,} / {rows[0]:,} rows: {ratio:.2f} (same code on statistics of "
          f"identical shape: (6, 25, 25) + (6, 25) + (6,)); statistics pass ratio "
          f"{large[0] / small[0]:.0f} (linear in the rows, paid once)")
    print(json.dumps({
        "tx40_dims": len(post.names), "tx40_walkers": dg.n_walkers, "tx40_sampling_s": round(sampling, 2),
        "tx40_ratio_to_reference": round(sampling / ref, 1), "tx40_steps": dg.n_steps,
        "tx40_us_per_step": round(1e6 * dg.elapsed / dg.n_steps), "tx40_converged": post.converged,
        "tx40_sampling_over_logprob_work": round(step_ratio, 2),
        "tx40_sampling_cpu_over_logprob_cpu_work": round(step_ratio_cpu, 2),
        "tx40_runqueue_wait_s": round(float(use[3]), 2), "tx40_system_cpu_s": round(float(use[2]), 2),
        "tx40_voluntary_switches": int(use[4]), "load_average": round(load0, 1),
        "emcee_step_us_trivial_logprob": round(floor["emcee"] * 1e6, 1),
        "dynid_step_us_trivial_logprob": round(floor["dynid"] * 1e6, 1),
        "emcee_step_over_logprob_work": round(floor["emcee"] / work, 2),
        "tx40_chain_sha256": chain_hash,
        "tx40_cpu_over_inrun_logprob_cpu": round(inrun, 2), "tx40_sampling_cpu_s": round(cpu, 2),
        "tx40_logprob_cpu_s": round(timed.cpu, 3), "tx40_stepping_cpu_s": round(stepping_cpu, 3),
        "tx40_checks_cpu_s": round(sec["checks"], 3), "tx40_setup_cpu_s": round(setup_cpu, 3),
        "kernels_warm_up_s": round(warm_s, 2), "kernels_compiled": compiled,
        "tx40_sampling_with_warm_up_over_logprob_work": round((sampling + warm_s) / (dg.n_steps * 2 * small[1]), 2),
        "tx40_noise_model": post.settings.get("noise_model", {}).get("kind", "white"),
        "tx40_tau_max": round(dg.tau_max, 1), "tx40_chain_over_tau": round(dg.chain_over_tau, 1),
        "tx40_rhat_max": round(dg.rhat_max, 4), "tx40_acceptance": round(dg.acceptance_mean, 3),
        "logprob_us_1k_rows": round(small[1] * 1e6, 1), "logprob_cpu_us_1k_rows": round(lp_cpu[0] * 1e6, 1), "logprob_us_large_rows": round(large[1] * 1e6, 1),
        "large_rows": rows[1], "logprob_ratio_large_to_1k": round(ratio, 2),
        "stats_ms_1k_rows": round(small[0] * 1e3, 3), "stats_ms_large_rows": round(large[0] * 1e3, 1),
        "naive_logprob_ms_large_rows": round(large[2] * 1e3, 1), "reference_s": round(ref, 4),
    }))


if __name__ == "__main__":
    main()
