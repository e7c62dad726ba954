"""Ordinary and weighted least squares of the inverse dynamic identification model.

Implements section 2 of Gautier, Janot & Vandanjon (2010), eqs. (9)-(16):
the sampled, decimated system Y = W χ + ρ (eq. (9)) with the equations of each
joint grouped together (eq. (10)), its LS solution (eq. (11)), the unbiased
error variance (eq. (13)), the covariance (eq. (14)), the relative standard
deviations (eq. (15)) and the per-joint weighting (eq. (16)).

Data convention: the regressor is `W3` of shape (N, n, b) (samples, joints,
parameters) and the torques `tau` are (N, n). Joints are indexed from 0 in
arguments (`joints=[0, 2]`) and numbered from 1 in messages, as in the paper.

Numerics. The normal equations are never formed. Each joint's block
[W^j | Y^j] is first reduced by a QR factorisation to a (b+1) x (b+1)
triangle; since Q^j has orthonormal columns, ‖Y^j − W^j_S x‖ is preserved
for every column subset S and every joint weight, so OLS, WLS and the
essential-parameter search (`dynid.analysis.estimators.essential`) all solve the small
stacked triangles exactly instead of the r x b system. The small system is
then solved by a column-scaled, column-pivoted QR (scipy.linalg.qr), which
also performs the rank check; the covariance uses R⁻¹, never (WᵀW)⁻¹.

Why one module above 800 lines: OLS, WLS, the reduction, the rank check and the covariance
options all work on one private reduced system (`_System`, `_fit`), whose invariants (the
per-joint triangles, the row masks) a split would have to make public.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from dynid.analysis.estimators import hac
from dynid.analysis.results import IdentificationResult
from dynid.errors import IdentificationError, InputError
from dynid.provenance import data_hash, json_safe

__all__ = ["stack", "ols", "wls", "RANK_RTOL", "UNCERTAINTY", "UNCERTAINTY_WORDS", "check_uncertainty", "identifiable_columns", "identifiable_and_aliased", "Reduction", "reduce_system", "ols_reduced", "wls_reduced"]

#: Default relative tolerance of the rank check: a column-normalised W whose
#: pivoted-QR diagonal falls below RANK_RTOL * |R_11| is declared rank-deficient.
#: sqrt(eps) ≈ 1.5e-8: beyond it (WᵀW) has condition > 1/eps, so the
#: covariance of eq. (14) has no correct digit even though a QR solve would
#: still return numbers.
RANK_RTOL = math.sqrt(np.finfo(float).eps)
#: A column in one joint's equations below this times its norm over all joints is rounding (σ_j, eq. (16)).
ROUNDING_RTOL = 1e-12


# --------------------------------------------------------------------- inputs
def _as_float(name: str, x, ndim: int, shape_doc: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric array of shape {shape_doc}: {exc}") from None
    if a.ndim != ndim:
        raise InputError(
            f"{name} has {a.ndim} dimension(s) (shape {a.shape}) but must have shape {shape_doc}."
        )
    return a


def _check_arrays(W3, tau) -> tuple[np.ndarray, np.ndarray]:
    W3 = _as_float("W3", W3, 3, "(N samples, n joints, b parameters)")
    tau = _as_float("tau", tau, 2, "(N samples, n joints)")
    if tau.shape != W3.shape[:2]:
        raise InputError(
            f"tau has shape {tau.shape} but W3 has shape {W3.shape}: tau must be (N, n) = "
            f"{W3.shape[:2]}, one torque per sample and joint."
        )
    return W3, tau


def stack(W3, tau) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stack the per-joint equations as in eq. (10): Y = [Y^1; ...; Y^n], W likewise.

    Returns `(W, Y, joint_of_row)` with W of shape (n*N, b), Y of shape (n*N,)
    and `joint_of_row` (n*N,) the 0-based joint of each row (joint-major).
    """
    W3, tau = _check_arrays(W3, tau)
    N, n, b = W3.shape
    W = W3.transpose(1, 0, 2).reshape(n * N, b)
    Y = tau.T.reshape(n * N)
    return W, Y, np.repeat(np.arange(n), N)


def _check_names(names, b: int) -> list[str]:
    if isinstance(names, str):
        raise InputError("names must be a list of parameter names, not a single string.")
    names = list(names)
    if len(names) != b:
        raise InputError(
            f"{len(names)} parameter names were given but W3 has {b} columns (axis 2); "
            "give one name per column, in column order."
        )
    bad = [repr(n) for n in names if not isinstance(n, str) or not n]
    if bad:
        raise InputError(f"parameter names must be non-empty strings; got {', '.join(bad)}.")
    seen, dup = set(), []
    for n in names:
        if n in seen and n not in dup:
            dup.append(n)
        seen.add(n)
    if dup:
        raise InputError(f"duplicate parameter name(s) {', '.join(dup)}; every column needs its own name.")
    return names


