"""Base parameters against closed forms, the DIDIM paper's TX40 set and FIGAROH's TX40 relations."""
import csv
import re

import numpy as np
import pytest
from conftest import TX40_EXAMPLE

from dynid.dynamics.base_parameters import base_parameters, base_regressor
from dynid.dynamics.regressor import regressor
from dynid.dynamics.robot_file import load_robot
from tests.support.oracles import random_standard_parameters, rel_err

FIGAROH_BP = TX40_EXAMPLE / "reference_results" / "TX40_bp_5.csv"


def fresh_samples(n, N, seed):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-np.pi, np.pi, (N, n)), rng.normal(0, 2.0, (N, n)),
            rng.normal(0, 5.0, (N, n)))


def relation_dict(bp, k):
    """{standard name: coefficient} of base parameter k (beta_k = sum coef * chi)."""
    row = bp.matrix[k]
    return {bp.standard_names[i]: row[i] for i in np.flatnonzero(row)}


@pytest.fixture(scope="module")
def tx40():
    return load_robot("tx40")


@pytest.fixture(scope="module")
def tx40_bp(tx40):
    return base_parameters(tx40)


# ------------------------------------------------------------- planar 2R

def test_planar2_base_parameters_are_the_closed_form_set():
    robot = load_robot("planar2")
    bp = base_parameters(robot)
    # Khalil & Dombre 2002 §12.5 with d2 = 1 m
    expected = {
        "ZZ1R": {"ZZ1": 1.0, "Ia1": 1.0, "M2": 1.0},
        "MX1R": {"MX1": 1.0, "M2": 1.0},
        "MY1": {"MY1": 1.0},
        "ZZ2": {"ZZ2": 1.0}, "MX2": {"MX2": 1.0}, "MY2": {"MY2": 1.0}, "Ia2": {"Ia2": 1.0},
        "Fv1": {"Fv1": 1.0}, "Fc1": {"Fc1": 1.0}, "Off1": {"Off1": 1.0},
        "Fv2": {"Fv2": 1.0}, "Fc2": {"Fc2": 1.0}, "Off2": {"Off2": 1.0},
    }
    assert sorted(bp.names) == sorted(expected)
    assert bp.n_base == 13 and bp.n_standard == 28
    for k, name in enumerate(bp.names):
        got = relation_dict(bp, k)
        assert got.keys() == expected[name].keys(), name
        for p, c in expected[name].items():
            assert got[p] == pytest.approx(c, abs=1e-12), (name, p)
    assert "ZZ1R = ZZ1 + Ia1 + M2" in bp.relations
    # parameters with no effect on a planar arm
    assert {"XX1", "XY1", "XZ1", "YY1", "YZ1", "MZ1", "M1", "XX2", "MZ2", "M2", "Ia1"} <= \
        set(robot.standard_names) - {bp.standard_names[i] for i in bp.independent}
    assert set(bp.unidentifiable) >= {"XX1", "YY2", "MZ2", "M1"}


# -------------------------------------------------------------------- TX40

def test_tx40_counts_and_names(tx40, tx40_bp):
    assert tx40.n_standard == 86
    assert tx40_bp.n_standard == 86
    assert tx40_bp.n_base == 60
    for name in ("ZZ1R", "XX2R", "XZ2R", "ZZ2R", "MX2R", "ZZ3R", "MY3R", "Ia3", "Ia4", "Ia5",
                 "Fvm6", "Fcm6"):
        assert name in tx40_bp.names
    # the relations of the DIDIM paper's Table 2 parameters
    rel = dict(zip(tx40_bp.names, tx40_bp.relations))
    assert rel["ZZ1R"].startswith("ZZ1R = ZZ1 + Ia1 + YY2 + YY3")
    assert rel["MX2R"] == "MX2R = MX2 + 0.225*M3 + 0.225*M4 + 0.225*M5 + 0.225*M6"
    # every a-priori value of the bundled TX40 names a base parameter
    assert set(tx40.apriori) <= set(tx40_bp.names)


def test_tx40_base_regressor_reproduces_standard_torques(tx40, tx40_bp):
    """W_base beta == W_st chi_st on samples the QR never saw, for random chi_st."""
    q, qd, qdd = fresh_samples(6, 500, seed=777)
    W_st = regressor(tx40, q, qd, qdd)
    W_b = base_regressor(tx40, tx40_bp, q, qd, qdd)
    rng = np.random.default_rng(778)
    for _ in range(5):
        chi = random_standard_parameters(tx40, rng)
        chi_wild = rng.normal(size=86) * 10.0             # not physical: any chi must work
        for c in (chi, chi_wild):
            beta = tx40_bp.from_standard(c)
            assert rel_err(W_b @ beta, W_st @ c) <= 1e-9


