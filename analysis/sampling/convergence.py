"""Convergence of ensemble MCMC runs, decided from the chain and never assumed.

`run_until_converged` drives an `emcee.EnsembleSampler` in
batches and stops when the chain is long enough for every sampled parameter,
or when a step or wall-clock limit is hit. The result carries
`converged=False` and the reason whenever the rule was not met; nothing
downstream reports such a run as if it had converged.

The rule (all of it must hold, on the *sampled* parameters)
-----------------------------------------------------------
1. Integrated autocorrelation time τ_i of every parameter (emcee's
   `emcee.autocorr.integrated_time` with `tol=0`, i.e. the estimate
   of Goodman & Weare / Sokal with the automatic window c = 5, averaged over
   walkers as emcee does) is finite, and the chain after burn-in is at least
   `tau_multiple` (default 50) times max_i τ_i long.
2. Burn-in = `ceil(burn_in_tau * max τ)` steps (default 5 τ). τ is first
   estimated on the whole chain (inflated by the initial transient, hence
   conservative), the burn-in is discarded, and τ is estimated again on the
   rest; rule 1 uses this second estimate.
3. Split-chain R̂ < `rhat_max` (default 1.05) for every parameter, on the
   chain after burn-in (formula in `split_rhat`).
4. Mean acceptance fraction ≥ `min_acceptance` (default 0.05) and no walker
   is stuck (acceptance < `min_walker_acceptance`, default 0.01).

Why R̂ < 1.05 and not 1.01: the "chains" of an ensemble sampler are single
walkers. A walker of length L (after burn-in) split in halves has about
L / (2τ) independent draws per half, and for a stationary chain R̂ ≈
sqrt(1 + 2τ/L) − small terms; at L = 50 τ that is ≈ 1.02. A threshold of
1.01 would therefore demand ~100 τ; 1.05 still flags walkers that disagree
(a stuck or separated walker gives R̂ ≫ 1.05).

Thinning: thin = max(1, floor(`thin_tau` * max τ)) steps (default τ / 2),
so consecutive kept draws of a walker are still mildly correlated; effective
sample sizes are computed from τ on the unthinned chain:
ESS_i = n_walkers · (n_steps − burn_in) / τ_i.

Storage. Positions are kept in a buffer of at most `max_stored` steps: when
it is full, every other stored step is dropped and the storage interval
doubles (so memory does not grow with the chain length and the spacing stays
≤ ~L / (max_stored / 2) ≪ τ at convergence). τ is computed on the stored
chain and multiplied by the storage interval.

Batches. The first batch is `first_batch` steps; after each batch the
required length burn-in + 50 τ is re-estimated and the next batch covers it
with a 10 % margin, but never more than doubles the chain (an early,
underestimated τ must not decide the stopping point alone) and never less
than a quarter of it.

Budget and reproducibility. Every run is bounded by a step budget
(`max_steps`, default 200 000 steps of every walker), never by the clock:
the sampler's random state is seeded by the caller and batch sizes depend
only on the chain, so the same seed gives the same chain bit for bit on any
machine, loaded or idle. A wall-clock limit (`max_seconds`) is only an
explicit option of the user (default none); when it stops a run the
stopping step depends on the machine, and the reason says so.
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.fft

from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = [
    "ConvergenceCriteria",
    "ChainDiagnostics",
    "ChainRun",
    "integrated_time",
    "Workspace",
    "split_rhat",
    "rank_normalized_rhat",
    "chain_effective_sample_size",
    "diagnose",
    "run_until_converged",
]


@dataclass
class ConvergenceCriteria:
    """Thresholds of the convergence rule (see the module docstring)."""

    tau_multiple: float = 50.0
    burn_in_tau: float = 5.0
    thin_tau: float = 0.5
    rhat_max: float = 1.05
    min_acceptance: float = 0.05
    min_walker_acceptance: float = 0.01
    max_steps: int = 200_000
    max_seconds: float | None = None      # wall-clock safety: off unless the user asks for it
    first_batch: int = 1000
    max_stored: int = 2048

    def __post_init__(self):
        if not self.tau_multiple > 0:
            raise InputError(f"tau_multiple must be > 0, got {self.tau_multiple!r}")
        if not self.burn_in_tau >= 0:
            raise InputError(f"burn_in_tau must be >= 0, got {self.burn_in_tau!r}")
        if not self.thin_tau >= 0:
            raise InputError(f"thin_tau must be >= 0, got {self.thin_tau!r}")
        if not self.rhat_max > 1.0:
            raise InputError(f"rhat_max must be > 1, got {self.rhat_max!r}")
        if int(self.max_steps) < 2:
            raise InputError(f"max_steps must be at least 2, got {self.max_steps!r}")
        if self.max_seconds is not None and not self.max_seconds > 0:
            raise InputError(f"max_seconds must be positive or None, got {self.max_seconds!r}")
        if int(self.first_batch) < 1:
            raise InputError(f"first_batch must be >= 1, got {self.first_batch!r}")
        if int(self.max_stored) < 64 or int(self.max_stored) % 2:
            raise InputError(f"max_stored must be an even number >= 64, got {self.max_stored!r}")
        self.max_steps = int(self.max_steps)
        self.first_batch = int(self.first_batch)
        self.max_stored = int(self.max_stored)

    def to_dict(self) -> dict:
        return json_safe(asdict(self))


@dataclass
class ChainDiagnostics:
    """What the convergence rule found. Times in steps of the sampler.

    Attributes
    ----------
    tau : (d,) integrated autocorrelation time of each parameter after burn-in
        (NaN for a parameter with no variation).
    rhat : (d,) split-chain R̂ after burn-in.
    acceptance : (n_walkers,) acceptance fraction of each walker over the run.
    n_steps : steps run. burn_in, thin : steps discarded / kept interval.
    converged : the rule of the module docstring holds for the sampled
        parameters. reason : why not (or a one-line confirmation).
    sampled : (d,) bool, the parameters the rule applies to (others are
        derived from them, e.g. drawn from an exact conditional).
    limit : `"steps"`, `"time"` or `None` — the limit that stopped the run.
    history : list of (n_steps, max τ) after each batch.
    elapsed : wall-clock seconds (not part of `to_dict`, which must be
        deterministic).
    """

    tau: np.ndarray
    rhat: np.ndarray
    acceptance: np.ndarray
    n_steps: int
    n_walkers: int
    burn_in: int
    thin: int
    converged: bool
    reason: str
    sampled: np.ndarray
    criteria: ConvergenceCriteria
    limit: str | None = None
    rhat_rank: np.ndarray | None = None      # rank-normalised split R̂ (reported; the rule uses rhat)
    history: list = field(default_factory=list)
    storage_interval: int = 1
    elapsed: float = math.nan

    @property
    def tau_max(self) -> float:
        t = self.tau[self.sampled]
        return float(np.max(t)) if t.size and np.all(np.isfinite(t)) else math.nan

    @property
    def rhat_max(self) -> float:
        r = self.rhat[self.sampled]
        return float(np.max(r)) if r.size and np.all(np.isfinite(r)) else math.nan

    @property
    def acceptance_mean(self) -> float:
        return float(np.mean(self.acceptance))

    @property
    def chain_over_tau(self) -> float:
        """(n_steps − burn_in) / max τ: the length the rule compares to `tau_multiple`."""
        t = self.tau_max
        return (self.n_steps - self.burn_in) / t if t > 0 else math.nan

    def ess(self) -> np.ndarray:
        """Effective sample size n_walkers · (n_steps − burn_in) / τ_i of each parameter."""
        return chain_effective_sample_size(self.n_walkers, self.n_steps - self.burn_in, self.tau)

    def to_dict(self) -> dict:
        return json_safe({
            "converged": bool(self.converged),
            "reason": self.reason,
            "limit": self.limit,
            "n_steps": self.n_steps,
            "n_walkers": self.n_walkers,
            "burn_in": self.burn_in,
            "thin": self.thin,
            "storage_interval": self.storage_interval,
            "tau": self.tau,
            "tau_max": self.tau_max,
            "chain_over_tau": self.chain_over_tau,
            "rhat": self.rhat,
            "rhat_max": self.rhat_max,
            "rhat_rank_normalized": self.rhat_rank,
            "acceptance_mean": self.acceptance_mean,
            "acceptance_min": float(np.min(self.acceptance)),
            "sampled": self.sampled,
            "history": [[int(n), t] for n, t in self.history],
            "criteria": self.criteria.to_dict(),
        })


# ----------------------------------------------------------------------- statistics
class Workspace:
    """Arrays reused by the checks of one run.

    The autocorrelation of a stored chain (2048 steps x 64 walkers x 31 parameters) works
    on ~100 MB of temporaries; allocated afresh at every check they are mapped and zeroed
    page by page by the kernel, which on a shared VM cost 3-4 times the arithmetic
    (system time). `get` hands out views of buffers kept between checks; `reserve` sizes
    them once for the longest chain of a run (a buffer that grows is mapped again).
    """

    def __init__(self):
        self._bufs = {}

    def reserve(self, name: str, size: int, dtype=float) -> None:
        """Make buffer `name` hold at least `size` elements of `dtype`."""
        buf = self._bufs.get(name)
        if buf is None or buf.dtype != np.dtype(dtype) or buf.size < size:
            self._bufs[name] = np.empty(int(size), dtype=dtype)

    def get(self, name: str, shape: tuple, dtype=float) -> np.ndarray:
        """An uninitialised C-contiguous array of `shape` in buffer `name` (grown if too small)."""
        size = math.prod(shape)
        self.reserve(name, size, dtype)
        return self._bufs[name][:size].reshape(shape)


# parameters per FFT block of `integrated_time`: its spectra (64 walkers x 4097 values)
# stay in the cache between the transform, the power and the walker average
_TAU_BLOCK = 2


def chain_memory_bytes(n_steps: int, n_walkers: int, d: int) -> int:
    """Bytes the stored chain and its diagnostics' workspace take (`_Buffer`, `_reserve_for_chain`)."""
    n = 1 << (max(n_steps, 2) - 1).bit_length()
    return 8 * n_steps * n_walkers * (2 * d + 1) + 2 * 16 * n_walkers * min(d, _TAU_BLOCK) * (n + 1)


