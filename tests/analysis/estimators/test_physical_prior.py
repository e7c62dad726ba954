"""PC-WLS with the geometric prior (Lee, Wensing & Park 2020): an independent solution by
scipy, the divergence's closed-form properties, bad input, the command line.

The reference objective, the pseudo-inertia and the divergence are written here in NumPy
(Wensing, Kim & Slotine 2017, eq. (7); Lee, Wensing & Park 2020, entropic divergence),
not taken from dynid; the optimiser is scipy's L-BFGS-B on a log-Cholesky
parameterisation of each link's pseudo-inertia (positive definite by construction).
"""
import json
import os
import tempfile

import numpy as np
import pytest
from scipy import optimize
from scipy.spatial.transform import Rotation

from dynid.errors import InputError

pytest.importorskip("cvxpy")

# planar2 with a-priori links that are bodies (thin 1 m bars along x, 4 cm thick): its
# bundled a-priori set (ZZ alone) has an indefinite pseudo-inertia and is refused
TOML = """
name = "planar2_bars"
description = "planar2 with physical a-priori bars (geometric-prior tests)"
gravity = [0.0, -9.81, 0.0]

[[joints]]
name = "shoulder"
sigma = 0
q_limits = [-3.1416, 3.1416]
qd_max = 6.0
qdd_max = 30.0
tau_max = 200.0

[[joints]]
name = "elbow"
sigma = 0
d = 1.0
q_limits = [-2.8, 2.8]
qd_max = 6.0
qdd_max = 30.0
tau_max = 100.0

[controller]
kind = "pd"
rate = 200.0
wn = [30.0, 30.0]
zeta = [1.0, 1.0]
J_ap = [4.0, 1.0]

[apriori]
source = "thin bars of 1 m and 2 kg along x"
values = { XX1 = 0.0005, YY1 = 0.6669, ZZ1 = 0.6669, MX1 = 1.0, M1 = 2.0, XX2 = 0.0005, YY2 = 0.6669, ZZ2 = 0.6669, MX2 = 1.0, M2 = 2.0, Ia1 = 0.05, Ia2 = 0.05, Fv1 = 0.5, Fv2 = 0.3, Fc1 = 1.0, Fc2 = 0.5 }
"""

INERTIAL = ("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M")


def _load(text):
    from dynid.dynamics.robot_file import load_robot
    fd, path = tempfile.mkstemp(suffix=".toml", prefix="dynid-geo-")
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    try:
        return load_robot(path)
    finally:
        os.unlink(path)


# ------------------------------------------------------------------ independent NumPy
def pseudo(v):
    """J = [[tr(I)/2 1 - I, h], [h^T, m]] of XX XY XZ YY YZ ZZ MX MY MZ M (I about the origin)."""
    XX, XY, XZ, YY, YZ, ZZ, MX, MY, MZ, M = v
    inertia = np.array([[XX, XY, XZ], [XY, YY, YZ], [XZ, YZ, ZZ]])
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J[:3, 3] = J[3, :3] = [MX, MY, MZ]
    J[3, 3] = M
    return J


def values(J):
    """The inverse of :func:`pseudo`: Sigma = J[:3, :3], I = tr(Sigma) 1 - Sigma."""
    S = J[:3, :3]
    inertia = np.trace(S) * np.eye(3) - S
    return np.array([inertia[0, 0], inertia[0, 1], inertia[0, 2], inertia[1, 1], inertia[1, 2],
                     inertia[2, 2], J[0, 3], J[1, 3], J[2, 3], J[3, 3]])


# the linear map J (16 entries, read as given) -> ten values, for the gradient
_VALUES = np.array([values(np.eye(16)[k].reshape(4, 4)) for k in range(16)]).T


def divergence(J, J0):
    """-log det(J0^-1 J) + tr(J0^-1 J) - 4 (inf outside the PD cone)."""
    sign, logdet = np.linalg.slogdet(np.linalg.solve(J0, J))
    if sign <= 0:
        return np.inf
    return float(-logdet + np.trace(np.linalg.solve(J0, J)) - 4.0)