@pytest.mark.parametrize("method", ["zero", "least_norm"])
def test_tx40_to_standard_round_trips(tx40, tx40_bp, method):
    rng = np.random.default_rng(31)
    q, qd, qdd = fresh_samples(6, 200, seed=32)
    W_st = regressor(tx40, q, qd, qdd)
    for _ in range(5):
        beta = rng.normal(size=tx40_bp.n_base)
        chi = tx40_bp.to_standard(beta, method=method)
        assert chi.shape == (86,)
        np.testing.assert_allclose(tx40_bp.from_standard(chi), beta, rtol=1e-10, atol=1e-10)
        assert rel_err(W_st @ chi, base_regressor(tx40, tx40_bp, q, qd, qdd) @ beta) <= 1e-9
    with pytest.raises(ValueError):
        tx40_bp.to_standard(np.zeros(tx40_bp.n_base), method="nope")


def test_base_parameters_are_deterministic(tx40, tx40_bp):
    again = base_parameters(load_robot("tx40"))
    assert again.names == tx40_bp.names
    assert again.relations == tx40_bp.relations
    np.testing.assert_array_equal(again.K, tx40_bp.K)
    np.testing.assert_array_equal(again.independent, tx40_bp.independent)
    np.testing.assert_array_equal(again.dependent, tx40_bp.dependent)


def test_base_parameter_matrix_is_consistent(tx40_bp):
    P = tx40_bp.matrix
    assert P.shape == (60, 86)
    np.testing.assert_array_equal(P[:, tx40_bp.independent], np.eye(60))
    assert np.linalg.matrix_rank(P) == 60


# ------------------------------------------------- FIGAROH reference relations

_FIG_PREFIX = {"Ixx": "XX", "Ixy": "XY", "Ixz": "XZ", "Iyy": "YY", "Iyz": "YZ", "Izz": "ZZ",
               "mx": "MX", "my": "MY", "mz": "MZ", "m": "M", "Ia": "Ia", "fv": "Fv", "fs": "Fc",
               "off": "Off"}
_FIG_SKIP = {"Iam", "fvm", "fsm"}      # coupling parametrised differently (see module doc)
_TERM = re.compile(r"\s*([+-])?\s*(?:([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\*)?([A-Za-z]+)([0-9]+)\s*")


def parse_figaroh(expr):
    """'Ixx2 - 1.0*Iyy2 - 0.05*m3' -> {'XX2': 1, 'YY2': -1, 'M3': -0.05}, or None if skipped."""
    out, pos = {}, 0
    while pos < len(expr):
        m = _TERM.match(expr, pos)
        assert m and m.end() > pos, f"cannot parse FIGAROH expression {expr!r} at {pos}"
        sign, coef, prefix, joint = m.groups()
        if prefix in _FIG_SKIP:
            return None
        value = (-1.0 if sign == "-" else 1.0) * (float(coef) if coef else 1.0)
        out[_FIG_PREFIX[prefix] + joint] = value
        pos = m.end()
    return out


def test_parse_figaroh():
    assert parse_figaroh("Ixx2 - 1.0*Iyy2 - 0.050625*m3") == {"XX2": 1.0, "YY2": -1.0, "M3": -0.050625}
    assert parse_figaroh("fsm6") is None


@pytest.mark.skipif(not FIGAROH_BP.exists(), reason=f"{FIGAROH_BP} not available")
def test_tx40_relations_agree_with_figaroh(tx40_bp):
    with FIGAROH_BP.open(newline="") as fh:
        exprs = [row[0] for row in csv.reader(fh) if row]
    assert len(exprs) == 60
    by_lead = {tx40_bp.standard_names[i]: k for k, i in enumerate(tx40_bp.independent)}
    compared = set()
    for expr in exprs:
        fig = parse_figaroh(expr)
        if fig is None:
            continue
        lead = next(iter(fig))
        assert fig[lead] == 1.0
        assert lead in by_lead, f"FIGAROH base parameter {expr!r}: {lead} is not a dynid base column"
        k = by_lead[lead]
        ours = relation_dict(tx40_bp, k)
        assert ours.keys() == fig.keys(), f"{tx40_bp.relations[k]}  vs FIGAROH  {expr}"
        for name, c in fig.items():
            assert ours[name] == pytest.approx(c, abs=1e-9), f"{name} in {tx40_bp.relations[k]} vs {expr}"
        compared.add(tx40_bp.names[k])
    # every dynid base parameter was compared except the coupling-related ones
    assert set(tx40_bp.names) - compared == {"Ia6", "Fvm6", "Fcm6"}