def _cgroup_room() -> int | None:
    """Bytes a container's memory limit leaves (cgroup v2, else v1), None without a limit."""
    for limit, usage in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                         ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                          "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            with open(limit) as fh:
                text = fh.read().strip()
            if text == "max" or int(text) >= 1 << 60:       # no limit (v1 writes a huge number)
                return None
            with open(usage) as fh:
                return max(int(text) - int(fh.read().strip()), 0)
        except (OSError, ValueError):
            continue
    return None


def _available_memory() -> int | None:
    """Bytes of memory available to this process: Linux' MemAvailable (else the physical
    memory), or less when a container's memory limit leaves less."""
    have = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    have = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if have is None:
        try:
            have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            have = None
    room = _cgroup_room()
    return room if have is None else have if room is None else min(have, room)


def check_chain_memory(n_steps: int, n_walkers: int, d: int) -> None:
    """Refuse, before sampling, an ensemble whose chains would not fit in the available memory."""
    need, have = chain_memory_bytes(n_steps, n_walkers, d), _available_memory()
    if have is not None and need > 0.8 * have:
        raise InputError(
            f"walkers = {n_walkers} (--walkers): the chains of {n_walkers} walkers over {d} parameters "
            f"need about {need / 2**30:.3g} GiB of memory, and {have / 2**30:.3g} GiB are available; use "
            f"fewer walkers (a few times the number of parameters is enough for emcee's stretch move)")


