"""Catalogue-free tests of the final residual: structure that no selected effect explains.

After the forward selection (`dynid.analysis.diagnosis.selection.diagnose`) the
residual of each joint j (decimated, fitted rows) is tested for structure of any
shape, without a candidate list. The residual is that of the *full* base model plus the
selected effects (issue 13 item 1): what the essential reduction dropped is explained by
base parameters, not by a missing effect (TX40 plant with a speed-dependent ripple on
joint 1: the 24-parameter essential model left 5.6 x the noise floor on wrist joints 5
and 6, whose parameters it had dropped because joint 1's large residual dominated the
error criterion; the full base model leaves them at the floor). The tests:

* **dependence** on a variable x: `q_j`, `qd_j`, `qdd_j`, `t`, the friction
  level over time (`e_j sign(qd_j)` against `t`: a friction whose level
  drifts changes sign with the velocity, so its time means are zero) and the
  other joints' `q_i`, `qd_i`. Statistic: `S = sum_b n_b m_b^2` of the
  binned means `m_b` of the residual in `BINS` equal-count bins of x;
* **spectral lines against position**: the residual resampled on a uniform grid
  of `q_j` (sums per bin) and Fourier transformed: `F(k) = sum_i e_i
  exp(-i k q_i)`, every order k the grid resolves (high orders too: a k = 50
  motor ripple has a period of 0.13 rad);
* **a step in time**: the largest excursion of the cumulative sum of the
  (centred) residual (CUSUM);
* **excess over the torque-noise floor** (whiteness, calibrated): the residual
  variance against the variance that the recording's own torque noise has
  after the same dead zone and decimation filter (the noise's standard
  deviation from the second differences of the full-rate torque,
  `var(d2 tau) / 6`; a white sequence of that variance passed through
  `EffectObservation.decimate`). The residual of even a correct model is
  coloured by the decimation filter, so a Ljung-Box test on it always rejects;
  comparing with the noise the data show does not.
  The floor is only estimated where the full-rate torque's increments are white:
  `r = var(d3 tau) / var(d2 tau)` is 20/6 = 3.33 for white noise (measured
  3.31-3.37 on the independent plant) and far below 1 for a torque low-pass
  filtered upstream (0.001-0.003 on the KUKA LWR4+ recordings of examples/,
  filtered at 2 Hz by their source; 0.012 on plant data filtered at 100 Hz). Below
  `WHITE_MIN` (2) the joint's floor is unknown: its noise-floor test is not run
  (a filtered torque's second differences hold almost no noise, so the floor
  would come out 100-1000 x too low and flag every joint), and its permutation
  block length uses the residual's own autocorrelation time too (the noise left
  after an upstream filter below the decimation cutoff is more correlated than
  white noise through the decimation filter).
  The floor also holds the **position noise carried through the model** (errors in
  variables: `M(q) dqdd + dg/dq dq + ...`, the noise after the position filter and
  the differentiation): `position_noise_residual` adds one more white sequence of
  the recording's own position-noise level (from the third differences of the full-rate
  positions, `var(d3 q) / 20`, only where their increments are white: `var(d4 q) /
  var(d3 q)` ~ 3.5) and processes the recording again; the change of the residual is
  that noise's contribution. Measured on the independent plant (2e-5 rad position noise):
  clean KUKA LWR4+ joint 2, residual 0.0395 N m, 0.0134 with the plant's true positions,
  torque-noise floor alone 0.0124 (ratio 3.2, flagged "coloured" before), position-noise
  part 0.029-0.039 N m; the floor with it is 0.029-0.041 and the joint is not flagged.

Null distributions (why closed-loop correlation and the decimation colour do
not produce alarms). The residual's rows are serially correlated, and the
variables are smooth functions of time, so counting rows as independent would
flag everything. Each dependence/line/step statistic is compared with its
distribution under **block permutation** of the residual (contiguous blocks
of `L` rows moved together, the variables kept in place: the residual's own
autocorrelation within a block is kept, its alignment with the motion
destroyed). `L` is at least three integrated autocorrelation times of the
decimated noise and at least twice the decimation guard. With
`N_PERM` permutations the tail is extrapolated from the permutation moments:
a scaled chi-square matched to the mean and variance for `S`
(Satterthwaite), the Kolmogorov distribution scaled by its mean for the
CUSUM, and for the spectral line `p = K exp(-P(k) / P_null(k))` (the
periodogram ordinate over its permutation mean is ~ Exp(1); K orders). The
noise-floor test uses `chi2(n_eff)` with the effective sample size of the
decimated noise. p-values are Bonferroni-adjusted over all tests and joints.

Rows at the dead-zone edge. The tests leave out the decimated rows with
`|qd_j| < EDGE_FACTOR x qd_threshold_j` (EDGE_FACTOR = 3): dynid's friction model
has `Fc sign(qd)`, a real friction rises to its Coulomb level over a small speed
range, and where that range is wider than the dead zone (dynid's default, 1 % of the
peak speed) the rows just outside it carry the mismatch the dead zone exists to
drop. Measured on the independent plant (`Fc tanh(qd / 0.01)`), default dead
zone: the clean KUKA LWR4+ joint 2 residual is 2.1 x its noise floor with those rows
(flagged "coloured"), at the floor without them. An effect that lives only below
three dead-zone widths is thereby not tested; every effect of the campaign reaches
well beyond (a Stribeck v_s of 0.2 rad/s against dead zones of 0.01-0.02 rad/s).

Rule for "unexplained" (documented choice). A joint is reported as
**unexplained** when some test on it has a Bonferroni p below `alpha`
(0.01) **and** the structure is large against the noise:

* dependence, line, step: the structure's RMS (binned means, line amplitude
  or step, minus its permutation-null expectation) is at least `MIN_RATIO`
  (0.5) times the RMS of the rest of the residual (it carries >= 20 % of the
  residual variance);
* noise floor: the residual RMS is at least `FLOOR_RATIO` (2) times the
  torque-noise floor, and no variable explains it ("time (coloured residual)").

Why both. Significance alone flags tiny, harmless mismatches on long
recordings (n_eff in the thousands makes 1 % of the residual variance
significant); size alone flags noise. Measured on the independent closed-loop
plant (tests/support/independent_plant.py, TX40, 8 s at 5 kHz, 179 decimated samples;
benchmarks/diagnosis_independent.py): on clean runs (seeds 1-3) the final
residual RMS is 1.0-1.3 x the torque-noise floor (0.011-0.013 N m) and no joint
is flagged; a 1.5 N m order-50 ripple on joint 3 (outside the catalogue) is
flagged on joint 3 alone, period 0.126-0.128 rad (true 0.1257), RMS ~1 N m,
Bonferroni p ~1e-19-1e-24; a friction warm-up (25 %, time constant 3 s) on
joints 1 and 2 is named (`drift`, friction level) and what the linear drift
leaves of the exponential is flagged on those two joints only. The 2 x floor
threshold leaves a margin over the clean 1.3 x; a smooth Coulomb onset that the
model's sign(qd) lacks (the plant's tanh(qd / 0.01)) reaches 3 x on joint 2
with the default 1 % dead zone.

The spectral-line test runs on the *full-rate* residual (the final model's
full-rate torque from the base regressor and the effect columns; skipped when
a time delay was selected); its structure RMS is compared with the RMS of the
decimated residual (the noise level the model is judged on; the full-rate
residual is dominated by the torque sensor's white noise, which the
decimation removes). A line at an order the decimation filter removes at the
recorded speeds is still reported: the torque has it, the decimated model
cannot see it (on the real TX40 recording of examples/, joints 1 and 2 show a
line of period 0.0041 rad, ~1.8 and ~0.5 N m, in the full-rate torque).
The reported `depends_on` is the variable of the flagged test with the
largest structure RMS.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from dynid.analysis.diagnosis.permuted_bins import permuted_bins
from dynid.analysis.processing.observation import observed_residual
from dynid.analysis.results import p_phrase
from dynid.analysis.statistics.residuals import effective_sample_size
from dynid.threads import with_single_blas_thread

__all__ = ["residual_structure", "StructureResult", "StructureTest", "Unexplained",
           "noise_floor", "whiteness", "position_noise", "position_noise_residual", "WHITE_Q_MIN", "WHITE_MIN", "EDGE_FACTOR", "BINS", "N_PERM", "MIN_RATIO", "FLOOR_RATIO"]

BINS = 20
N_PERM = 200
MIN_RATIO = 0.5
FLOOR_RATIO = 2.0
WHITE_MIN = 2.0
#: a floor this many times the residual's own RMS is not the residual's noise: the full-rate
#: torque's high-frequency content is not white (a limit cycle, noise shaped by the loop), and
#: the second differences overstate what the decimation passes (`_noise_floors`)
FLOOR_ABOVE_RESIDUAL = 2.0
WHITE_Q_MIN = 2.0      # var(d4 q) / var(d3 q): 70/20 = 3.5 for white position noise
EDGE_FACTOR = 3.0
GRID = 4096            # position grid of the spectral test (before zero padding x2)
_BATCH = 16            # permutations binned together (bounds the memory of a batch)


@dataclass
class StructureTest:
    joint: int                 # 1-based
    test: str                  # "dependence", "line", "step", "noise_floor"
    depends_on: str            # e.g. "q2", "t", "q3 (order 50.1, period 0.125 rad)"
    statistic: float
    p_raw: float
    p_value: float = float("nan")     # Bonferroni
    rms: float = 0.0           # N m, size of the structure
    noise_rms: float = 0.0     # N m, the rest of the residual (or the noise floor)
    ratio: float = 0.0
    large: bool = False
    flagged: bool = False
    detail: dict = field(default_factory=dict)

    def to_dict(self):
        return {"joint": self.joint, "test": self.test, "depends_on": self.depends_on,
                "statistic": self.statistic, "p_value": self.p_value, "p_value_unadjusted": self.p_raw,
                "rms": self.rms, "noise_rms": self.noise_rms, "ratio": self.ratio,
                "large": self.large, "flagged": self.flagged, **self.detail}


@dataclass
class Unexplained:
    joint: int
    depends_on: str
    rms: float
    p_value: float
    test: str
    noise_rms: float
    variable: str = ""         # the variable key ("q2", "t", "t*sign(qd2)", ...)
    period: float | None = None
    also: list = field(default_factory=list)
    curve: tuple | None = None     # (x, mean residual) for a figure: x in the variable's unit
    curve_label: str = ""
    hypothesis: str = ""           # the mechanism it points to (hypotheses.py)
    mechanism: str = ""
    reason: str = ""               # why the flag is not raised (alias, too small)

    def to_dict(self):
        return {"joint": self.joint, "depends_on": self.depends_on, "rms": self.rms,
                "p_value": self.p_value, "test": self.test, "noise_rms": self.noise_rms,
                "variable": self.variable, "period_rad": self.period, "also": list(self.also),
                "hypothesis": self.hypothesis or None, "mechanism": self.mechanism or None,
                "not_raised_because": self.reason or None}

    def sentence(self):
        if self.test == "line":
            what = f"the residual depends on {self.variable} with period {self.period:.3g} rad"
        elif self.test == "step":
            what = "the residual steps in time"
        elif self.test == "noise_floor":
            tot = math.hypot(self.rms, self.noise_rms)
            what = (f"the residual RMS ({tot:.3g} N m) is {tot / max(self.noise_rms, 1e-300):.2g} x "
                    f"the torque-noise floor ({self.noise_rms:.3g} N m) and no tested variable "
                    f"explains it")
        elif self.variable.startswith("t*sign"):
            what = "the friction level changes over the recording (residual x sign(qd) depends on t)"
        else:
            what = f"the residual depends on {self.variable}"
        size = ("excess" if self.test == "noise_floor" else "structure") + f" RMS {self.rms:.3g} N m"
        rest = "floor" if self.test == "noise_floor" else "rest"
        return (f"joint {self.joint}: {what} ({size} vs {rest} {self.noise_rms:.3g} N m, "
                f"{p_phrase(self.p_value)}); no candidate explains it"
                + (f". Hypothesis: {self.hypothesis}" if self.hypothesis else ""))


@dataclass
class StructureResult:
    tests: list
    unexplained: list
    alpha: float
    n_tests: int
    noise_floor: np.ndarray
    block_length: int
    rule: str
    whiteness: np.ndarray | None = None    # var(d3 tau) / var(d2 tau) per joint (white: 3.33)
    floor_over_residual: np.ndarray | None = None   # per joint: the floor refused, over the residual RMS
    dropped: list = field(default_factory=list)      # Unexplained not raised (alias, too small)
    hypotheses: list = field(default_factory=list)   # Hypothesis per flagged joint (hypotheses.py)

    @property
    def floor_known(self):
        """Joints (bool, n) whose torque-noise floor could be estimated (white increments)."""
        return np.isfinite(self.noise_floor)

    def to_dict(self):
        return {"alpha": self.alpha, "n_tests": self.n_tests, "block_length": self.block_length,
                "noise_floor_rms": [float(x) if np.isfinite(x) else None for x in self.noise_floor],
                "whiteness_d3_d2": None if self.whiteness is None else list(map(float, self.whiteness)),
                "noise_floor_over_residual": (None if self.floor_over_residual is None else
                                              [float(x) if np.isfinite(x) else None
                                               for x in self.floor_over_residual]),
                "rule": self.rule,
                "not_raised": [u.to_dict() for u in self.dropped],
                "hypotheses": [h.to_dict() for h in self.hypotheses],
                "tests": [t.to_dict() for t in self.tests if t.flagged or t.p_value < 0.05]}


RULE = (f"per joint, tests of the final residual (binned means vs q_j, qd_j, qdd_j, t, "
        f"t*sign(qd_j), other joints' q, qd; spectral lines vs q_j; step in t; excess over the "
        f"torque-noise floor) with block-permutation nulls, Bonferroni over tests x joints < alpha; "
        f"flagged when structure RMS >= {MIN_RATIO} x rest of the residual (noise floor test: "
        f"residual RMS >= {FLOOR_RATIO} x floor)")


def noise_floor(eobs, seed=0):
    """(floor_rms (n,), decimated unit noise (M, n)): torque-noise RMS after the decimation.

    The full-rate torque noise std per joint is estimated from second
    differences (`var(d2 tau)/6` for white noise; the smooth closed-loop torque
    contributes little at the full rate). A white sequence of unit variance goes
    through the same dead zone and decimation as the torque.
    """
    tau = np.asarray(eobs.tau, dtype=float)
    d2 = np.diff(tau, n=2, axis=0)
    # robust: median absolute deviation of the second differences
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) * 1.4826
    sigma = mad / math.sqrt(6.0)
    rng = np.random.default_rng(seed)
    white = rng.standard_normal(tau.shape)
    D = eobs.decimate(white[:, :, None])[:, :, 0]
    return sigma, D


def whiteness(tau):
    """`var(d3 tau) / var(d2 tau)` per joint (robust variances, MAD): 20/6 = 3.33 for white
    noise, << 1 when the torque was low-pass filtered before it was recorded."""
    tau = np.asarray(tau, dtype=float)

    def v(k):
        d = np.diff(tau, n=k, axis=0)
        return (np.median(np.abs(d - np.median(d, axis=0)), axis=0) * 1.4826) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        r = v(3) / v(2)
    return np.where(np.isfinite(r), r, 0.0)


def position_noise(q):
    """(sigma_q (n,), ratio (n,)): position-noise std per joint from the third differences of
    the full-rate positions (`var(d3 q) = 20 sigma^2` for white noise; robust variances, MAD),
    and `var(d4 q) / var(d3 q)` (70/20 = 3.5 for white noise). Where the ratio is below
    `WHITE_Q_MIN` the third differences are not noise (positions filtered or quantised
    upstream, or too smooth to show it): sigma_q is 0 there."""
    q = np.asarray(q, dtype=float)

    def v(k):
        d = np.diff(q, n=k, axis=0)
        return (np.median(np.abs(d - np.median(d, axis=0)), axis=0) * 1.4826) ** 2
    v3, v4 = v(3), v(4)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(v3 > 0, v4 / np.where(v3 > 0, v3, 1.0), 0.0)
    sigma = np.where(r >= WHITE_Q_MIN, np.sqrt(v3 / 20.0), 0.0)
    return sigma, r


def position_noise_residual(experiment, robot, eobs, cols, chi, seed=0, n_draws=2):
    """(delta (n_draws, M, n) or None, sigma_q (n,)): what the recording's own position noise does
    to the decimated residual of the model `(cols, chi)` (base-regressor columns of `eobs.obs.W` and
    their values).

    The residual of even the true model carries the position noise through the regressor
    (errors in variables: `M(q) dqdd + dg/dq dq + ...` with `dq` the noise after the
    position filter and the differentiation), on top of the torque noise. One more white
    sequence of std sigma_q (`position_noise`) is added to the recorded positions and
    the recording processed again with the same settings (filter, differentiation, dead
    zone, decimation); `delta` is the change of the residual `tau - W chi`, one per draw
    (its RMS varies between draws: 0.029-0.039 N m below, the dead-zone rows that flip make it
    spiky). To first order in the noise it has the distribution of the position noise's
    contribution (the dead-zone rows that flip are part of it). Measured on the independent plant (KUKA LWR4+, clean,
    2e-5 rad): joint 2 residual 0.0395 N m with the recorded positions, 0.0134 with the true
    ones (torque-noise floor 0.0124), delta 0.0388 N m RMS.
    """
    sigma_q, _ = position_noise(experiment.q)
    if not np.any(sigma_q > 0):
        return None, sigma_q
    q = np.asarray(experiment.q, dtype=float)
    rng = np.random.default_rng(seed + 7919)
    obs = eobs.obs
    cols = np.asarray(cols, dtype=int)
    chi = np.asarray(chi, dtype=float)
    r0 = obs.tau - obs.W[:, :, cols] @ chi
    out = []
    for _ in range(int(n_draws)):
        noisy = dataclasses.replace(experiment, q=q + sigma_q * rng.standard_normal(q.shape))
        r2, mask2 = observed_residual(noisy, robot, eobs.bp, obs.settings, cols, chi)
        if r2.shape != r0.shape:
            return None, sigma_q
        out.append(np.where(obs.row_mask & mask2, r2 - r0, 0.0))
    return np.stack(out), sigma_q


def _block_perms(n, L, n_perm, rng):
    """(n_perm, n) sample orders: blocks of L samples in a random order (the last one short)."""
    nb = int(math.ceil(n / L))
    within = np.arange(L)
    out = np.empty((n_perm, n), dtype=np.intp)
    for i in range(n_perm):
        idx = (rng.permutation(nb)[:, None] * L + within).ravel()
        out[i] = idx[idx < n]           # the short last block keeps its order wherever it lands
    return out


def _binned_stat(bins, nb, e):
    s = np.bincount(bins, weights=e, minlength=nb)
    c = np.bincount(bins, minlength=nb)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.sum(np.where(c > 0, s * s / np.maximum(c, 1), 0.0)))


def _binned_null(bins, nb, y, perms):
    """`_binned_stat(bins, nb, y[p])` for every order p of `perms` (the counts binned once)."""
    c = np.bincount(bins, minlength=nb)
    s = np.empty((len(perms), nb))
    for i, p in enumerate(perms):
        s[i] = np.bincount(bins, weights=y[p], minlength=nb)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sum(np.where(c > 0, s * s / np.maximum(c, 1), 0.0), axis=1)


def _perm_power(gi, y, L, n_perm, rng):
    """Mean over `n_perm` block permutations p (`_block_perms(y.size, L, n_perm, rng)`: the same
    draws) of `_position_power(gi, y[p])` (FFTs batched).

    The permuted residuals are binned on the position grid in one compiled pass per batch
    (`permuted_bins`: neither the orders as sample indices, n_perm x N integers, nor the
    permuted copies are built; at the full rate those were most of the structure tests'
    time); the same sums as `np.bincount(gi, weights=y[p])`, bit for bit.
    """
    n = y.size
    nb = int(math.ceil(n / L))
    perms = np.array([rng.permutation(nb) for _ in range(n_perm)], dtype=np.intp).reshape(n_perm, nb)
    total = np.zeros(GRID + 1)
    binned = np.empty((_BATCH, GRID))
    for a in range(0, n_perm, _BATCH):
        B = len(perms[a:a + _BATCH])
        permuted_bins(y, gi, perms[a:a + _BATCH], L, GRID, out=binned)
        power = np.abs(np.fft.rfft(binned[:B], 2 * GRID, axis=1)) ** 2
        for row in power:                # the same running sum as np.mean over the rows
            total += row
    return total / n_perm


def _satterthwaite_p(S, null):
    m, v = float(np.mean(null)), float(np.var(null))
    if not (m > 0 and v > 0):
        return 1.0 if S <= m else 0.0
    nu = 2.0 * m * m / v
    c = v / (2.0 * m)
    return float(stats.chi2.sf(S / c, nu))


def _cusum(e):
    c = np.cumsum(e - e.mean())
    k = int(np.argmax(np.abs(c)))
    return float(np.abs(c[k])), k


def _line_test(j, x, e, L, n_perm, rng, noise_rms):
    """Spectral line of the residual e against position x (full rate): StructureTest or None."""
    nu = x.size
    lo, hi = float(x.min()), float(x.max())
    rng_q = hi - lo
    if rng_q < 1e-3 or nu < 100:
        return None
    dq = rng_q / (GRID - 1)
    gi = np.clip(np.round((x - lo) / dq).astype(int), 0, GRID - 1)
    nfft = 2 * GRID
    P = _position_power(gi, e)
    Pn = _perm_power(gi, e, L, n_perm, rng)
    k_orders = 2 * np.pi * np.fft.rfftfreq(nfft, dq)
    kmin = 2 * np.pi * 3.0 / rng_q           # at least 3 periods over the range
    kmax = 2 * np.pi / (4 * dq)              # at least 4 grid steps per period
    sel = (k_orders >= kmin) & (k_orders <= kmax) & (Pn > 0)
    if not sel.any():
        return None
    z = np.where(sel, P / np.where(Pn > 0, Pn, 1.0), 0.0)
    ib = int(np.argmax(z))
    K = int(sel.sum()) / 2.0                 # zero padding x2: about half are independent
    p = float(min(1.0, K * math.exp(-min(z[ib], 700.0))))
    struct2 = max(0.0, 2.0 * (P[ib] - Pn[ib]) / nu ** 2)
    rms = math.sqrt(struct2)
    if noise_rms is None:          # the rest of the full-rate residual
        noise_rms = math.sqrt(max(float(np.mean(e ** 2)) - struct2, 1e-300))
    p = max(p, _line_confirmation(gi, e, sel, L, n_perm, rng, needed=p < 1.0))
    order = float(k_orders[ib])
    if 0 < ib < P.size - 1:       # parabolic interpolation of the peak (bin spacing ~2 % at order 50)
        a_, b_, c_ = P[ib - 1], P[ib], P[ib + 1]
        den = a_ - 2 * b_ + c_
        if den < 0:
            order += float(np.clip(0.5 * (a_ - c_) / den, -0.5, 0.5)) * float(k_orders[1] - k_orders[0])
    return StructureTest(j + 1, "line", f"q{j + 1} (order {order:.3g}, period {2 * np.pi / order:.3g} rad)",
                         float(z[ib]), p, rms=rms, noise_rms=noise_rms, ratio=rms / max(noise_rms, 1e-300),
                         detail={"order": order, "period_rad": 2 * np.pi / order,
                                 "full_rate_rms": float(np.std(e))})


def _position_power(gi, y):
    """Periodogram against position: y summed on the position grid (bins gi), zero-padded x2."""
    return np.abs(np.fft.rfft(np.bincount(gi, weights=y, minlength=GRID), 2 * GRID)) ** 2


def _line_confirmation(gi, e, sel, L, n_perm, rng, needed=True):
    """p of the spectral line found in one half of the recording, tested in the other.

    The full-data test searches thousands of orders; its Bonferroni factor K holds only if
    the periodogram's ordinates over the permutation mean are independent Exp(1), and at the
    band's upper edge (a period of a few position-grid steps, where slow passes put many
    samples in few bins) they are not: a clean TX40 plant run had a "line" of period
    0.0017 rad on joint 1 at p = 0.008, in every case of that seed. A line of the robot
    is a function of position, so it is the same in both halves of the recording. The
    order is searched in one half (in time) and the ordinate at that order (and the
    bins beside it) is tested in the other, without a search: `p = 3 exp(-z)`; both
    directions, the smaller p times 2. The line must pass both this and the full-data
    test (the larger p is kept). `needed=False` (the full-data p is 1 already, so the larger
    is 1 whatever this one is): 1, after drawing the same permutations from `rng`, so the
    tests after this one draw what they would have.
    """
    nu = e.size
    half = nu // 2
    if half < 100:
        return 1.0
    if not needed:
        for size in (half, nu - half):
            nb = int(math.ceil(size / L))
            for _ in range(n_perm):
                rng.permutation(nb)
        return 1.0

    def spectra(idx):
        g, y = gi[idx], e[idx]
        Pn = _perm_power(g, y, L, n_perm, rng)
        return np.where(sel & (Pn > 0), _position_power(g, y) / np.where(Pn > 0, Pn, 1.0), 0.0)

    za = spectra(np.arange(half))
    zb = spectra(np.arange(half, nu))
    ps = []
    for z_find, z_test in ((za, zb), (zb, za)):
        k = int(np.argmax(z_find))
        zt = float(np.max(z_test[max(k - 1, 0):k + 2]))
        ps.append(min(1.0, 3.0 * math.exp(-min(zt, 700.0))))
    return float(min(1.0, 2.0 * min(ps)))


def _binned_curve(x, y, nb):
    order = np.argsort(x, kind="stable")
    parts = np.array_split(order, nb)
    return (np.array([float(np.median(x[p])) for p in parts if p.size]),
            np.array([float(np.mean(y[p])) for p in parts if p.size]))


def _curve(test, d):
    """(x, binned mean residual) along the variable a flagged test found, and its axis label."""
    if test.test == "dependence":
        x, y = d["vars"][test.depends_on]
        lab = test.depends_on if not test.depends_on.startswith("t*") else "t [s] (residual x sign(qd))"
        return _binned_curve(x, y, int(max(4, min(BINS, x.size // 10)))), lab
    if test.test == "line" and "full" in d:
        x, y = d["full"]
        per = test.detail["period_rad"]
        w = per / 8.0
        # ten periods about the middle of the range (readable; the line is the same everywhere)
        lo = max(float(x.min()), 0.5 * (float(x.min()) + float(x.max())) - 5 * per)
        nb = int(min(80, max(8, (float(x.max()) - lo) / w)))
        b = np.clip(((x - lo) / w).astype(int), 0, nb - 1)
        keep = ((x - lo) < nb * w) & (x >= lo)
        c = np.bincount(b[keep], minlength=nb)
        sm = np.bincount(b[keep], weights=y[keep], minlength=nb)
        ok = c > 0
        return ((lo + (np.arange(nb) + 0.5) * w)[ok], sm[ok] / c[ok]), test.depends_on.split(" ")[0] + " [rad]"
    x, y = d["t"], d["e"]
    return (x, y), "t [s]"


@with_single_blas_thread
def residual_structure(eobs, residual, mask, *, names=None, alpha=0.01, n_perm=N_PERM, gap=2,
                       seed=0, min_ratio=MIN_RATIO, floor_ratio=FLOOR_RATIO, bins=BINS,
                       explained=None, full_residual=None, full_mask=None, full_block=None,
                       position_delta=None):
    """Structure tests of `residual` (M, n) over the rows `mask` (M, n): `StructureResult`.

    `eobs`: the `EffectObservation` (decimated t, q, qd, qdd in
    `eobs.obs`; full-rate torque and decimation for the noise floor).
    `explained`: labels of the selected effects (only reported).
    `full_residual` (N, n): the residual at the full rate (`eobs.tau` minus the
    final model's full-rate torque), rows `full_mask`: the spectral-line test
    runs on it (the decimation filter removes high position orders at speed);
    without it the line test is skipped. `full_block`: its permutation block
    length in samples (default `fs / f_decimation_cutoff`).
    `position_delta` ((k,) M, n): draws of the position noise's contribution to the decimated residual
    (`position_noise_residual`); the noise floor is that of the torque noise plus it.
    """
    R = np.asarray(residual, dtype=float)
    n = R.shape[1]
    thr = np.atleast_1d(np.asarray(eobs.obs.settings.get("qd_threshold") or 0.0, dtype=float))
    thr = np.broadcast_to(thr if thr.size == n else thr[:1], (n,))
    mask = np.asarray(mask, dtype=bool) & ~(np.abs(np.asarray(eobs.obs.qd, dtype=float))
                                            < EDGE_FACTOR * thr)   # the dead-zone edge (module docstring)
    rng = np.random.default_rng(seed)
    floor, tau_noise, white, over = _noise_floors(eobs, R, mask, seed, position_delta)
    L = int(max(8, 2 * gap, math.ceil(3 * np.max(tau_noise))))
    tests, data = [], {}
    for j in range(n):
        u = mask[:, j]
        nu = int(u.sum())
        if nu < 60:
            continue
        e = R[u, j] - R[u, j].mean()
        perms = _block_perms(nu, int(min(L, max(2, nu // 30))), n_perm, rng)
        data[j] = _variables(eobs.obs, u, j, e)
        tests += _dependence_tests(j, data[j]["vars"], e, perms, int(max(4, min(bins, nu // 15))))
        if full_residual is not None:
            lt, full = _full_rate_line(eobs, j, full_residual, full_mask, thr[j], full_block, n_perm,
                                       rng, float(np.sqrt(np.mean(e ** 2))))
            if lt is not None:
                tests.append(lt)
                data[j]["full"] = full
        tests.append(_step_test(j, data[j]["t"], e, perms))
        if np.isfinite(floor[j]) and floor[j] > 0:
            tests.append(_floor_test(j, e, floor[j], tau_noise[j]))
    m = max(1, len(tests))
    for tt in tests:
        tt.p_value = float(min(1.0, m * tt.p_raw))
        tt.large = tt.ratio >= (floor_ratio if tt.test == "noise_floor" else min_ratio)
        tt.flagged = bool(tt.p_value < alpha and tt.large)
    return StructureResult(tests=tests, unexplained=_unexplained(tests, data, n), alpha=alpha, n_tests=m,
                           noise_floor=floor, block_length=L, rule=RULE, whiteness=white,
                           floor_over_residual=over)



def _noise_floors(eobs, R, mask, seed, position_delta):
    """(floor (n,), tau_noise (n,), whiteness (n,), over (n,)): the decimated noise floor of each
    joint, the integrated autocorrelation time of that noise, var(d3 tau)/var(d2 tau), and, where
    the floor was refused as above the residual, its torque part over the residual's RMS (NaN
    elsewhere).

    A residual holds its torque noise: a torque-noise floor above `FLOOR_ABOVE_RESIDUAL` times the
    joint's residual RMS measures something else, and the floor is unknown (NaN). The position
    noise's part is left out of that comparison: it is what the residual of the true model would
    carry, and a fitted model absorbs much of it (up to 2 x on planar2 with 4e-5 rad position
    noise and 0.02 N m torque noise)."""
    n = R.shape[1]
    sigma_full, Dn = noise_floor(eobs, seed=seed)
    white = whiteness(eobs.tau)
    floor = np.zeros(n)
    over = np.full(n, np.nan)
    tau_noise = np.ones(n)
    for j in range(n):
        u = mask[:, j]
        if u.sum() <= 10:
            continue
        # the noise the residual of the true model has: torque noise through the decimation,
        # plus the position noise through the model (errors in variables)
        nz = sigma_full[j] * Dn[u, j]
        var_q = 0.0
        if position_delta is not None:
            pdl = np.asarray(position_delta, dtype=float).reshape((-1,) + R.shape)
            var_q = float(np.mean([np.var(d_[u, j]) for d_ in pdl]))
            nz = nz + pdl[0][u, j]
        torque_part = math.sqrt(float(np.var(sigma_full[j] * Dn[u, j])))
        floor[j] = math.sqrt(torque_part ** 2 + var_q)
        tau_noise[j] = float(effective_sample_size(nz)[1])
        if white[j] < WHITE_MIN:       # filtered upstream: floor unknown (module docstring)
            floor[j] = np.nan
            tau_noise[j] = max(tau_noise[j], float(effective_sample_size(R[u, j])[1]))
            continue
        rms = float(np.std(R[u, j]))
        if torque_part > FLOOR_ABOVE_RESIDUAL * rms:
            over[j] = torque_part / rms if rms > 0 else np.inf
            floor[j] = np.nan
    return floor, tau_noise, white, over


def _variables(obs, u, j, e):
    """The variables the residual of joint j is tested against (key, x, y), on rows u."""
    t = np.asarray(obs.t, dtype=float)
    q, qd, qdd = (np.asarray(getattr(obs, a), dtype=float) for a in ("q", "qd", "qdd"))
    variables = [(f"q{j + 1}", q[u, j], e), (f"qd{j + 1}", qd[u, j], e),
                 (f"qdd{j + 1}", qdd[u, j], e), ("t", t[u], e),
                 (f"t*sign(qd{j + 1})", t[u], e * np.sign(qd[u, j]))]
    for i in range(q.shape[1]):
        if i != j:
            variables += [(f"q{i + 1}", q[u, i], e), (f"qd{i + 1}", qd[u, i], e)]
    return {"vars": {k_: (x_, y_) for k_, x_, y_ in variables}, "t": t[u], "e": e}


def _dependence_tests(j, variables, e, perms, nbins):
    """Binned-means tests of the residual against each variable (block-permutation null)."""
    nu = e.size
    var_e = float(np.mean(e ** 2))
    out = []
    for key, (x, y) in variables.items():
        ranks = np.argsort(np.argsort(x, kind="stable"), kind="stable")
        b = np.minimum((ranks * nbins) // nu, nbins - 1)
        S = _binned_stat(b, nbins, y)
        null = _binned_null(b, nbins, y, perms)
        p = _satterthwaite_p(S, null)
        struct2 = max(0.0, (S - float(np.mean(null))) / nu)
        rms = math.sqrt(struct2)
        rest = math.sqrt(max(var_e - struct2, 1e-300))
        out.append(StructureTest(j + 1, "dependence", key, S, p, rms=rms, noise_rms=rest,
                                 ratio=rms / rest))
    return out


def _full_rate_line(eobs, j, full_residual, full_mask, thr_j, full_block, n_perm, rng, rest_rms):
    """(StructureTest or None, (q, e) at the full rate): the spectral line against q_j."""
    fu = np.ones(full_residual.shape[0], bool) if full_mask is None else full_mask[:, j]
    fu = fu & ~(np.abs(np.asarray(eobs.qd, float)[:, j]) < EDGE_FACTOR * thr_j)
    ef = full_residual[fu, j] - full_residual[fu, j].mean()
    Lf = full_block or int(max(20, math.ceil(eobs.fs / float(eobs.settings.get(
        "f_decimation_cutoff") or eobs.fs / 100))))
    Lf = int(min(Lf, max(2, ef.size // 50)))
    x = np.asarray(eobs.q, float)[fu, j]
    return _line_test(j, x, ef, Lf, n_perm, rng, rest_rms), (x, ef)


def _step_test(j, t, e, perms):
    """A step in time: the CUSUM's largest excursion against its block-permutation null."""
    nu = e.size
    var_e = float(np.mean(e ** 2))
    C, kstep = _cusum(e)
    null = np.array([_cusum(e[p])[0] for p in perms])
    scale = float(np.mean(null)) / 0.8687
    p = float(stats.kstwobign.sf(C / scale)) if scale > 0 else 1.0
    f = min(max((kstep + 1) / nu, 1.0 / nu), 1.0 - 1.0 / nu)
    d = float(e[kstep + 1:].mean() - e[:kstep + 1].mean()) if kstep + 1 < nu else 0.0
    # |cusum| at the step = nu f (1 - f) |d|; the step's RMS is |d| sqrt(f (1 - f))
    struct2 = max(0.0, (C * C - float(np.mean(null ** 2))) / (nu * nu * f * (1 - f)))
    rms = math.sqrt(struct2)
    rest = math.sqrt(max(var_e - struct2, 1e-300))
    return StructureTest(j + 1, "step", "t (step)", C, p, rms=rms, noise_rms=rest,
                         ratio=rms / rest, detail={"t_step": float(t[min(kstep + 1, nu - 1)]),
                                                   "step_nm": d})


