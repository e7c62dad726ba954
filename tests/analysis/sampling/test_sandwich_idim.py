"""The sandwich posterior of an IDIM result: its robust covariance is the identification's own.

`dynid identify` reports the circular block bootstrap by default; the posterior's default
noise model matches its curvature to that covariance. An IDIM result identified with the
classic covariance (the library's internal default) must give the same matrix, computed
the same way (full WLS bootstrap, and for the essential parameters plus d d', the bias of
removing the others), so that the posterior does not depend on how the result was made.
"""
import numpy as np
import pytest

import dynid
from dynid.analysis.estimators.idim import identify_idim
from dynid.analysis.sampling.noise import sandwich_model, temper
from dynid.analysis.sampling.posterior import known_noise_posterior, sufficient_statistics
from dynid.analysis.sampling.sample import idim_robust_cov


@pytest.fixture(scope="module")
def planar2_both():
    robot = dynid.load_robot("planar2")
    rec = dynid.simulate(robot, 6.0, seed=3)
    return (identify_idim(rec.experiment, robot, uncertainty="bootstrap"),
            identify_idim(rec.experiment, robot, uncertainty="classic"))


@pytest.mark.slow
@pytest.mark.parametrize("which", ["base", "essential"])
def test_robust_covariance_is_the_identifications_whatever_its_option(planar2_both, which):
    boot, classic = planar2_both
    R_boot, src_boot = idim_robust_cov(boot, which)
    R_classic, src_classic = idim_robust_cov(classic, which)
    ls = boot.essential.result if which == "essential" else boot.wls
    assert R_boot is not None and np.array_equal(R_boot, ls.cov) and "bootstrap" in src_boot
    np.testing.assert_allclose(R_classic, R_boot, rtol=1e-9, atol=1e-15 * np.abs(R_boot).max())
    assert "bootstrap" in src_classic
    # and the closed form of the sandwich posterior at the LS sigma_j is N(chi_LS, that covariance)
    obs = classic.observation
    lsc = classic.essential.result if which == "essential" else classic.wls
    st = sufficient_statistics(obs.W[:, :, classic.columns(lsc.names)], obs.tau, lsc.names,
                               row_mask=obs.row_mask, ref=lsc.chi)
    mean, cov = known_noise_posterior(temper(st, sandwich_model(st, R_classic, lsc.joint_sigma)),
                                      lsc.joint_sigma)
    np.testing.assert_allclose(cov, R_classic, rtol=1e-7, atol=1e-12 * np.abs(R_classic).max())
    np.testing.assert_allclose(mean, lsc.chi, rtol=1e-9, atol=1e-12)