def _reserve_for_chain(work: Workspace, n_steps: int, n_walkers: int, d: int) -> None:
    """Size `work` once for `integrated_time` and `split_rhat` of chains up to (n_steps, n_walkers, d)."""
    n = 1 << (max(n_steps, 2) - 1).bit_length()
    work.reserve("x", n_steps * n_walkers * d)          # also split_rhat's deviations
    work.reserve("spec", d * (n + 1))
    block = n_walkers * min(d, _TAU_BLOCK) * (n + 1)
    work.reserve("P", block)
    work.reserve("P2", block)


def integrated_time(chain: np.ndarray, c: float = 5.0, *, work: Workspace | None = None) -> np.ndarray:
    """τ of each parameter of `chain` (n_steps, n_walkers, d), in stored steps.

    emcee's estimator (`emcee.autocorr.integrated_time` with `tol=0`:
    never raises for short chains, the convergence rule judges the length):
    the normalised autocorrelation function of each walker, by FFT, averaged
    over walkers; τ(M) = 1 + 2 Σ_{t=1..M} ρ(t) with the automatic window,
    the smallest M ≥ c τ(M). Same algorithm, vectorised over walkers and
    parameters (emcee loops over them in Python, ~50× slower here); the tests
    check it equals emcee's. A parameter whose draws are all equal gets NaN.
    `work` (a `Workspace`) keeps the buffers between calls of one run.
    """
    chain = np.asarray(chain, dtype=float)
    if chain.ndim != 3:
        raise InputError(f"chain must be (n_steps, n_walkers, d), got shape {chain.shape}")
    T, W, d = chain.shape
    out = np.full(d, np.nan)
    if T < 2:
        return out
    ws = work if work is not None else Workspace()
    n = 1 << (T - 1).bit_length()             # next power of two, as emcee.autocorr.next_pow_two
    # (walkers * d, T), time contiguous: FFTs along the last axis are ~3x faster
    x = ws.get("x", (W * d, T))
    np.subtract(chain.reshape(T, W * d).T, chain.mean(axis=0).reshape(W * d, 1), out=x)
    # each walker's ACF normalised by its lag-0 value Σ x² (Parseval), then averaged over walkers:
    # linear, so done on the spectra, one inverse FFT per parameter instead of one per walker
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = (1.0 / (W * np.einsum("kt,kt->k", x, x))).reshape(W, d)
    x3 = x.reshape(W, d, T)
    spec = ws.get("spec", (d, n + 1))
    for i0 in range(0, d, _TAU_BLOCK):
        i1 = min(d, i0 + _TAU_BLOCK)
        shape = (W, i1 - i0, n + 1)
        # scipy's pocketfft transforms several series at once (SIMD): numpy's numbers, faster
        F = scipy.fft.rfft(x3[:, i0:i1], n=2 * n, axis=-1)
        P = np.square(F.real, out=ws.get("P", shape))
        P += np.square(F.imag, out=ws.get("P2", shape))
        np.einsum("wdf,wd->df", P, inv[:, i0:i1], out=spec[i0:i1])
    f = np.fft.irfft(spec, n=2 * n, axis=-1)[:, :T].T   # (T, d)
    taus = 2.0 * np.cumsum(f, axis=0) - 1.0
    m = np.arange(T)[:, None] < c * taus      # auto_window
    window = np.where(m.any(axis=0), np.argmin(m, axis=0), T - 1)
    est = taus[window, np.arange(d)]
    # a parameter with two different draws (a NaN draw makes est NaN): a witness among the first
    # and last draws of the walkers decides almost always; the others are compared in full
    first = chain[0, 0]
    varies = (chain[0] != first).any(axis=0) | (chain[-1] != first).any(axis=0)
    if not varies.all():
        rest = np.flatnonzero(~varies)
        varies[rest] = (chain[:, :, rest].reshape(T * W, rest.size) != first[rest]).any(axis=0)
    ok = varies & np.isfinite(est)
    out[ok] = est[ok]
    return out