def test_divergence_by_hand():
    """J0 = diag(1, 2, 3, 4), J = diag(2, 2, 3, 8): J0^-1 J = diag(2, 1, 1, 2), so
    d = -log 4 + 6 - 4 = 2 - 2 log 2; zero at J0, positive elsewhere."""
    J0 = np.diag([1.0, 2.0, 3.0, 4.0])
    J = np.diag([2.0, 2.0, 3.0, 8.0])
    assert divergence(J, J0) == pytest.approx(2 - 2 * np.log(2), rel=1e-14)
    assert divergence(J0, J0) == pytest.approx(0.0, abs=1e-14)
    # not diagonal: J0 = 1, J with the block [[2, 1], [1, 2]] (eigenvalues 3, 1): det 3, trace 6
    J = np.eye(4)
    J[:2, :2] = [[2.0, 1.0], [1.0, 2.0]]
    assert divergence(J, np.eye(4)) == pytest.approx(2 - np.log(3), rel=1e-14)
    rng = np.random.default_rng(0)
    for _ in range(20):
        A = rng.normal(size=(4, 4))
        Jr = A @ A.T + 0.1 * np.eye(4)
        assert divergence(Jr, J0) > 0


# ------------------------------------------------------------------ the small robot's fit
@pytest.fixture(scope="module")
def bars():
    from dynid.analysis.data.synthetic import simulate_experiment
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.estimators.standard_set import apriori_standard
    from dynid.dynamics.trajectories import random_fourier_trajectory
    robot = _load(TOML)
    ap = apriori_standard(robot)
    truth = ap.copy()
    names = robot.standard_names
    # the true arm is not the a-priori one: heavier, the second bar's mass off its axis
    for n, f in (("M1", 1.3), ("MX1", 1.3), ("YY1", 1.3), ("ZZ1", 1.3), ("Fv1", 0.6), ("Ia2", 1.5)):
        truth[names.index(n)] *= f
    truth[names.index("MY2")] = 0.15
    rng = np.random.default_rng(4)
    traj = random_fourier_trajectory(robot, 0.2, 6, rng)
    exp = simulate_experiment(robot, truth, traj, 3.0, rng=rng, q_noise=1e-6, tau_noise=0.2)
    return robot, identify_idim(exp, robot), ap


def _objective_parts(robot, res, ap, w):
    """The geometric-prior PC-WLS objective written here: chi2 in the WLS metric (solved with
    cov, not whitened), w * (divergences + Euclidean term of the non-inertial parameters)."""
    from dynid.analysis.estimators.standard_set import scales
    names = list(robot.standard_names)
    P = res.base.matrix
    b, cov = res.wls.chi, res.wls.cov
    icov = np.linalg.inv(cov)
    s = scales(robot, ap)
    links = [[names.index(f"{k}{j + 1}") for k in INERTIAL] for j in range(robot.n_joints)]
    inertial = sorted(i for lk in links for i in lk)
    rest = [i for i in range(len(names)) if i not in inertial]
    J0 = [pseudo(ap[lk]) for lk in links]
    nonneg = [k for k, i in enumerate(rest) if names[i].rstrip("0123456789") in ("Ia", "Fv", "Fc")]
    return dict(P=P, b=b, icov=icov, s=s, links=links, rest=rest, J0=J0, nonneg=nonneg, w=w, ap=ap)


def f_chi(chi, o):
    r = o["P"] @ chi - o["b"]
    d = sum(divergence(pseudo(chi[lk]), J0) for lk, J0 in zip(o["links"], o["J0"]))
    e = (chi[o["rest"]] - o["ap"][o["rest"]]) / o["s"][o["rest"]]
    return float(r @ o["icov"] @ r + o["w"] * (d + e @ e))


_TRIU = np.triu_indices(4)


def _unpack(x, o):
    """x = (10 log-Cholesky coordinates per link, then z = chi / s of the other parameters)."""
    n_l = len(o["links"])
    chi = np.zeros(len(o["s"]))
    Us = []
    for j, lk in enumerate(o["links"]):
        th = x[10 * j:10 * j + 10]
        U = np.zeros((4, 4))
        U[_TRIU] = th
        U[np.diag_indices(4)] = np.exp(np.diag(U))
        Us.append(U)
        chi[lk] = values(U @ U.T)
    chi[o["rest"]] = x[10 * n_l:] * o["s"][o["rest"]]
    return chi, Us


