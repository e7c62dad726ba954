"""PC-WLS with effect columns (analysis/diagnosis/physical_fit.py) on the real KUKA LWR4+."""
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cvxpy")

import dynid
from dynid.analysis.diagnosis.physical_fit import (
    effect_candidates,
    effect_design,
    held_out_errors,
    identify_physical_effects,
)
from dynid.errors import InputError

HERE = Path(__file__).resolve().parents[1] / "examples" / "kuka_lwr4"


@pytest.fixture(scope="module")
def lwr():
    robot = dynid.load_robot("kuka_lwr4")
    rec = {i: dynid.load_experiment(HERE / f"recording_{i}.toml", robot) for i in (1, 2)}
    res = dynid.identify(rec[1], robot)
    return robot, rec, res


def test_candidates_parse_and_refuse():
    c = effect_candidates("spring:all,position_ripple:7:1", 7)
    assert [x.name for x in c] == ["spring"] * 7 + ["position_ripple"]
    assert list(c[-1].active_params) == ["Rc7k1", "Rs7k1"]
    for bad in ("spring:9", "position_ripple:7", "time_delay:all", "spring"):
        with pytest.raises(InputError):
            effect_candidates(bad, 7)


def test_effect_parameters_are_the_least_squares_fit_given_the_physical_base(lwr):
    """Eq. (2): theta_pc minimises the weighted residual for the PC base parameters, i.e. the
    weighted normal equations in theta hold at (beta_pc, theta_pc)."""
    robot, rec, res = lwr
    fit = identify_physical_effects(rec[1], robot, res, effect_candidates("spring:all", 7), n_boot=0)
    W, tau, mask, names = effect_design(rec[1], robot, res.base, fit.settings, fit.candidates)
    assert names == fit.names and len(names) == res.base.n_base + 7
    w = np.where(mask, 1.0 / np.asarray(fit.wls.joint_sigma)[None, :], 0.0)
    r = (tau - W @ fit.x_pc) * w
    C = W[:, :, fit.n_base:] * w[:, :, None]
    grad = np.einsum("mjk,mj->k", C, r)
    scale = np.sqrt(np.einsum("mjk,mjk->k", C, C) * np.sum(r ** 2))
    assert np.all(np.abs(grad) <= 1e-6 * scale)
    # and the unconstrained fit is not moved by the profile: beta_pc differs, theta follows
    assert not np.allclose(fit.physical.chi, fit.x_wls[:fit.n_base])


def test_springs_close_the_lwr4_gap_on_flobaroids_split(lwr):
    """Identified on recording 1, validated on 2 (all samples): with a spring on every joint the
    PC fit is consistent and within 0.2 points of the unconstrained fit of the same model
    (measured +0.030; without the springs +0.358, benchmarks/physical.py --effects)."""
    robot, rec, res = lwr
    fit = identify_physical_effects(rec[1], robot, res, effect_candidates("spring:all", 7), n_boot=0)
    e = held_out_errors(fit, rec[2], robot, res.base)
    assert fit.physical.consistent
    assert e["pc"] - e["wls"] < 0.002
    none = identify_physical_effects(rec[1], robot, res, [], n_boot=0)
    e0 = held_out_errors(none, rec[2], robot, res.base)
    assert e0["pc"] - e0["wls"] > 0.003          # the gap the springs remove
    assert e["pc"] < e0["pc"]