def split_rhat(chain: np.ndarray, *, work: Workspace | None = None) -> np.ndarray:
    """Split-chain potential scale reduction R̂ of each parameter.

    `chain` is (n_steps, n_walkers, d). Each walker's chain is cut in two
    halves of n = floor(n_steps / 2) draws (the middle draw of an odd length is
    dropped), giving m = 2·n_walkers chains θ_c,t. With chain means θ̄_c,
    grand mean θ̄ and chain variances s_c² (ddof 1)::

        B   = n / (m − 1) · Σ_c (θ̄_c − θ̄)²          (between chains)
        W   = (1 / m) · Σ_c s_c²                       (within chains)
        var⁺ = (n − 1) / n · W + B / n
        R̂   = sqrt(var⁺ / W)

    (Gelman et al., Bayesian Data Analysis, 3rd ed., eq. (11.4), with split
    chains.) NaN when a parameter has no within-chain variation or n < 2.
    """
    chain = np.asarray(chain, dtype=float)
    n_steps, n_walkers, d = chain.shape
    n = n_steps // 2
    out = np.full(d, np.nan)
    if n < 2:
        return out
    m = 2 * n_walkers
    if chain.flags.c_contiguous:
        # the stored chain: the halves' means and variances (ddof 1) by numpy's operations in
        # numpy's order, the deviations in one buffer instead of temporaries of the chain's size
        means = np.empty((m, d))              # chain c: half c // n_walkers of walker c % n_walkers
        variances = np.empty((m, d))
        dev = (work or Workspace()).get("x", (n, n_walkers, d))   # integrated_time's buffer: free now
        for k, half in enumerate((chain[:n], chain[n_steps - n:])):
            mean = np.add.reduce(half, axis=0) / n
            means[k * n_walkers:(k + 1) * n_walkers] = mean
            np.subtract(half, mean, out=dev)
            np.multiply(dev, dev, out=dev)
            variances[k * n_walkers:(k + 1) * n_walkers] = np.add.reduce(dev, axis=0) / (n - 1)
    else:
        # another layout (the rank-normalised draws): numpy's reductions follow it
        halves = np.concatenate([chain[:n], chain[n_steps - n:]], axis=1)  # (n, 2W, d)
        means = halves.mean(axis=0)
        variances = halves.var(axis=0, ddof=1)
    B = n / (m - 1) * ((means - means.mean(axis=0)) ** 2).sum(axis=0)
    W = variances.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        var_plus = (n - 1) / n * W + B / n
        r = np.sqrt(var_plus / W)
    ok = np.isfinite(W) & (W > 0)
    out[ok] = r[ok]
    return out