def _build_mask(row_mask, joints, N: int, n: int) -> np.ndarray:
    mask = np.ones((N, n), dtype=bool)
    if row_mask is not None:
        m = np.asarray(row_mask)
        if m.dtype != bool:
            raise InputError(
                f"row_mask must be a boolean array (True = use the row), got dtype {m.dtype}; "
                "convert it with `mask.astype(bool)` (integer index arrays are not accepted)."
            )
        if m.shape == (N,):
            mask &= m[:, None]
        elif m.shape == (N, n):
            mask &= m
        else:
            raise InputError(
                f"row_mask has shape {m.shape}; it must be ({N},) to select samples or "
                f"({N}, {n}) to select samples per joint."
            )
    if joints is not None:
        idx = np.asarray(joints).reshape(-1)
        if idx.dtype.kind not in "iu" or idx.size == 0 or np.any((idx < 0) | (idx >= n)):
            raise InputError(
                f"joints={list(np.asarray(joints).reshape(-1))} must list 0-based joint indices "
                f"in 0..{n - 1} (W3 has {n} joints)."
            )
        keep = np.zeros(n, dtype=bool)
        keep[idx] = True
        mask &= keep[None, :]
    return mask


def _check_finite(name: str, a: np.ndarray, mask: np.ndarray) -> None:
    bad = ~np.isfinite(a)
    if a.ndim == 3:
        bad = bad.any(axis=2)
    bad &= mask
    if bad.any():
        k, j = np.argwhere(bad)[0]
        raise InputError(
            f"{name} has {int(bad.sum())} non-finite value(s) in the equations used for "
            f"identification (first at sample {k}, joint {j + 1}); fill or drop them, or "
            "exclude those samples with row_mask."
        )


def _check_settings(settings) -> dict:
    if settings is None:
        return {}
    if not isinstance(settings, dict):
        raise InputError(f"settings must be a dict, not {type(settings).__name__}.")
    try:
        return json_safe(settings, "settings")
    except TypeError as exc:
        raise InputError(f"{exc} (settings are written to the JSON results)") from None


@dataclass
class _System:
    """The stacked system (eq. (10)) compressed joint by joint.

    `blocks[j]` is the (b+1) x (b+1) triangle R of the QR factorisation of
    [W^j | Y^j] over the included rows of joint j: columns 0..b-1 stand for
    W^j, column b for Y^j. Any least-squares problem on a column subset and
    with per-joint weights has the same solution and the same per-joint
    residual norms on these triangles as on the full rows.
    """

    W3: np.ndarray
    tau: np.ndarray
    mask: np.ndarray  # (N, n) rows used
    names: list
    blocks: np.ndarray  # (n, b+1, b+1)
    rows: np.ndarray  # (n,) r_j
    y_ss: np.ndarray  # (n,) ‖Y^j‖²
    support: np.ndarray  # (n, b) column k is non-zero in joint j's rows

    n_samples: int = 0
    n_equations: int = 0  # n*N: every equation, included or not

    @property
    def n_joints(self) -> int:
        return self.blocks.shape[0]

    @property
    def n_params(self) -> int:
        return self.blocks.shape[2] - 1

    @property
    def reduced(self) -> bool:
        """True when only the triangles are held (built from a `Reduction`, no W3)."""
        return self.W3 is None


def _build_system(W3, tau, names, row_mask=None, joints=None) -> _System:
    W3, tau = _check_arrays(W3, tau)
    N, n, b = W3.shape
    names = _check_names(names, b)
    mask = _build_mask(row_mask, joints, N, n)
    _check_finite("W3", W3, mask)
    _check_finite("tau", tau, mask)
    blocks = np.zeros((n, b + 1, b + 1))
    rows = mask.sum(axis=0)
    y_ss = np.zeros(n)
    support = np.zeros((n, b), dtype=bool)
    for j in range(n):
        if rows[j] == 0:
            continue
        A = np.empty((rows[j], b + 1))
        A[:, :b] = W3[mask[:, j], j, :]
        A[:, b] = tau[mask[:, j], j]
        support[j] = np.any(A[:, :b] != 0.0, axis=0)
        y_ss[j] = A[:, b] @ A[:, b]
        # mode="r" skips forming Q: only the triangle is needed (see module doc).
        R = sla.qr(A, mode="r", overwrite_a=True, check_finite=False)[0]
        k = min(rows[j], b + 1)
        blocks[j, :k] = R[:k]
    return _System(W3, tau, mask, names, blocks, rows, y_ss, support, N, mask.size)