def f_and_grad(x, o):
    chi, Us = _unpack(x, o)
    r = o["P"] @ chi - o["b"]
    e = (chi[o["rest"]] - o["ap"][o["rest"]]) / o["s"][o["rest"]]
    f = r @ o["icov"] @ r + o["w"] * (e @ e)
    g_chi = 2 * o["P"].T @ o["icov"] @ r
    grad = np.zeros_like(x)
    for j, (lk, U, J0) in enumerate(zip(o["links"], Us, o["J0"])):
        J = U @ U.T
        f += o["w"] * divergence(J, J0)
        # df/dJ entry by entry (J read through _VALUES and through the divergence), then
        # J = U U^T: df/dU = (G + G^T) U, and the log of the diagonal
        G = (_VALUES.T @ g_chi[lk]).reshape(4, 4) + o["w"] * (np.linalg.inv(J0) - np.linalg.inv(J)).T
        gU = (G + G.T) @ U
        gth = gU[_TRIU]
        diag = [k for k, (a, c) in enumerate(zip(*_TRIU)) if a == c]
        gth[diag] *= U[_TRIU][diag]
        grad[10 * j:10 * j + 10] = gth
    n = 10 * len(o["links"])
    grad[n:] = g_chi[o["rest"]] * o["s"][o["rest"]] + 2 * o["w"] * e
    return float(f), grad


def _pack(chi, o):
    th = []
    for lk in o["links"]:
        L = np.linalg.cholesky(pseudo(chi[lk])[::-1, ::-1])
        U = L[::-1, ::-1]                     # upper triangular, J = U U^T
        t = U[_TRIU].copy()
        t[[0, 4, 7, 9]] = np.log(np.diag(U))
        th.append(t)
    return np.concatenate(th + [chi[o["rest"]] / o["s"][o["rest"]]])


def _scipy_min(x0, o):
    n = 10 * len(o["links"])
    bounds = [(None, None)] * len(x0)
    for k in o["nonneg"]:
        bounds[n + k] = (0.0, None)
    r = optimize.minimize(f_and_grad, x0, args=(o,), jac=True, method="L-BFGS-B", bounds=bounds,
                          options={"maxiter": 100000, "maxfun": 200000, "ftol": 1e-15, "gtol": 1e-9,
                                   "maxcor": 50})
    return _unpack(r.x, o)[0]


def test_gradient_of_the_reference_objective(bars):
    """The hand gradient of the reference (used by L-BFGS-B) against central differences."""
    robot, res, ap = bars
    o = _objective_parts(robot, res, ap, 1.0)
    x = _pack(ap, o) + np.random.default_rng(1).normal(scale=0.05, size=10 * 2 + len(o["rest"]))
    _, g = f_and_grad(x, o)
    h = 1e-6
    num = np.array([(f_and_grad(x + h * e, o)[0] - f_and_grad(x - h * e, o)[0]) / (2 * h)
                    for e in np.eye(len(x))])
    assert np.allclose(g, num, rtol=1e-5, atol=1e-4 * np.abs(g).max())


def test_geometric_solution_matches_an_independent_scipy_minimisation(bars):
    from dynid.analysis.estimators.physical import identify_physical
    robot, res, ap = bars
    w = 30.0
    pc = identify_physical(res, robot, prior="geometric", prior_weight=w, n_boot=0)
    assert pc.prior == "geometric" and pc.prior_weight == w and pc.consistent
    o = _objective_parts(robot, res, ap, w)
    f_cvx = f_chi(pc.standard, o)
    # the prior pulls: the solution is neither the a-priori set nor free of the prior's cost
    assert f_cvx < f_chi(ap, o)
    rng = np.random.default_rng(2)
    starts = [_pack(pc.standard, o) + rng.normal(scale=0.1, size=10 * 2 + len(o["rest"])), _pack(ap, o)]
    s = o["s"]
    for x0 in starts:
        chi = _scipy_min(x0, o)
        f_sci = f_chi(chi, o)
        assert f_sci >= f_cvx * (1 - 1e-6)          # cvxpy's is (to rounding) the minimum
        assert f_sci == pytest.approx(f_cvx, rel=1e-6)
        assert np.max(np.abs(chi - pc.standard) / s) < 1e-3