def rank_normalized_rhat(chain: np.ndarray) -> np.ndarray:
    """Rank-normalised split R̂ of each parameter (Vehtari et al. 2021, Bayesian Analysis 16(2)).

    The draws of all chains are replaced by their normal scores
    `Φ⁻¹((r − 3/8) / (S − 1/4))` (r the rank among all S draws) and `split_rhat`
    is taken of those (the bulk R̂), and of the same for the draws folded about their
    median, `|θ − median|` (the tail R̂); the larger is returned. It is robust to heavy
    tails and to chains that differ in scale only, which the classic R̂ misses; ArviZ's
    `rhat(method="rank")` is the same estimator. `chain` is (n_steps, n_walkers, d).
    """
    from scipy.special import ndtri  # Φ⁻¹ without scipy.stats' per-call argument checks (5x)
    from scipy.stats import rankdata

    chain = np.asarray(chain, dtype=float)
    n_steps, n_walkers, d = chain.shape

    def z(x):
        flat = x.reshape(-1, d)
        r = rankdata(flat, axis=0, method="average")
        return ndtri((r - 0.375) / (flat.shape[0] + 0.25)).reshape(x.shape)

    bulk = split_rhat(z(chain))
    tail = split_rhat(z(np.abs(chain - np.median(chain.reshape(-1, d), axis=0))))
    return np.fmax(bulk, tail)