def _floor_test(j, e, floor_j, tau_noise_j):
    """Excess of the residual variance over the noise floor (chi2 with n_eff)."""
    var_e = float(np.mean(e ** 2))
    neff = max(1.0, e.size / tau_noise_j)
    ratio2 = var_e / floor_j ** 2
    p = float(stats.chi2.sf(neff * ratio2, neff))
    excess = math.sqrt(max(0.0, var_e - floor_j ** 2))
    return StructureTest(j + 1, "noise_floor", "time (coloured residual)", ratio2, p,
                         rms=excess, noise_rms=float(floor_j),
                         ratio=math.sqrt(ratio2), detail={"residual_rms": math.sqrt(var_e)})


def _unexplained(tests, data, n):
    """`Unexplained` per joint with a flagged test: the flagged variable test of largest RMS."""
    out = []
    for j in range(1, n + 1):
        fl = [tt for tt in tests if tt.joint == j and tt.flagged]
        var_fl = [tt for tt in fl if tt.test != "noise_floor"]
        if not fl:
            continue
        best = max(var_fl or fl, key=lambda tt: (tt.rms, -tt.p_value))
        variable = {"line": f"q{j}", "step": "t", "noise_floor": "t"}.get(best.test, best.depends_on)
        out.append(Unexplained(
            joint=j, depends_on=best.depends_on, rms=best.rms, p_value=best.p_value, test=best.test,
            noise_rms=best.noise_rms, variable=variable, period=best.detail.get("period_rad"),
            also=[tt.depends_on for tt in fl if tt is not best]))
        try:
            out[-1].curve, out[-1].curve_label = _curve(best, data.get(j - 1, {}))
        except Exception:          # a figure aid only
            pass
    return out
