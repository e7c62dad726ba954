"""Scores of candidate effects against a model: blocked cross-validation and the
likelihood-ratio statistic with the effective sample size (the two checks of the
selection rule, see dynid.analysis.diagnosis.rule), and the column-span checks
(which candidate columns add to the model).
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla
from scipy import stats

from dynid.analysis.statistics.residuals import effective_sample_size
from dynid.threads import with_single_blas_thread

__all__ = ["ALIAS_RTOL", "Scorer", "lr_statistics", "weighted_sse", "shift_scores", "chi2_logsf",
           "chi2_logsf_many",
           "new_columns", "independent_columns", "separability"]

#: Column tolerance of the rank check: a candidate column whose part outside the
#: model's span is below this fraction of its norm adds nothing (alias of the model).
ALIAS_RTOL = 1e-6


# ======================================================================= scoring
class Scorer:
    """Blocked-CV and full-data scores of many candidates against one model.

    Rows are the used equations (sample i, joint j), weighted by w_j. For each
    fold (and for all rows) the model's columns are factorised once (pivoted
    QR); a candidate's fit is then the small least-squares problem of its
    columns projected off the model's span, and its held-out prediction
    X_V theta + C_V beta = pred0_V + (C_V - X_V R^-1 Q^T C_T) beta.
    """

    def __init__(self, X, Y, mask, weights, n_folds, gap):
        M, n, p = X.shape
        self.M, self.n, self.p = M, n, p
        self.mask = mask
        ri, rj = np.nonzero(mask)
        self.ri, self.rj = ri, rj
        w = np.asarray(weights, dtype=float)
        self.w = w
        self.Xw = X[ri, rj, :] * w[rj][:, None]
        self.yw = Y[ri, rj] * w[rj]
        edges = np.linspace(0, M, n_folds + 1).round().astype(int)
        self.folds = []
        for f in range(n_folds):
            a, b = edges[f], edges[f + 1]
            test = (ri >= a) & (ri < b)
            train = (ri < a - gap) | (ri >= b + gap)
            self.folds.append(self._factor(train, test))
        self.full = self._factor(np.ones(ri.size, dtype=bool), None)
        self.n_folds = n_folds

    def _factor(self, train, test):
        A = self.Xw[train]
        Q, R, piv = sla.qr(A, mode="economic", pivoting=True, check_finite=False)
        d = np.abs(np.diag(R))
        r = int(np.count_nonzero(d > 1e-10 * d[0])) if d.size else 0
        Q, R = Q[:, :r], R[:r, :r]
        yT = self.yw[train]
        py = Q.T @ yT
        yperp = yT - Q @ py
        out = {"train": train, "test": test, "Q": Q, "py": py, "yperp": yperp}
        if test is not None:
            XV = self.Xw[test][:, piv[:r]]
            G = sla.solve_triangular(R, XV.T, trans="T", check_finite=False).T   # X_V R^-1
            out.update(G=G, pred0=G @ py, yV=self.yw[test])
            out["err0"] = float(np.sum((out["yV"] - out["pred0"]) ** 2))
        else:
            out["sse0_rows"] = yperp ** 2
        return out

    def rows(self, C):
        """Weighted used rows (r, k) of decimated columns C (M, n, k)."""
        return C[self.ri, self.rj, :] * self.w[self.rj][:, None]

    @with_single_blas_thread
    def score(self, Cw_list):
        """Scores of candidates given as weighted row blocks (r, k_c).

        Returns dict of arrays over candidates: err (n_folds, m) held-out
        errors, err0 (n_folds,), active (list of kept column indices),
        res (r, m) full-data residual rows, sse0_rows (r,).
        """
        m = len(Cw_list)
        widths = [c.shape[1] for c in Cw_list]
        Call = np.concatenate(Cw_list, axis=1) if m else np.zeros((self.yw.size, 0))
        starts = np.concatenate([[0], np.cumsum(widths)])
        # full data: projection, rank check, residuals
        F = self.full
        PC = F["Q"].T @ Call
        Cperp = Call - F["Q"] @ PC
        norms = np.linalg.norm(Call, axis=0)
        active, res = [], np.zeros((self.yw.size, m))
        for c in range(m):
            s = slice(starts[c], starts[c + 1])
            keep = independent_columns(Cperp[:, s], norms[s])
            active.append(keep)
            if keep:
                cols = starts[c] + np.asarray(keep)
                beta = np.linalg.lstsq(Cperp[:, cols], F["yperp"], rcond=None)[0]
                res[:, c] = F["yperp"] - Cperp[:, cols] @ beta
            else:
                res[:, c] = F["yperp"]
        err = np.full((self.n_folds, m), np.nan)
        err0 = np.zeros(self.n_folds)
        for f, D in enumerate(self.folds):
            CT = Call[D["train"]]
            CV = Call[D["test"]]
            PCT = D["Q"].T @ CT
            CperpT = CT - D["Q"] @ PCT
            H = CV - D["G"] @ PCT
            err0[f] = D["err0"]
            for c in range(m):
                if not active[c]:
                    err[f, c] = D["err0"]
                    continue
                cols = starts[c] + np.asarray(active[c])
                beta = np.linalg.lstsq(CperpT[:, cols], D["yperp"], rcond=None)[0]
                pred = D["pred0"] + H[:, cols] @ beta
                err[f, c] = float(np.sum((D["yV"] - pred) ** 2))
        return {"err": err, "err0": err0, "active": active, "res": res,
                "sse0_rows": F["sse0_rows"], "res0": F["yperp"]}

    def per_joint(self, rows_vec):
        """Scatter used-row values (r, m) into (M, n, m) (zeros elsewhere)."""
        rows_vec = rows_vec.reshape(rows_vec.shape[0], -1)
        out = np.zeros((self.M, self.n, rows_vec.shape[1]))
        out[self.ri, self.rj, :] = rows_vec
        return out


def lr_statistics(scorer, scores, k_params):
    """LR with effective sample sizes, per candidate; also n_eff totals."""
    res = scores["res"]
    m = res.shape[1]
    E1 = scorer.per_joint(res)                       # (M, n, m)
    E0 = scorer.per_joint(scores["res0"])            # (M, n, m) baseline of each candidate
    mask = scorer.mask
    sse1 = (E1 ** 2).sum(axis=0)                     # (n, m)
    sse0 = (E0 ** 2).sum(axis=0)                     # (n, m)
    if m == 0:
        return np.zeros(0), np.zeros(0)
    flat = E1.reshape(scorer.M, scorer.n * m)
    mflat = np.repeat(mask, m, axis=1)
    # columns ordered (joint, candidate) after the reshape of (M, n, m)
    n_eff, tau, _, n_used = effective_sample_size(flat, mflat)
    n_eff = np.asarray(n_eff).reshape(scorer.n, m)
    n_eff = np.where(np.isfinite(n_eff), n_eff, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        contrib = np.where(sse1 > 0, n_eff * (sse0 - sse1) / sse1, 0.0)
    lr = contrib.sum(axis=0)
    return np.maximum(lr, 0.0), n_eff.sum(axis=0)



def weighted_sse(X, Y, mask, weights):
    """Weighted residual sum of squares of the LS fit of Y on X over the used rows."""
    ri, rj = np.nonzero(mask)
    w = weights[rj]
    A = X[ri, rj, :] * w[:, None]
    y = Y[ri, rj] * w
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    r = y - A @ coef
    return float(r @ r), int(y.size - A.shape[1])


@with_single_blas_thread
def shift_scores(problem, state, delays, weights, folds, gap):
    """Scores of 'time_delay' candidates: the *base* model (all base parameters, plus the
    effects so far) re-fitted on W(t - d), against the same model on W(t).

    The full base model, not the essential set: the essential parameters were
    selected by backward elimination on the misaligned data and may lack
    parameters the aligned model needs (measured: the delay is then not found).
    Returns held-out errors and full-data residual rows of the alternatives
    and of that baseline.
    """
    def errs(X):
        sc = Scorer(X, problem.Y, problem.mask, weights, folds, gap)
        return np.array([F["err0"] for F in sc.folds]), sc.full["yperp"]

    e0, r0 = errs(problem.design(state["delay"], state["effects"], cols=problem.all_cols))
    m = len(delays)
    err = np.zeros((e0.size, m))
    res = np.zeros((r0.size, m))
    for i, d in enumerate(delays):
        err[:, i], res[:, i] = errs(problem.design(d, state["effects"], cols=problem.all_cols))
    return err, res, e0, r0



def chi2_logsf(x, k):
    """log P(chi2_k > x), finite where scipy's underflows to -inf (x in the thousands).

    Beyond that the leading term of the upper incomplete gamma function,
    log Q(k/2, x/2) ~ (k/2 - 1) log(x/2) - x/2 - lgamma(k/2), keeps huge statistics
    ordered (a spring's LR of 3e6 against a ripple's 3e3 on the same joint).
    """
    v = float(stats.chi2.logsf(x, k))
    if np.isfinite(v) or not x > 0:
        return v
    a = 0.5 * float(k)
    return (a - 1.0) * math.log(0.5 * x) - 0.5 * x - math.lgamma(a)



def chi2_logsf_many(x, k):
    """`chi2_logsf` of each (x_i, k_i), in one call to scipy (the per-candidate calls of a
    selection step cost more than its LR statistics); the same values, element by element."""
    x = np.asarray(x, dtype=float)
    k = np.asarray(k)
    if x.size == 0:
        return np.zeros(0)
    v = np.asarray(stats.chi2.logsf(x, k), dtype=float).reshape(x.shape)
    for i in np.flatnonzero(~np.isfinite(v) & (x > 0)):
        v[i] = chi2_logsf(x[i], k[i])
    return v


def _weighted_span(X, C, mask, weights):
    """(A, B, Q): the used rows of X and C (M, n, ·) weighted by their joint's w_j, and an
    orthonormal basis Q of the span of A (pivoted QR, rank cut at 1e-10, as `Scorer`)."""
    ri, rj = np.nonzero(mask)
    w = np.asarray(weights, dtype=float)[rj][:, None]
    A = X[ri, rj, :] * w
    Q, R, _ = sla.qr(A, mode="economic", pivoting=True, check_finite=False)
    d = np.abs(np.diag(R))
    return A, C[ri, rj, :] * w, Q[:, :int(np.count_nonzero(d > 1e-10 * d[0]))]


def new_columns(X, C, mask, weights):
    """Indices of the columns of C (M, n, k) that add to the span of X (weighted used rows)."""
    _, B, Q = _weighted_span(X, C, mask, weights)
    return independent_columns(B - Q @ (Q.T @ B), np.linalg.norm(B, axis=0))


def separability(X, C, mask, weights):
    """How much of a candidate's torque lies outside what the model's parameters already give.

    Over every combination of the columns of C (M, n, k), the smallest norm of its part outside
    the span of X (M, n, p), over its norm (weighted used rows, as `new_columns`): the sine of
    the largest principal angle between the candidate's columns and the model's. 1 for a
    candidate orthogonal to the model, 0 for an alias. Below a few per cent, the effect's size
    and the parameters it nearly equals are told apart only by noise (their σ grow as
    1 / fraction), and both take absurd values that cancel. A combination matters: a position
    ripple of order 1 on a joint that moves little has cos q and sin q each well outside the
    model, and the one combination cos(q - q_mean) nearly equal to the joint's offset.

    Returns
    -------
    (float, list of (int, float))
        The fraction, and the model's columns that combination nearly equals: (column index,
        share of the combination's part inside the span), largest first, those above 10 %.
    """
    A, B, Q = _weighted_span(X, C, mask, weights)
    norms = np.linalg.norm(B, axis=0)
    if not np.any(norms > 0):
        return 0.0, []
    # an orthonormal basis of the candidate's columns (its own dependent columns dropped)
    U, s, _ = np.linalg.svd(B[:, norms > 0] / norms[norms > 0], full_matrices=False)
    U = U[:, s > 1e-8 * s[0]]
    _, sv, Vt = np.linalg.svd(U - Q @ (Q.T @ U), full_matrices=False)
    u = U @ Vt[-1]                                  # the combination most inside the span
    coef = np.linalg.lstsq(A, Q @ (Q.T @ u), rcond=None)[0]
    size = np.abs(coef) * np.linalg.norm(A, axis=0)
    share = size / size.sum() if size.sum() > 0 else size
    terms = [(int(i), float(share[i])) for i in np.argsort(-share) if share[i] >= 0.1]
    return float(sv[-1]), terms[:3]


def independent_columns(Bperp, norms):
    """Columns of Bperp (projected candidate columns) that are independent, relative to `norms`."""
    nz = norms > 0
    if not nz.any():
        return []
    Z = Bperp[:, nz] / norms[nz]
    _, Rz, pz = sla.qr(Z, mode="economic", pivoting=True, check_finite=False)
    dz = np.abs(np.diag(Rz))
    good = pz[dz > ALIAS_RTOL]
    return sorted(np.flatnonzero(nz)[good].tolist())