def test_huge_weight_gives_the_apriori_values(bars):
    """The data's chi2 at the a-priori set is ~1e6 here: the standard set reaches the a-priori
    values as the weight grows past that, the fit degrading monotonically on the way."""
    from dynid.analysis.estimators.physical import identify_physical
    from dynid.analysis.estimators.standard_set import scales
    robot, res, ap = bars
    s = scales(robot, ap)
    fits = [identify_physical(res, robot, prior="geometric", prior_weight=w, n_boot=0)
            for w in (1e-2, 1e4, 1e8, 1e12)]
    dist = [np.max(np.abs(f.standard - ap) / s) for f in fits]
    chi2 = [f.chi2 for f in fits]
    assert dist[-1] < 1e-3 and all(a > b for a, b in zip(dist, dist[1:]))
    assert all(a < b for a, b in zip(chi2, chi2[1:]))


def _random_transform(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.normal(scale=0.5, size=3)
    return T


def test_divergence_is_frame_invariant_the_euclidean_term_is_not():
    """A rigid change of the link frame, x' = R x + p, maps J = int [x;1][x;1]^T dm to T J T^T;
    d(T J T^T || T J0 T^T) = d(J || J0) (similar matrices), the scaled Euclidean distance changes."""
    rng = np.random.default_rng(3)
    J0 = pseudo([0.0005, 0, 0, 0.6669, 0, 0.6669, 1.0, 0, 0, 2.0])
    J = pseudo([0.002, 0.01, 0, 0.8, 0.02, 0.75, 1.2, 0.1, 0.05, 2.4])
    d = divergence(J, J0)
    s = np.maximum(np.abs(values(J0)), 1e-3)
    euclid = np.sum(((values(J) - values(J0)) / s) ** 2)
    changed = []
    for _ in range(5):
        T = _random_transform(rng)
        Jt, J0t = T @ J @ T.T, T @ J0 @ T.T
        assert divergence(Jt, J0t) == pytest.approx(d, rel=1e-9)
        st = np.maximum(np.abs(values(J0t)), 1e-3)
        changed.append(abs(np.sum(((values(Jt) - values(J0t)) / st) ** 2) / euclid - 1))
    assert min(changed) > 0.01


def test_dynid_pulls_toward_the_same_divergence_in_any_frame():
    """The objective dynid builds gives, at a given J, the divergence computed here (the SDP's
    prior term by cvxpy at a fixed point), in the original and in a moved link frame."""
    from dynid.analysis.estimators.sdp import build_sdp
    from dynid.analysis.estimators.standard_set import apriori_standard, scales
    from dynid.dynamics.base_parameters import base_parameters
    robot = _load(TOML)
    bp = base_parameters(robot)
    ap = apriori_standard(robot)
    rng = np.random.default_rng(5)
    chi = ap.copy()
    names = robot.standard_names
    for j in range(2):
        chi[[names.index(f"{k}{j + 1}") for k in INERTIAL]] = values(
            pseudo(ap[[names.index(f"{k}{j + 1}") for k in INERTIAL]]) + 0.01 * np.diag([1, 2, 3, 4]))
    for T in (np.eye(4), _random_transform(rng)):
        ap_t, chi_t = ap.copy(), chi.copy()
        expect = 0.0
        for j in range(2):
            lk = [names.index(f"{k}{j + 1}") for k in INERTIAL]
            J0t, Jt = T @ pseudo(ap[lk]) @ T.T, T @ pseudo(chi[lk]) @ T.T
            ap_t[lk], chi_t[lk] = values(J0t), values(Jt)
            expect += divergence(Jt, J0t)
        st = scales(robot, ap_t)
        pb = build_sdp(robot, bp, np.zeros((1, bp.n_base)), ap_t, st, 1.0, None, prior="geometric")
        pb.target.value = np.zeros(1)
        pb.z.value = chi_t / st
        got = pb.prob.objective.value
        assert got == pytest.approx(expect, rel=1e-8, abs=1e-12)


# ------------------------------------------------------------------ bad input
def test_a_zero_mass_link_is_refused_naming_it():
    from dynid.analysis.estimators.physical import pc_wls
    from dynid.dynamics.base_parameters import base_parameters
    text = TOML.replace("XX2 = 0.0005, YY2 = 0.6669, ZZ2 = 0.6669, MX2 = 1.0, M2 = 2.0, ", "")
    robot = _load(text)
    bp = base_parameters(robot)
    beta = np.ones(bp.n_base)
    with pytest.raises(InputError, match=r"link 2 .*no a-priori inertial values.*prior='apriori'") as e:
        pc_wls(robot, bp, beta, np.eye(bp.n_base), prior="geometric", n_boot=0)
    assert "link 1" not in str(e.value)
    # the Euclidean prior needs no pseudo-inertia
    assert pc_wls(robot, bp, beta, np.eye(bp.n_base), prior="apriori", n_boot=0).prior == "apriori"


def test_bundled_robots_without_physical_apriori_links_are_refused():
    import dynid
    from dynid.analysis.estimators.physical import apriori_pseudo_inertias
    from dynid.analysis.estimators.standard_set import apriori_standard
    for name, bad in (("tx40", "link 1"), ("planar2", "link 1")):
        robot = dynid.load_robot(name)
        with pytest.raises(InputError, match=bad):
            apriori_pseudo_inertias(robot, apriori_standard(robot))
    kuka = dynid.load_robot("kuka_lwr4")
    assert len(apriori_pseudo_inertias(kuka, apriori_standard(kuka))) == 7


def test_unknown_prior_lists_the_choices():
    from dynid.analysis.estimators.physical import pc_wls
    from dynid.dynamics.base_parameters import base_parameters
    robot = _load(TOML)
    bp = base_parameters(robot)
    with pytest.raises(InputError, match=r"None, 'apriori' .*'geometric'.*'entropic'"):
        pc_wls(robot, bp, np.ones(bp.n_base), np.eye(bp.n_base), prior="entropic")
    with pytest.raises(InputError, match="prior_weight"):
        pc_wls(robot, bp, np.ones(bp.n_base), np.eye(bp.n_base), prior="geometric", prior_weight=-1)


# ------------------------------------------------------------------ command line
def test_cli_geometric_prior_in_the_json(tmp_path, capsys):
    from dynid.reports.cli import main
    toml = tmp_path / "bars.toml"
    toml.write_text(TOML)
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--robot", str(toml), "--duration", "3", "--out", str(csv), "--quiet"]) == 0
    js = tmp_path / "p.json"
    assert main(["identify", str(csv), "--robot", str(toml), "--physical", "--prior", "geometric",
                 "--prior-weight", "0.1", "--bootstrap", "0", "--json", str(js), "--quiet"]) == 0
    ph = json.loads(js.read_text())["physical"]
    assert ph["prior"] == "geometric" and ph["prior_weight"] == 0.1 and ph["consistent"] is True
    # the effects' PC fit (physical_fit.profile_physical) passes the prior on to the same SDP
    js2 = tmp_path / "e.json"
    assert main(["identify", str(csv), "--robot", str(toml), "--physical", "--prior", "geometric",
                 "--prior-weight", "0.1", "--effects", "spring:all", "--bootstrap", "0", "--json", str(js2),
                 "--quiet"]) == 0
    ph = json.loads(js2.read_text())["physical"]
    assert ph["prior"] == "geometric" and ph["prior_weight"] == 0.1 and "effects" in ph
    # a robot file whose a-priori links are no bodies: exit 2, the link named, the way out given
    assert main(["identify", str(csv), "--robot", "planar2", "--physical", "--prior", "geometric",
                 "--bootstrap", "0", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "link 1" in err and "--prior apriori" in err