# ------------------------------------------------------- chunked reduction
@dataclass
class Reduction:
    """The stacked system of eq. (10) reduced to what OLS, WLS and the essential set need.

    Per joint j, `blocks[j]` is a (b+1) x (b+1) upper triangle R^j with
    R^jᵀR^j = [W^j | Y^j]ᵀ[W^j | Y^j]: it holds W^jᵀW^j, W^jᵀY^j and ‖Y^j‖²
    (the normal equations and the residual sum of squares of every fit,
    ‖Y^j − W^j x‖² = ‖R^j [x; −1]‖²) without squaring the condition number of W
    as forming WᵀW would. Reductions of consecutive chunks of one recording add
    up (`a + b`: the two triangles stacked and factorised again, the tall-skinny
    QR of Demmel et al. 2012), so a recording is identified chunk by chunk with
    memory independent of its length; the result equals that of the whole system
    to rounding. `rows`: r_j; `y_ss`: ‖Y^j‖²; `support`: the columns non-zero
    in joint j's rows; `n_samples`, `n_equations`: N and n·N of every chunk.
    """

    names: list
    blocks: np.ndarray  # (n, b+1, b+1)
    rows: np.ndarray  # (n,)
    y_ss: np.ndarray  # (n,)
    support: np.ndarray  # (n, b)
    n_samples: int
    n_equations: int

    def __add__(self, other: Reduction) -> Reduction:
        if not isinstance(other, Reduction):
            return NotImplemented
        if list(other.names) != list(self.names):
            raise InputError(
                f"cannot add reductions of different parameter lists ({', '.join(self.names[:3])}... "
                f"and {', '.join(other.names[:3])}...); reduce every chunk with the same names."
            )
        n, k = self.blocks.shape[0], self.blocks.shape[1]
        blocks = np.zeros_like(self.blocks)
        for j in range(n):
            if other.rows[j] == 0 or self.rows[j] == 0:
                blocks[j] = self.blocks[j] if other.rows[j] == 0 else other.blocks[j]
                continue
            R = sla.qr(np.vstack([self.blocks[j], other.blocks[j]]), mode="r", check_finite=False)[0]
            blocks[j] = R[:k]
        return Reduction(list(self.names), blocks, self.rows + other.rows, self.y_ss + other.y_ss,
                         self.support | other.support, self.n_samples + other.n_samples,
                         self.n_equations + other.n_equations)

    def columns(self, cols) -> Reduction:
        """The reduction of the model restricted to the parameters `cols` (indices)."""
        cols = np.asarray(cols, dtype=int)
        b = len(self.names)
        keep = np.append(cols, b)
        blocks = np.zeros((self.blocks.shape[0], keep.size, keep.size))
        for j in range(self.blocks.shape[0]):
            R = sla.qr(self.blocks[j][:, keep], mode="r", check_finite=False)[0]
            m = min(R.shape[0], keep.size)
            blocks[j, :m] = R[:m]
        return Reduction([self.names[c] for c in cols], blocks, self.rows.copy(), self.y_ss.copy(),
                         self.support[:, cols], self.n_samples, self.n_equations)

    def system(self) -> _System:
        return _System(None, None, None, list(self.names), self.blocks, self.rows, self.y_ss,
                       self.support, self.n_samples, self.n_equations)


def reduce_system(W3, tau, names, *, row_mask=None, joints=None) -> Reduction:
    """The `Reduction` of one chunk (W3 (N, n, b), tau (N, n)); add the chunks' reductions."""
    s = _build_system(W3, tau, names, row_mask, joints)
    return Reduction(s.names, s.blocks, s.rows, s.y_ss, s.support, s.n_samples, s.n_equations)


# --------------------------------------------------------------------- solver
@dataclass
class _Fit:
    cols: np.ndarray  # indices into system.names
    chi: np.ndarray  # (s,)
    cov_unscaled: np.ndarray  # (W̃ᵀW̃)⁻¹ of the (weighted) system
    ss_joint: np.ndarray  # (n,) ‖ρ^j‖², original units
    ss_weighted: float  # ‖W̃χ̂ − Ỹ‖² of the system solved
    cond: float
    cond_scaled: float


def _fit(system: _System, cols: np.ndarray, weights: np.ndarray, rank_rtol: float) -> _Fit:
    """Weighted LS of eq. (11) on the compressed system, with rank check.

    `weights` (n,) multiply the rows of each joint (1 for OLS, 1/σ_j for WLS).
    """
    cols = np.asarray(cols, dtype=int)
    s, n, b = cols.size, system.n_joints, system.n_params
    active = np.flatnonzero(system.rows > 0)
    r = int(system.rows.sum())
    if r <= s:
        raise IdentificationError(
            f"only {r} equations are used for {s} parameters; eq. (13) needs more rows than "
            "parameters. Record a longer trajectory, decimate less, include more joints/rows, "
            "or identify fewer parameters; if the velocity dead zone (--qd-threshold, "
            "qd_threshold) is above the joint speeds it drops every row: lower it."
        )
    w = np.asarray(weights, dtype=float)[active]
    blocks = system.blocks[active]
    M = (blocks[:, :, cols] * w[:, None, None]).reshape(-1, s)
    c = (blocks[:, :, b] * w[:, None]).reshape(-1)

    # Unit-norm columns make the rank tolerance independent of parameter units
    # (an inertia column can be 1e3 times smaller than a friction column).
    norms = np.sqrt(np.einsum("ij,ij->j", M, M))
    nonzero = norms > 0.0
    Ms = M[:, nonzero] / norms[nonzero]
    if Ms.shape[1]:
        Q, R, piv = sla.qr(Ms, mode="economic", pivoting=True, check_finite=False)
    else:  # every column is zero: nothing to factorise, the error names them all
        Q, R, piv = Ms, np.zeros((0, 0)), np.zeros(0, dtype=int)
    d = np.abs(np.diag(R))
    small = np.flatnonzero(d <= rank_rtol * d[0]) if d.size else np.array([], dtype=int)
    rank = int(small[0]) if small.size else d.size
    sv_scaled = sla.svdvals(R) if rank == d.size else None
    if (
        not nonzero.all()
        or rank < d.size
        or (sv_scaled is not None and sv_scaled[-1] <= rank_rtol * sv_scaled[0])
    ):
        raise _rank_error(system, cols, nonzero, R, piv, rank, rank_rtol, Ms)

    y = sla.solve_triangular(R, Q.T @ c, check_finite=False)
    chi = np.empty(s)
    chi[piv] = y / norms[piv]
    # (MᵀM)⁻¹ = D⁻¹ P R⁻¹ R⁻ᵀ Pᵀ D⁻¹: only the triangle is inverted, which keeps
    # cond(W) rather than cond(W)² as the error amplification of eq. (14).
    Rinv = sla.solve_triangular(R, np.eye(s), check_finite=False)
    cov_unscaled = np.empty((s, s))
    cov_unscaled[np.ix_(piv, piv)] = Rinv @ Rinv.T
    cov_unscaled /= np.outer(norms, norms)

    res = (c - M @ chi).reshape(active.size, b + 1)
    ssw = np.einsum("ij,ij->i", res, res)
    ss_joint = np.zeros(n)
    ss_joint[active] = ssw / w**2
    sv = sla.svdvals(M, check_finite=False)
    return _Fit(
        cols=cols,
        chi=chi,
        cov_unscaled=cov_unscaled,
        ss_joint=ss_joint,
        ss_weighted=float(ssw.sum()),
        cond=float(sv[0] / sv[-1]),
        cond_scaled=float(sv_scaled[0] / sv_scaled[-1]),
    )