def chain_effective_sample_size(n_walkers: int, n_steps: int, tau: np.ndarray) -> np.ndarray:
    """ESS = n_walkers · n_steps / τ of an ensemble MCMC chain (τ in the same steps as `n_steps`).

    τ is the chain's integrated autocorrelation time from `integrated_time`
    (emcee's estimator: walker-averaged autocorrelation, Sokal's automatic
    window c = 5). Not to be confused with
    `dynid.analysis.statistics.residuals.effective_sample_size`, the
    effective size of one serially correlated *residual* series, whose τ_int
    sum stops at the first lag inside the white-noise band 2/sqrt(n) (with a
    row mask); the two answer different questions with different truncation
    rules, hence two functions with two names.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return n_walkers * n_steps / np.asarray(tau, dtype=float)


# ----------------------------------------------------------------------- the rule
def diagnose(stored: np.ndarray, interval: int, n_steps: int, accepted: np.ndarray,
             criteria: ConvergenceCriteria, sampled=None, limit: str | None = None,
             history=None, elapsed: float = math.nan, final_burn: bool = True,
             rank_rhat: bool = True, work: Workspace | None = None) -> ChainDiagnostics:
    """Apply the convergence rule to a stored chain.

    `stored` (L, n_walkers, d) holds every `interval`-th step of a run of
    `n_steps` steps (stored[i] is step (i + 1)·interval); `accepted`
    (n_walkers,) counts accepted proposals per walker. `rank_rhat=False` skips the
    rank-normalised R-hat (reported, not part of the rule): the checks between batches do.
    `work` (a `Workspace`) keeps the buffers of the autocorrelation between the checks of a run.
    """
    stored = np.asarray(stored, dtype=float)
    L, n_walkers, d = stored.shape
    sampled = np.ones(d, dtype=bool) if sampled is None else np.asarray(sampled, dtype=bool)
    acc = np.asarray(accepted, dtype=float) / max(n_steps, 1)
    c = criteria
    problems = []

    tau_all = integrated_time(stored, work=work) * interval
    t0 = tau_all[sampled]
    if L < 8:
        burn = n_steps // 2
        problems.append(f"the chain ({n_steps} steps) is too short to estimate the autocorrelation time")
    elif t0.size == 0 or not np.all(np.isfinite(t0)):
        bad = np.flatnonzero(sampled & ~np.isfinite(tau_all))
        burn = n_steps // 2
        problems.append(f"autocorrelation time undefined for parameter(s) {bad.tolist()} "
                        "(no variation in the chain: stuck walkers or a degenerate model)")
    else:
        burn = int(math.ceil(c.burn_in_tau * float(t0.max())))
    burn_stored = int(math.ceil(burn / interval))
    if burn_stored > L - 4:
        burn_stored = max(0, L // 2)
        if not problems:
            problems.append(f"the chain ({n_steps} steps) is shorter than its burn-in "
                            f"({c.burn_in_tau:g} τ with τ ≈ {float(t0.max()):.3g} steps)")
    post = stored[burn_stored:]
    burn = burn_stored * interval
    tau = integrated_time(post, work=work) * interval
    rhat = split_rhat(post, work=work)
    ts = tau[sampled]
    if np.all(np.isfinite(ts)) and ts.size:
        tmax = float(ts.max())
        length = n_steps - burn
        if length < c.tau_multiple * tmax:
            problems.append(f"chain after burn-in is {length} steps = {length / tmax:.1f} τ "
                            f"(max τ = {tmax:.3g} steps), needs ≥ {c.tau_multiple:g} τ")
        thin = max(1, int(math.floor(c.thin_tau * tmax)))
    else:
        if not problems:
            problems.append("autocorrelation time undefined after burn-in")
        thin = 1
    rs = rhat[sampled]
    if not np.all(np.isfinite(rs)):
        problems.append("split R̂ undefined (too short or no variation)")
    elif rs.size and rs.max() >= c.rhat_max:
        problems.append(f"split R̂ = {rs.max():.4f} ≥ {c.rhat_max:g}")
    if acc.mean() < c.min_acceptance:
        problems.append(f"mean acceptance fraction {acc.mean():.3f} < {c.min_acceptance:g}")
    stuck = int(np.sum(acc < c.min_walker_acceptance))
    if stuck:
        problems.append(f"{stuck} walker(s) with acceptance < {c.min_walker_acceptance:g} (stuck)")
    # thinning is in steps; kept draws must fall on stored steps
    thin = max(interval, (thin // interval) * interval)
    if limit == "steps":
        problems.insert(0, f"step limit max_steps = {c.max_steps} reached")
    elif limit == "time":
        problems.insert(0, f"time limit max_seconds = {c.max_seconds:g} s reached (the stopping "
                        "point depends on the machine's speed)")
    converged = not problems or (limit is not None and len(problems) == 1)
    if converged:
        reason = (f"converged: {n_steps - burn} steps after burn-in = "
                  f"{(n_steps - burn) / float(ts.max()):.1f} τ ≥ {c.tau_multiple:g} τ, "
                  f"max split R̂ = {float(rs.max()):.4f} < {c.rhat_max:g}, "
                  f"acceptance {acc.mean():.3f}")
        if limit is not None:
            reason += f" (run stopped by its {limit} limit after meeting the rule)"
    else:
        reason = "NOT CONVERGED: " + "; ".join(problems)
    rank = _kept_rank_rhat(stored, interval, burn, thin) if rank_rhat else None
    return ChainDiagnostics(tau=tau, rhat=rhat, rhat_rank=rank,
                            acceptance=acc, n_steps=int(n_steps),
                            n_walkers=n_walkers, burn_in=int(burn), thin=int(thin),
                            converged=bool(converged), reason=reason, sampled=sampled,
                            criteria=c, limit=limit, history=list(history or []),
                            storage_interval=int(interval), elapsed=elapsed)


def _kept_rank_rhat(stored, interval, burn, thin):
    """The rank-normalised R̂ of the kept draws (after burn-in, thinned as `ChainRun.kept`):
    the ranks of every stored step cost seconds, for the same estimate. None if < 4 draws."""
    post = stored[int(math.ceil(burn / interval)):]
    kept = post[::-1][:: max(1, thin // interval)][::-1]
    return rank_normalized_rhat(kept) if kept.shape[0] >= 4 else None


# ----------------------------------------------------------------------- the runner
@dataclass
class ChainRun:
    """A finished run: the stored chain and its diagnostics."""

    stored: np.ndarray          # (L, n_walkers, d), every `interval`-th step
    log_prob: np.ndarray        # (L, n_walkers)
    interval: int
    diagnostics: ChainDiagnostics

    def kept(self) -> np.ndarray:
        """Draws after burn-in, thinned: (n_walkers, n_draws, d)."""
        dg = self.diagnostics
        start = int(math.ceil(dg.burn_in / self.interval))
        step = max(1, dg.thin // self.interval)
        # stored index i is step (i+1)*interval; keep draws ending on the last stored step
        idx = np.arange(self.stored.shape[0] - 1, start - 1, -step)[::-1]
        return np.ascontiguousarray(self.stored[idx].transpose(1, 0, 2))


class _Buffer:
    """Stored steps with doubling interval (see the module docstring)."""

    def __init__(self, cap: int, n_walkers: int, d: int):
        self.cap = cap
        self.x = np.empty((cap, n_walkers, d))
        self.lp = np.empty((cap, n_walkers))
        self.n = 0
        self.interval = 1

    def push(self, step: int, coords: np.ndarray, lp: np.ndarray) -> None:
        # step is 1-based; store steps that are multiples of the interval
        if step % self.interval:
            return
        if self.n == self.cap:
            half = self.cap // 2
            # keep stored steps 2, 4, ... (multiples of the doubled interval)
            self.x[:half] = self.x[1::2]
            self.lp[:half] = self.lp[1::2]
            self.n = half
            self.interval *= 2
            if step % self.interval:
                return
        self.x[self.n] = coords
        self.lp[self.n] = lp
        self.n += 1

    def view(self):
        return self.x[: self.n], self.lp[: self.n]


def run_until_converged(sampler, p0: np.ndarray, criteria: ConvergenceCriteria | None = None,
                        *, sampled=None, progress=None) -> ChainRun:
    """Run `sampler` (an `emcee.EnsembleSampler`, seeded by the caller) from `p0`.

    Batches as in the module docstring, until the rule holds or a limit is
    hit. Positions are not stored by emcee (`store=False`); this function
    keeps them in its own bounded buffer and counts acceptances per walker
    (a walker moved iff its position changed: proposals are continuous).
    `progress(n_steps, required_steps)` is called after each batch.
    """
    c = criteria or ConvergenceCriteria()
    p0 = np.asarray(p0, dtype=float)
    n_walkers, d = p0.shape
    check_chain_memory(c.max_stored, n_walkers, d)
    buf = _Buffer(c.max_stored, n_walkers, d)
    accepted = np.zeros(n_walkers)
    n = 0
    state = p0
    prev = p0.copy()
    history = []
    t_start = time.perf_counter()
    target = min(c.first_batch, c.max_steps)
    limit = None
    first = True
    lean = hasattr(sampler, "advance")
    work = Workspace()
    _reserve_for_chain(work, c.max_stored, n_walkers, d)
    while True:
        todo = target - n
        # emcee checks the initial ensemble for degeneracy; later batches resume a live one
        if lean:
            steps = sampler.advance(state, todo, check=first)
        else:
            steps = ((st, None) for st in sampler.sample(state, iterations=todo, store=False,
                                                          skip_initial_state_check=not first))
        for st, acc in steps:
            n += 1
            coords = st.coords
            if acc is None:
                acc = np.any(coords != prev, axis=1)
                prev = coords.copy()
            accepted += acc
            buf.push(n, coords, st.log_prob)
            state = st
            if c.max_seconds is not None and (n & 63) == 0 and \
                    time.perf_counter() - t_start > c.max_seconds:
                limit = "time"
                break
        if lean:
            steps.close()       # stopped early: the sampler's random state as after the steps taken
        first = False
        stored, _ = buf.view()
        dg = diagnose(stored, buf.interval, n, accepted, c, sampled=sampled, rank_rhat=False, work=work)
        tmax = dg.tau_max
        history.append((n, tmax))
        if dg.converged or limit is not None:
            break
        if n >= c.max_steps:
            limit = "steps"
            break
        if math.isfinite(tmax):
            required = (c.burn_in_tau + c.tau_multiple) * tmax
        else:
            required = 2 * n
        if progress is not None:
            progress(n, required)
        nxt = int(math.ceil(1.1 * required - n))
        nxt = min(max(nxt, n // 4, 50), n)
        target = min(n + nxt, c.max_steps)
    stored, lps = buf.view()
    elapsed = time.perf_counter() - t_start
    if limit is None and dg.converged:
        # the last check ran on this very chain: its τ, R̂ and reason stand
        dg = dataclasses.replace(dg, history=list(history), elapsed=elapsed,
                                 rhat_rank=_kept_rank_rhat(stored, buf.interval, dg.burn_in, dg.thin))
    else:
        dg = diagnose(stored, buf.interval, n, accepted, c, sampled=sampled, limit=limit,
                      history=history, elapsed=elapsed, work=work)
    # the buffer is the run's own and not used again: its views are the result (no copy)
    return ChainRun(stored=stored, log_prob=lps, interval=buf.interval, diagnostics=dg)
