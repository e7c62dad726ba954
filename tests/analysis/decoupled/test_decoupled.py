"""Per-joint identification of Bona & Curatella (2005), section 3, on a simulated decoupled COMAU.

The simulated robot's true values are the paper's Tables 1-3
(:mod:`dynid.dynamics.comau_decoupled`); 25 repetitions with torque and encoder
noise, closed loop under a sampled PID. dynid's report must reproduce the
three tables in the paper's layout with every true value inside its 99.9 %
Student interval, and the intervals must be narrow enough to mean something.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats
from scipy.linalg import expm

from dynid.analysis.decoupled.campaign import identify_campaign, simulate_campaign
from dynid.analysis.decoupled.estimates import estimate_friction, estimate_gravity, estimate_inertia
from dynid.analysis.decoupled.repeated import RepeatedEstimate
from dynid.dynamics.joint_model import JointModel, JointPID, simulate_joints
from dynid.dynamics.joint_trajectories import trapezoid_reference
from dynid.errors import InputError
from dynid.reports.decoupled_section import decoupled_sections, table1_frame, table2_frame, table3_frame
from dynid.reports.html import render_sections

N_REP = 25


@pytest.fixture(scope="module")
def campaign():
    return simulate_campaign(N_REP, seed=2024)


@pytest.fixture(scope="module")
def ident(campaign):
    return identify_campaign(campaign)


def test_tables_1_2_3_contain_the_true_values(ident):
    print()
    print(ident.summary())
    for res, n_params in ((ident.gravity, 4), (ident.friction, 24), (ident.inertia, 16)):
        assert res.n_repetitions == N_REP
        assert len(res.names) == n_params
        outside = [n for n, ok in zip(res.names, res.inside) if not ok]
        assert not outside, f"{res.table}: true value outside the 99.9 % interval for {outside}"
    assert ident.n_inside == ident.n_parameters == 44


def test_intervals_are_informative(ident):
    """A wide interval would contain anything; these must pin the parameters down."""
    rel = {r.kind: r.half_width / np.abs(r.truth) for r in ident.tables}
    zz = max(h for n, h in zip(ident.inertia.names, rel["inertia"]) if n.startswith("ZZ"))
    print(f"\nlargest relative half-width: gravity {rel['gravity'].max():.3g}, "
          f"friction {rel['friction'].max():.3g}, inertia ZZ {zz:.3g}")
    assert rel["friction"].max() < 0.01
    zz = [h for n, h in zip(ident.inertia.names, rel["inertia"]) if n.startswith("ZZ")]
    assert max(zz) < 0.01
    # the first moments of the shoulder are large and well identified (paper: "due to gravity")
    assert all(rel["inertia"][ident.inertia.names.index(n)] < 0.01 for n in ("MX2", "MY2", "MX3", "MY3"))
    # k3 sits in 3 N m of torque noise and 13-65 N m of friction; still within 5 %
    assert rel["gravity"][ident.gravity.names.index("k3")] < 0.05


def test_report_reproduces_the_paper_layout(ident, tmp_path):
    t1, spans1 = table1_frame(ident.gravity)
    assert list(t1.index) == ["k [N m]", "q^off [deg]"]
    assert [g for g, _ in spans1] == ["Axis 2", "Axis 3"]
    assert math.isclose(t1.loc["q^off [deg]", "Axis 2: true"], 7.5)
    t2, spans2 = table2_frame(ident.friction)
    assert list(t2.index) == [f"Axis {j}" for j in range(1, 7)]
    assert [g for g, _ in spans2] == ["β^v+", "β^v−", "β^c+", "β^c−"]
    assert t2.loc["Axis 2", "β^v−: true"] == 73.0530
    t3 = table3_frame(ident.inertia)
    assert list(t3.columns[:5]) == ["Axis", "Parameter", "θ̄", "σ", "t_γ σ/√(n−1)"]
    assert len(t3) == 16 and t3["inside"].all()
    sections = decoupled_sections(ident)
    html = render_sections(sections, title="COMAU decoupled")
    for key in ("tab-table1", "tab-table2", "tab-table3", "fig-validation-fig8-pdf"):
        assert f'id="{key}"' in html
    json.dumps(ident.to_dict())


def test_validation_by_simulation(ident):
    v = ident.validation
    print("\n" + v.summary())
    # section 3.5: position error below 0.1 deg; the torque error is the noise, a few % at most
    assert v.max_q_error_deg.max() < 0.1
    assert v.rel_tau_error.max() < 0.05
    # SI in the exports (rad, N m), the paper's degrees beside them
    doc, frame = v.to_dict(), v.to_frame()
    assert np.allclose(np.degrees(doc["max_q_error"]), doc["max_q_error_deg"])
    assert np.allclose(frame["rms_q_error [rad]"], v.rms_q_error) and "max_tau_error [N m]" in frame
    assert v.tau_tests.table.shape[0] == 6 and v.q_tests.table.shape[0] == 6


def test_half_width_is_the_student_interval_of_the_mean():
    x = np.random.default_rng(3).normal(2.0, 0.5, (25, 1))
    r = RepeatedEstimate("x", ["a"], x, [1])
    lo, hi = stats.t.interval(0.999, 24, loc=x.mean(), scale=stats.sem(x[:, 0]))
    assert math.isclose(r.std[0], x.std(ddof=0))
    assert math.isclose(r.lower[0], lo, rel_tol=1e-12) and math.isclose(r.upper[0], hi, rel_tol=1e-12)
    assert math.isclose(r.t_gamma, stats.t.ppf(0.9995, 24))
    # JSON and CSV: `std` is the sigma of the estimate (the mean), as for every result; the
    # paper's sigma of the repetitions is `spread`
    rec = r.to_dict()["parameters"][0]
    assert math.isclose(rec["std"], stats.sem(x[:, 0]), rel_tol=1e-12)
    assert math.isclose(rec["spread"], x.std(ddof=0), rel_tol=1e-12)
    assert math.isclose(rec["rel_std_percent"], 100 * stats.sem(x[:, 0]) / abs(x.mean()), rel_tol=1e-12)
    row = r.to_frame().loc["a"]
    assert math.isclose(row["value"], x.mean()) and math.isclose(row["std"], r["a"].std, rel_tol=1e-12)
    assert math.isclose(row["spread"], x.std(ddof=0), rel_tol=1e-12)


def test_simulator_matches_exact_zero_order_hold_of_the_linear_joint():
    """Independent check: J qdd + b qd = u with u held over each period is linear, so its exact
    discretisation is expm of the augmented matrix; the PID loop is replayed around it."""
    J, b, T = 2.0, 3.0, 1e-3
    pid = JointPID.triple_pole([J], 3.0)
    ref = trapezoid_reference([0.0], [1.0], move_time=2.0, accel_time=0.5, pause=0.3, fs=1 / T)
    E = expm(np.block([[np.array([[0, 1], [0, -b / J]]), np.array([[0], [1 / J]])],
                       [np.zeros((1, 3))]]) * T)
    Ad, Bd = E[:2, :2], E[:2, 2]
    x, integ, q_prev, exact = np.zeros(2), 0.0, 0.0, []
    for k in range(ref.t.size):
        exact.append(x[0])
        e = ref.q[k, 0] - x[0]
        integ += T * e
        u = pid.kp[0] * e + pid.ki[0] * integ - pid.kd[0] * (x[0] - q_prev) / T
        q_prev = x[0]
        x = Ad @ x + Bd * u
    exact = np.array(exact)
    model = JointModel([J], [b], [b], [0.0], [0.0])
    err = [np.abs(simulate_joints(model, ref.t, ref.q, pid, substeps=s).q[0, :, 0] - exact).max()
           for s in (1, 2, 4)]
    print(f"\nmax |q - q_exact| with 1, 2, 4 substeps: {err[0]:.2e}, {err[1]:.2e}, {err[2]:.2e} rad")
    assert err[1] < 1e-9
    assert 3.0 < err[0] / err[1] < 5.0 and 3.0 < err[1] / err[2] < 5.0      # second order


def test_coulomb_friction_sticks_exactly():
    """Below the break-away torque the joint must not creep (the implicit friction step)."""
    m = JointModel([0.5], [1.0], [1.0], [2.0], [2.0])
    pid = JointPID(kp=np.array([0.0]), kd=np.array([0.0]), ki=np.array([0.0]))
    t = np.arange(1000) * 1e-3
    sim = simulate_joints(m, t, np.zeros((1000, 1)), pid)
    assert np.all(sim.q == 0) and np.all(sim.qd == 0)


# ------------------------------------------------------------------ bad input
def test_gravity_needs_constant_velocity_segments_of_each_sign(campaign):
    b = campaign.bang_bang
    with pytest.raises(InputError, match="constant-velocity segment of each sign"):
        estimate_gravity(b.t, b.q_meas, b.tau_meas, b.qr)


def test_friction_needs_bang_bang_data(campaign):
    s = campaign.sweep
    with pytest.raises(InputError, match="bang-bang"):
        estimate_friction(s.t, s.q_meas, s.tau_meas, s.qr)


def test_too_few_repetitions(campaign):
    s = campaign.sweep
    with pytest.raises(InputError, match="at least 3 repeated experiments"):
        estimate_gravity(s.t, s.q_meas[:2], s.tau_meas[:2], s.qr)
    with pytest.raises(InputError, match="at least 3"):
        RepeatedEstimate("x", ["a"], [[1.0], [2.0]], [1])


def test_shape_and_joint_errors(campaign):
    e = campaign.excitation
    with pytest.raises(InputError, match="repetitions, N, joints"):
        estimate_inertia(e.t[:-1], e.q_meas, e.tau_meas)
    with pytest.raises(InputError, match="joints must be numbers 1..6"):
        estimate_inertia(e.t, e.q_meas, e.tau_meas, joints=[7])
    q = e.q_meas.copy()
    q[0, 5, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        estimate_inertia(e.t, q, e.tau_meas)


def test_the_campaign_says_what_it_holds_in_a_line_not_its_arrays(campaign):
    """repr() of the simulated campaign is one line, not its arrays; str() summarises the recordings."""
    r = repr(campaign)
    assert r == f"<DecoupledCampaign 6 joints, {campaign.settings['n_repetitions']} repetitions>"
    text = str(campaign)
    assert text == campaign.summary() and len(text.splitlines()) == 6
    n = campaign.sweep.t.size
    assert f"sweep       {campaign.sweep.n_repetitions} repetition(s) x {n} samples" in text
    assert "at 1000 Hz) of 6 joint(s)" in text and "seed" in text
    assert repr(campaign.validation).startswith("<JointSimulation 1 repetition(s) x ")