def _joint_list(js) -> str:
    js = [int(j) + 1 for j in js]
    if not js:
        return ""
    return ("joint " if len(js) == 1 else "joints ") + ", ".join(map(str, js))


def _rank_error(system, cols, nonzero, R, piv, rank, rank_rtol, Ms) -> IdentificationError:
    """Name the parameters W cannot identify and say what to do about them."""
    names = [system.names[c] for c in cols]
    lines = []
    for k in np.flatnonzero(~nonzero):
        col = cols[k]
        elsewhere = (np.array([], dtype=int) if system.reduced
                     else np.flatnonzero(np.any(system.W3[:, :, col] != 0.0, axis=0)))
        if elsewhere.size:
            hint = (
                f"it only appears in rows excluded by row_mask/joints ({_joint_list(elsewhere)}); "
                f"include those rows, or remove {names[k]!r} from the model."
            )
        else:
            hint = (
                f"the trajectory does not excite it at all; excite the joint motion it describes, "
                f"or remove {names[k]!r} from the model."
            )
        lines.append(f"  - {names[k]!r}: its column of W is all zero; {hint}")

    nz = np.flatnonzero(nonzero)  # positions in cols of the columns given to the QR
    p = R.shape[1]
    if rank < p:
        coef = sla.solve_triangular(R[:rank, :rank], R[:rank, rank:], check_finite=False)
        norms = None
        for i, q in enumerate(piv[rank:]):
            k = nz[q]
            c = coef[:, i]
            order = np.argsort(-np.abs(c))
            terms = []
            for t in order[:4]:
                if abs(c[t]) <= 1e-6 * max(np.abs(c).max(), 1e-300):
                    break
                # Coefficients are for unit-norm columns; rescale to the raw columns.
                if norms is None:
                    norms = _raw_norms(system, cols)
                kk = nz[piv[t]]
                terms.append(f"{c[t] * norms[k] / norms[kk]:+.3g} x {names[kk]!r}")
            combo = " ".join(terms) if terms else "the other columns"
            if len(order) > 4 and len(terms) == 4:
                combo += " + ..."
            js = np.flatnonzero(system.support[:, cols[k]])
            lines.append(
                f"  - {names[k]!r}: its column is (numerically) {combo}, so only a combination "
                f"can be estimated. Excite {_joint_list(js) or 'the joints'} with a richer trajectory "
                f"(both directions of motion, a longer or wider one); in Python, a model of your own "
                f"can also regroup them into base parameters or remove {names[k]!r}."
            )
    if not lines:
        # Pivoted QR missed a near-deficiency the singular values show: name the
        # parameters carrying the smallest right singular vector.
        _, sv, Vt = np.linalg.svd(Ms, full_matrices=False)
        v = Vt[-1]
        big = np.argsort(-np.abs(v))[:4]
        involved = ", ".join(repr(names[nz[i]]) for i in big if abs(v[i]) > 0.1)
        lines.append(
            f"  - {involved}: nearly linearly dependent (smallest/largest singular value "
            f"{sv[-1] / sv[0]:.2g}); excite the robot with a richer trajectory (in Python, a model "
            "of your own can also regroup into base parameters or remove one of them)."
        )
    n_bad = len(lines)
    return IdentificationError(
        f"W is rank-deficient: {n_bad} of {len(names)} parameters cannot be identified from "
        f"these data (column-scaled pivoted QR, relative tolerance {rank_rtol:.2g}).\n"
        + "\n".join(lines)
    )


def identifiable_columns(W3, mask=None, rank_rtol: float = RANK_RTOL) -> np.ndarray:
    """Indices of the columns of W3 that the rows `mask` (N, n) identify together.

    Column-scaled pivoted QR of the stacked rows (the rank check of `ols`): the
    columns pivoted before the rank drop, in increasing order; zero columns and
    columns dependent on earlier pivots are left out.
    """
    return identifiable_and_aliased(W3, mask, rank_rtol)[0]


