"""The Bayesian sampler with a physically consistent support (dynid sample --physical)."""
import json

import numpy as np
import pytest

import dynid
from dynid.reports.cli import main

pytest.importorskip("cvxpy")


@pytest.fixture(scope="module")
def planar2_on_the_boundary():
    """planar2 simulated with Fv1 = 0 (a physical truth on the constraint Fv1 >= 0): about a
    third of the unconstrained posterior has Fv1 < 0 (a lone base parameter, its own column)."""
    robot = dynid.load_robot("planar2")
    robot.apriori["Fv1"] = 0.0
    rec = dynid.simulate(robot, 6.0, seed=2)
    return robot, dynid.identify(rec.experiment, robot)


def test_physical_support_rejects_non_physical_draws(planar2_on_the_boundary):
    from dynid.analysis.sampling.posterior import sample_idim
    robot, res = planar2_on_the_boundary
    kw = dict(which="base", seed=1, max_steps=25, n_walkers=32)
    plain = sample_idim(res, **kw)
    post = sample_idim(res, physical=True, **kw)
    i = post.names.index("Fv1")
    assert (plain.samples[:, i] < 0).mean() > 0.05       # the support matters here
    assert post.samples[:, i].min() >= 0
    for k in ("Fc1", "Fv2", "Fc2", "Ia2"):
        assert post.samples[:, post.names.index(k)].min() >= 0
    doc = post.to_dict()
    assert "physically consistent" in doc["settings"]["support"]
    assert "physically consistent" in doc["model"]
    assert plain.to_dict()["settings"]["support"] == "all of R^b"


def test_physical_support_is_the_feasibility_of_a_standard_set(planar2_on_the_boundary):
    """Points built from a consistent standard set are inside; a negative mass-like first moment
    budget (ZZ1R far below what any rigid body gives) is outside."""
    from dynid.analysis.estimators.physical import PhysicalSupport
    from dynid.analysis.estimators.standard_set import apriori_standard
    robot, res = planar2_on_the_boundary
    sup = PhysicalSupport(robot, res.base)
    beta = res.base.matrix @ apriori_standard(robot)
    bad = beta.copy()
    bad[res.base.names.index("ZZ1R")] = -1.0            # a negative inertia about joint 1's axis
    assert sup(np.vstack([beta, bad])).tolist() == [True, False]


def test_sample_physical_needs_the_base_parameters(tmp_path, capsys):
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "4", "--out", str(csv), "--quiet"]) == 0
    assert main(["sample", str(csv), "--robot", "planar2", "--physical", "--quiet"]) == 2
    assert "--which base" in capsys.readouterr().err
    js = tmp_path / "s.json"
    main(["sample", str(csv), "--robot", "planar2", "--physical", "--which", "base", "--max-steps", "10",
          "--walkers", "32", "--allow-unconverged", "--json", str(js), "--quiet"])
    assert "physically consistent" in json.loads(js.read_text())["settings"]["support"]