def identifiable_and_aliased(W3, mask=None, rank_rtol: float = RANK_RTOL, alias_rtol: float = 1e-3):
    """The columns of W3 the rows `mask` (N, n) identify, and those of them that absorb a column
    left out.

    A column left out for being (numerically) a combination of others, say
    `Fcm6 = 1.04 Off6 + 0.96 Off5` on a segment where motor 6 never reverses, does not vanish
    from the fit without it: `Off5` and `Off6` take its torque there, so their estimates mean
    something else than on data where all three are identified.

    Returns
    -------
    identifiable, aliased : ndarray of int
        Increasing column indices: those identified together (`identifiable_columns`), and
        those among them whose coefficient in the combination giving a left-out column
        (column-scaled) exceeds `alias_rtol` times the largest.
    """
    W3 = np.asarray(W3, dtype=float)
    mask = np.ones(W3.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    X = np.where(mask[:, :, None], W3, 0.0).transpose(1, 0, 2).reshape(-1, W3.shape[2])
    norms = np.linalg.norm(X, axis=0)
    nz = np.flatnonzero(norms > 0)
    if not nz.size:
        return nz, nz
    _, R, piv = sla.qr(X[:, nz] / norms[nz], mode="economic", pivoting=True, check_finite=False)
    d = np.abs(np.diag(R))
    rank = int(np.count_nonzero(d > rank_rtol * d[0]))
    kept = nz[piv[:rank]]
    if rank == R.shape[1]:
        return np.sort(kept), np.array([], dtype=int)
    coef = np.abs(sla.solve_triangular(R[:rank, :rank], R[:rank, rank:], check_finite=False))
    big = coef > alias_rtol * np.maximum(coef.max(axis=0, keepdims=True), 1e-300)
    return np.sort(kept), np.sort(kept[big.any(axis=1)])


def _raw_norms(system: _System, cols) -> np.ndarray:
    B = system.blocks[:, :, cols]
    return np.sqrt(np.einsum("ijk,ijk->k", B, B))


# ------------------------------------------------------------------- results
#: The covariances an estimate can carry (option ``uncertainty``).
UNCERTAINTY = ("classic", "hac", "bootstrap")

#: the covariance options in a few words, for captions and summaries
UNCERTAINTY_WORDS = {"classic": "eq. (14)", "hac": "HAC sandwich", "bootstrap": "circular block bootstrap"}

_UNCERTAINTY_LABEL = {
    "classic": "classic: sigma_rho^2 (W'W)^-1 of eqs. (13)-(14), samples counted as independent",
    "hac": "hac: Newey-West sandwich, Bartlett kernel, Andrews (1991) bandwidth, scores summed over joints per sample",
    "bootstrap": ("bootstrap: circular block bootstrap of the decimated samples with equations (Politis & "
                  "Romano 1992), block length of Politis & White (2004) from the scores, longer for a parameter "
                  "whose own influence series needs it, sigma = 95 % percentile half-width / 1.96"),
}


def check_uncertainty(uncertainty) -> str:
    """The name of a covariance option, checked (one of `UNCERTAINTY`)."""
    if uncertainty not in UNCERTAINTY:
        raise InputError(
            f"uncertainty must be one of {', '.join(UNCERTAINTY)}, got {uncertainty!r}: 'classic' is "
            "eq. (14) of Gautier et al. (independent samples), 'hac' a Newey-West sandwich, "
            "'bootstrap' a block bootstrap over time."
        )
    return uncertainty


def _robust(system, fit, weights, uncertainty, groups, n_boot, seed):
    """Covariance and description of `uncertainty` for the fit (None for classic)."""
    if uncertainty == "classic":
        return None, {"uncertainty": "classic", "covariance": _UNCERTAINTY_LABEL["classic"]}
    if system.reduced:
        raise InputError(
            f"uncertainty={uncertainty!r} needs the samples (a time series of scores); a Reduction "
            "holds only the triangles: use uncertainty='classic' or pass W3 and tau."
        )
    full = fit.cols.size == system.n_params and np.array_equal(fit.cols, np.arange(system.n_params))
    sub = system.W3 if full else system.W3[:, :, fit.cols]
    w = np.where(system.rows > 0, np.asarray(weights, dtype=float), 0.0)
    if groups is not None:
        groups = np.asarray(groups).reshape(-1)
        if groups.size != system.n_samples:
            raise InputError(f"groups has {groups.size} entries for {system.n_samples} samples: give the "
                             "recording of every sample.")
    if uncertainty == "hac":
        cov, info = hac.hac_covariance(sub, system.tau, system.mask, fit.chi, w, fit.cov_unscaled,
                                       groups=groups)
    else:
        try:
            cov, info = hac.bootstrap_covariance(sub, system.tau, system.mask, fit.chi, w, groups=groups,
                                                 n_boot=n_boot, seed=seed)
            # by name: an essential fit carries its full model's covariance settings
            info["parameter_blocks"] = dict(zip((system.names[c] for c in fit.cols), info["parameter_blocks"]))
        except ValueError as exc:
            # too few samples for blocks that keep every parameter identified: the sandwich
            # needs no refit, so it stands in (and the result says so)
            cov, info = hac.hac_covariance(sub, system.tau, system.mask, fit.chi, w, fit.cov_unscaled,
                                           groups=groups)
            return cov, {"uncertainty": "hac", "covariance": _UNCERTAINTY_LABEL["hac"], **info,
                         "requested": "bootstrap",
                         "fallback": f"bootstrap impossible ({exc}): the resampled data do not identify "
                                     "every parameter"}
    return cov, {"uncertainty": uncertainty, "covariance": _UNCERTAINTY_LABEL[uncertainty], **info}


def _make_result(method, system, fit, sigma_rho, joint_sigma, settings, notices,
                 robust_cov=None) -> IdentificationResult:
    names = [system.names[c] for c in fit.cols]
    W3, tau, mask = system.W3, system.tau, system.mask
    if system.reduced:
        # no samples held: the residual sums come from the triangles (equal to rounding)
        residual = np.zeros((0, system.n_joints))
        ss_j = fit.ss_joint
        digest = data_hash(system.blocks, system.rows, system.y_ss)
    else:
        full = fit.cols.size == system.n_params and np.array_equal(fit.cols, np.arange(system.n_params))
        sub = W3 if full else W3[:, :, fit.cols]
        with np.errstate(invalid="ignore", over="ignore"):
            residual = tau - sub @ fit.chi
        used = np.where(mask, residual, 0.0)
        ss_j = np.einsum("ij,ij->j", used, used)
        digest = data_hash(W3, tau, mask)
    with np.errstate(divide="ignore", invalid="ignore"):
        rms = np.sqrt(ss_j / system.rows)
        joint_rel = np.sqrt(ss_j / system.y_ss)
        rel_error = float(np.sqrt(ss_j.sum() / system.y_ss.sum()))
    return IdentificationResult(
        method=method,
        names=names,
        chi=fit.chi,
        cov=sigma_rho**2 * fit.cov_unscaled if robust_cov is None else robust_cov,
        sigma_rho=float(sigma_rho),
        residual=residual,
        rel_error=rel_error,
        rms=rms,
        joint_rel_error=joint_rel,
        cond=fit.cond,
        cond_scaled=fit.cond_scaled,
        n_samples=system.n_samples,
        n_joints=system.n_joints,
        n_rows=int(system.rows.sum()),
        joint_sigma=joint_sigma,
        settings=settings,
        notices=notices,
        data_hash=digest,
    )


def _row_notices(system: _System) -> list[str]:
    notices = []
    total = system.n_equations
    excluded = total - int(system.rows.sum())
    if excluded:
        notices.append(f"{excluded} of {total} equations were excluded by row_mask/joints.")
    empty = np.flatnonzero(system.rows == 0)
    if empty.size:
        notices.append(
            f"{_joint_list(empty)} contribute(s) no equation; per-joint statistics are NaN there."
        )
    return notices


def _check_rtol(rank_rtol) -> float:
    rtol = float(rank_rtol)
    if not 0.0 < rtol < 1.0:
        raise InputError(f"rank_rtol must be in (0, 1), got {rank_rtol!r}; the default is {RANK_RTOL:.3g}.")
    return rtol


def _solver_settings(method: str, rank_rtol: float, row_mask, joints) -> dict:
    return {
        "estimator": method,
        "solver": "per-joint QR compression + column-scaled pivoted QR (scipy.linalg.qr)",
        "rank_rtol": rank_rtol,
        "row_mask": row_mask is not None,
        "joints": None if joints is None else [int(j) for j in np.asarray(joints).reshape(-1)],
        "cond": "2-norm condition number of the solved (weighted) W; cond_scaled: unit-norm columns",
    }


def ols(W3, tau, names, *, row_mask=None, joints=None, rank_rtol: float = RANK_RTOL, settings=None,
        uncertainty: str = "classic", groups=None, n_boot: int = 300, seed: int = 0) -> IdentificationResult:
    """Ordinary least squares χ̂ = W⁺Y of eq. (11) with the statistics of eqs. (13)-(15).

    Parameters
    ----------
    W3 : array (N, n, b)
        Regressor samples (decimated observation matrix, eq. (9)), per joint.
    tau : array (N, n)
        Measured joint torques.
    names : sequence of b str
        Parameter names, e.g. `"ZZ1R"`, `"Fv1"`.
    row_mask : bool array (N,) or (N, n), optional
        True for the equations to use; (N,) selects samples for every joint.
    joints : sequence of int, optional
        0-based joints whose equations are used (default: all).
    rank_rtol : float
        Relative tolerance of the rank check (see `RANK_RTOL`).
    settings : dict, optional
        JSON-safe settings to record with the result (e.g. filter cut-offs);
        the estimator adds its own under `"least_squares"`.
    uncertainty : {"classic", "hac", "bootstrap"}
        The covariance reported. "classic": eq. (14), the samples counted as
        independent (the papers' σ). "hac": a Newey-West sandwich whose
        scores sum the joints of each sample (residual correlated in time and
        across joints; bandwidth of Andrews 1991). "bootstrap": a circular
        block bootstrap of the decimated samples that carry equations (block
        length by the rule of Politis & White 2004 on the scores, σ the
        half-width of the 95 % percentile interval over 1.96; see
        dynid.analysis.estimators.hac). The estimate is the same for all three; the
        choice is recorded in `settings["least_squares"]["uncertainty"]`
        and in a notice.
    groups : array (N,), optional
        Recording of each sample, for "hac" and "bootstrap": no lag and no
        block crosses from one recording to the next.
    n_boot, seed : int
        Replicates and seed of the "bootstrap" option.

    Returns
    -------
    IdentificationResult
        σ̂_ρ² = ‖Y − Wχ̂‖²/(r − b) (eq. (13)), cov = σ̂_ρ² (WᵀW)⁻¹ (eq. (14))
        or the robust covariance, %σ = 100 σ/|χ̂| (eq. (15)).

    Raises
    ------
    InputError
        Shapes, names, masks or non-finite values are wrong.
    IdentificationError
        W is (nearly) rank-deficient: the message names the parameters and
        what to do; or there are not more rows than parameters.
    """
    check_uncertainty(uncertainty)
    system = _build_system(W3, tau, names, row_mask, joints)
    return _ols_system(system, rank_rtol, settings, row_mask, joints,
                       (uncertainty, groups, n_boot, seed))


def ols_reduced(reduction: Reduction, *, rank_rtol: float = RANK_RTOL, settings=None) -> IdentificationResult:
    """`ols` of a system given by its `Reduction` (chunked recordings).

    Same estimate, covariance and residual statistics as `ols` on the whole
    W3 to rounding; `residual` is empty (the samples are not held).
    """
    return _ols_system(reduction.system(), rank_rtol, settings, None, None)


def _ols_system(system, rank_rtol, settings, row_mask, joints,
                robust=("classic", None, 0, 0)) -> IdentificationResult:
    rtol = _check_rtol(rank_rtol)
    user = _check_settings(settings)
    b = system.n_params
    fit = _fit(system, np.arange(b), np.ones(system.n_joints), rtol)
    r = int(system.rows.sum())
    sigma_rho = math.sqrt(fit.ss_weighted / (r - b))  # eq. (13)
    weights = np.ones(system.n_joints)
    cov, unc = _robust(system, fit, weights, *robust)
    cfg = {**user, "least_squares": {**_solver_settings("OLS", rtol, row_mask, joints), "uncertainty": unc}}
    return _make_result("OLS", system, fit, sigma_rho, None, cfg, _row_notices(system) + _unc_notice(unc),
                        cov)


def _unc_notice(unc: dict) -> list[str]:
    if unc["uncertainty"] == "classic":
        return []
    extra = (f"bandwidth {unc['bandwidth']:.3g} samples" if unc["uncertainty"] == "hac"
             else f"blocks of {unc['block']} samples ({unc.get('block_rule', 'given')} rule"
                  f"{_longer_blocks(unc)}), "
                  f"{unc['n_boot'] - unc['failed']} replicates, sigma from "
                  f"{'their 95 % percentile interval' if unc.get('spread') == 'percentile' else 'their covariance'}")
    note = f"sigma is the {unc['uncertainty']} covariance ({extra}), not the classic eq. (14)."
    if "fallback" in unc:
        note += f" The {unc['requested']} covariance was asked for: {unc['fallback']}."
    return [note]


def _longer_blocks(unc: dict) -> str:
    """The notice's words on the parameters whose σ also comes from a longer block."""
    blocks = list(dict(unc.get("parameter_blocks", {})).values())
    longer = sorted({b for b in blocks if b != unc["block"]})
    n = sum(b != unc["block"] for b in blocks)
    out = f"; {n} parameter{'s' if n > 1 else ''} with longer blocks of {', '.join(map(str, longer))}" if n else ""
    if unc.get("longer_blocks_failed"):
        out += (f"; blocks of {', '.join(map(str, unc['longer_blocks_failed']))} given up (too few replicates "
                "could be refitted): their parameters' sigma may be optimistic")
    return out


def _joint_sigma(system: _System, rank_rtol: float) -> np.ndarray:
    """σ_j of eq. (16): error standard deviation of the OLS solution of joint j's equations.

    For each joint, Y^j = W^j χ + ρ^j (eq. (16)) is solved alone by OLS and
    σ_j² = ‖Y^j − W^j χ̂^j‖² / (r_j − b_j), where b_j is the numerical rank of
    W^j (same column-scaled pivoted QR and tolerance as the main rank check).
    b_j is the number of parameters joint j's equations can identify: the
    parameters with a non-zero column in joint j's rows, less any that are
    dependent within those rows (joint j's equations alone need not identify
    all of them; only the projection of Y^j off the range of W^j matters,
    which is unique). So σ_j is the unbiased eq. (13) applied to joint j.

    Why not the residual of the joint OLS of all equations: its joint-j part
    also carries W^j(χ̂ − χ), and χ̂ is mostly perturbed by the noisiest joint;
    with one joint 20 times noisier than another, σ of the quiet joint comes
    out ~40 % too large, which defeats the purpose of the weighting.
    """
    b = system.n_params
    sig = np.full(system.n_joints, np.nan)
    joint_norms = np.sqrt(np.einsum("jik,jik->jk", system.blocks[:, :, :b], system.blocks[:, :, :b]))
    # a column at rounding level in joint j's rows (a regrouped parameter that joint j does not
    # see, e.g. ZZ2R in joint 1's rows at 1e-19 of its norm over all joints) is absent there:
    # scaled to unit norm it would be noise that takes a dof and makes σ_j depend on the
    # machine's rounding. Compared with the same column over all joints, whatever its units.
    floor = ROUNDING_RTOL * np.sqrt(np.sum(joint_norms**2, axis=0))
    for j in np.flatnonzero(system.rows > 0):
        A = system.blocks[j]
        norms = joint_norms[j]
        nz = np.flatnonzero(norms > floor)
        c = A[:, b]
        rank = 0
        if nz.size:
            Q, R, _ = sla.qr(A[:, nz] / norms[nz], mode="economic", pivoting=True, check_finite=False)
            d = np.abs(np.diag(R))
            rank = int(np.count_nonzero(d > rank_rtol * d[0]))
            Qr = Q[:, :rank]
            c = c - Qr @ (Qr.T @ c)
        dof = int(system.rows[j]) - rank
        if dof < 1:
            raise IdentificationError(
                f"joint {j + 1} has {system.rows[j]} equation(s) for {rank} parameter(s) it can "
                f"identify on its own, so its error level σ_{j + 1} of eq. (16) cannot be estimated; "
                "add samples for that joint or pass joint_sigma explicitly."
            )
        sig[j] = math.sqrt(float(c @ c) / dof)
        if not sig[j] > 0.0:
            raise IdentificationError(
                f"joint {j + 1}'s torque tau{j + 1} has no variation the model cannot explain: "
                f"the residual of its equations (eq. (16)) is exactly zero, so its error level "
                f"σ_{j + 1} and the weight 1/σ_{j + 1} cannot be computed. Usually tau{j + 1} "
                "is all zero or constant (a torque column that was not logged, or a drive gain "
                f"of 0): check the torque column tau{j + 1} (or current i{j + 1} and its drive "
                "gain) in the data file."
            )
    return sig


def _check_joint_sigma(joint_sigma, system: _System) -> np.ndarray:
    n = system.n_joints
    try:
        sig = np.asarray(joint_sigma, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"joint_sigma must be {n} positive numbers, one per joint.") from None
    if sig.size != n:
        raise InputError(f"joint_sigma has {sig.size} value(s) but W3 has {n} joints; give one σ_j per joint.")
    used = system.rows > 0
    bad = np.flatnonzero(used & ~(np.isfinite(sig) & (sig > 0)))
    if bad.size:
        raise InputError(
            f"joint_sigma must be finite and positive for every joint with equations; "
            f"{_joint_list(bad)} got {', '.join(str(sig[j]) for j in bad)}."
        )
    return np.where(used, sig, np.nan)


def wls(
    W3,
    tau,
    names,
    *,
    row_mask=None,
    joints=None,
    joint_sigma=None,
    rank_rtol: float = RANK_RTOL,
    settings=None,
    uncertainty: str = "classic",
    groups=None,
    n_boot: int = 300,
    seed: int = 0,
) -> IdentificationResult:
    """Weighted least squares with per-joint weights 1/σ_j (eq. (16), Gautier 1997).

    1. Unless `joint_sigma` is given, estimate σ_j as the standard deviation
       of the error of the OLS solution of joint j's equations (eq. (16)):
       σ_j² = ‖ρ^j‖² / (r_j − b_j), with r_j the rows of joint j and b_j the
       numerical rank of W^j, i.e. the number of parameters with a non-zero
       column in joint j's rows that joint j's equations can separate
       (degrees-of-freedom choice and reasons in `_joint_sigma`).
    2. Divide the rows of W^j and Y^j by σ_j and solve the weighted system by LS.
    3. σ̂² of the weighted residual by eq. (13) (reported as `sigma_rho`,
       dimensionless, ≈ 1), covariance σ̂² (WᵀΣ⁻¹W)⁻¹ by eq. (14) applied to the
       weighted system. Keeping the factor σ̂² (instead of assuming the σ_j
       exact, cov = (WᵀΣ⁻¹W)⁻¹) absorbs a common scale error in the σ_j.

    Residual statistics (`rel_error`, `rms`, `joint_rel_error`,
    `residual`) are in the original, unweighted units. `cond` is that of
    the weighted W. Other arguments as in `ols`; `joint_sigma` (n,)
    fixes the σ_j instead of estimating them (`nan` allowed for joints
    without equations); `uncertainty`, `groups`, `n_boot` and `seed`
    choose the covariance as in `ols` (the sandwich and the bootstrap
    keep the weights 1/σ_j fixed).
    """
    check_uncertainty(uncertainty)
    system = _build_system(W3, tau, names, row_mask, joints)
    return _wls_system(system, joint_sigma, rank_rtol, settings, row_mask, joints,
                       (uncertainty, groups, n_boot, seed))


def wls_reduced(reduction: Reduction, *, joint_sigma=None, rank_rtol: float = RANK_RTOL,
                settings=None) -> IdentificationResult:
    """`wls` of a system given by its `Reduction` (chunked recordings).

    The σ_j of eq. (16), the weighted solution and its statistics need only the
    per-joint triangles, so they equal `wls` on the whole W3 to rounding;
    `residual` is empty (the samples are not held).
    """
    return _wls_system(reduction.system(), joint_sigma, rank_rtol, settings, None, None)


def _wls_system(system, joint_sigma, rank_rtol, settings, row_mask, joints,
                robust=("classic", None, 0, 0)) -> IdentificationResult:
    rtol = _check_rtol(rank_rtol)
    user = _check_settings(settings)
    b, n = system.n_params, system.n_joints
    cols = np.arange(b)
    if joint_sigma is None:
        _fit(system, cols, np.ones(n), rtol)  # OLS first: rank errors take precedence
        sig = _joint_sigma(system, rtol)
        source = "estimated by OLS of each joint's equations (eq. 16), dof r_j - rank(W^j)"
    else:
        sig = _check_joint_sigma(joint_sigma, system)
        source = "given (joint_sigma)"
    weights = np.where(system.rows > 0, 1.0 / np.where(np.isnan(sig), 1.0, sig), 0.0)
    fit = _fit(system, cols, weights, rtol)
    r = int(system.rows.sum())
    sigma_rho = math.sqrt(fit.ss_weighted / (r - b))  # eq. (13) on the weighted system
    cov, unc = _robust(system, fit, weights, *robust)
    cfg = {**user, "least_squares": {**_solver_settings("WLS", rtol, row_mask, joints), "joint_sigma": source,
                                     "uncertainty": unc}}
    return _make_result("WLS", system, fit, sigma_rho, sig, cfg, _row_notices(system) + _unc_notice(unc),
                        cov)
