"""What the Python API does with what a user passes it: simulated recordings where a recording
is expected, joint numbers, switches, progress callables, payload options, and one recording
given twice (shifted by a sample), plus the parts of the results interface every result has
(`to_csv`, a one-line `repr`) on the results that lacked them."""
import dataclasses
import pickle
import re

import numpy as np
import pandas as pd
import pytest

import dynid
from dynid.analysis.data.plausibility import position_jumps
from dynid.analysis.data.record import Experiment, same_samples, shared_run
from dynid.errors import IdentificationError, InputError
from dynid.ranges import check_joints


@pytest.fixture(scope="module")
def planar2():
    robot = dynid.load_robot("planar2")
    rec = dynid.simulate(robot, 8.0, seed=3)
    return robot, rec, dynid.identify(rec, robot)


@pytest.fixture(scope="module")
def tx40_payload():
    """The TX40, a 4 s recording with a 2 kg payload (seed 2) and the IDIM run of a 4 s recording
    without it (seed 1): the model JSON the payload tests edit is that run's `to_dict()` (a new
    dict at every call)."""
    tx40 = dynid.load_robot("tx40")
    loaded = dynid.simulate(tx40, 4.0, seed=2, payload=(2.0, (0, 0, 0.05)))
    return tx40, loaded, dynid.run(dynid.simulate(tx40, 4.0, seed=1), tx40)


def _shifted(exp, k=1):
    """The same recording without its first k samples (what a re-export or a trim gives)."""
    return Experiment(t=exp.t[k:] - exp.t[k], q=exp.q[k:], qr=None if exp.qr is None else exp.qr[k:],
                      qd=None, qdd=None, tau=exp.tau[k:], name="shifted", source="shifted.csv")


def test_a_simulated_recording_is_taken_wherever_a_recording_is(planar2):
    robot, rec, r = planar2
    train, held = dynid.holdout_split(rec, 2.0)
    assert train.n_samples + held.n_samples == rec.experiment.n_samples
    assert dynid.validate(r, dynid.simulate(robot, 4.0, seed=4), "planar2").rel_error < 0.1


def test_joint_numbers_are_checked_before_any_work(planar2):
    robot, rec, r = planar2
    assert check_joints(None, 3) == [1, 2, 3] and check_joints("all", 2) == [1, 2] and check_joints(2, 2) == [2]
    assert check_joints(np.int64(2), 2) == [2] and check_joints(np.array([2, 1]), 2) == [2, 1]
    assert check_joints((j for j in (1, 2)), 2) == [1, 2]
    for bad in ([0], [3], [1, 1], [True], [np.True_], [1.5], [float("inf")], [float("nan")], "x", []):
        with pytest.raises(InputError, match="distinct joint numbers 1..2"):
            check_joints(bad, 2)
    # joint 0 used to test joint 2 under the name "joint 0" (numpy's index -1)
    with pytest.raises(InputError, match="joint numbers 1..2"):
        dynid.diagnose(rec.experiment, robot, idim_result=r, joints=[0], effects=["offset"])


def test_a_switch_given_as_text_is_refused(planar2):
    robot, rec, _ = planar2
    with pytest.raises(InputError, match="gravity_tilt= is a switch"):
        dynid.run(rec, robot, gravity_tilt="yes")


def test_sample_calls_progress_with_the_fraction_done(planar2):
    _, _, r = planar2
    with pytest.raises(InputError, match="progress must be a function"):
        dynid.sample(r, progress=5)
    for bad in (dict(seed="a"), dict(walkers="x")):
        with pytest.raises(InputError, match="out of range"):
            dynid.sample(r, max_steps=10, **bad)
    seen = []
    dynid.sample(r, max_steps=400, progress=seen.append)
    assert seen and all(0.0 <= f <= 1.0 for f in seen) and seen[-1] == 1.0
    assert all(b >= a for a, b in zip(seen, seen[1:]))


def test_payload_options_are_checked(planar2):
    robot, rec, r = planar2
    tx40 = dynid.load_robot("tx40")
    loaded = dynid.simulate(tx40, 3.0, seed=2, payload=(2.0, (0, 0, 0.05)))
    with pytest.raises(InputError, match="unknown key.*'xzy'"):
        dynid.identify_payload(loaded, tx40, unloaded=loaded, offset={"xzy": [0, 0, 0.01]})
    with pytest.raises(InputError, match="no 'parameters' list"):
        dynid.identify_payload(loaded, tx40, model={"parameters": []})
    with pytest.raises(InputError, match="max_rel_halfwidth"):
        dynid.identify_payload(loaded, tx40, model={"parameters": []}, max_rel_halfwidth="x")
    with pytest.raises(InputError, match="payload_options given without payload"):
        dynid.report(rec, robot, payload_options={"frame": "flange"})


def test_a_model_json_whose_covariance_is_not_one_is_refused(tx40_payload):
    tx40, loaded, empty_run = tx40_payload
    doc = empty_run.to_dict()
    doc["wls"]["covariance"] = (-np.asarray(doc["wls"]["covariance"], dtype=float)).tolist()
    # a negated covariance gave the payload sigma 0 and intervals of zero width, exit 0
    with pytest.raises(InputError, match="not a covariance"):
        dynid.identify_payload(loaded, tx40, model=doc)


def test_an_edited_model_json_is_refused_naming_the_record(tx40_payload):
    """A value that is not a number or a name that is not text crashed (exit 1); a repeated name was
    summed into one parameter and a missing one taken as 0, without a word."""
    import copy
    tx40, loaded, empty_run = tx40_payload
    doc = empty_run.to_dict()
    first = doc["wls"]["parameters"][0]["name"]
    cases = [(lambda d: d["wls"]["parameters"][0].update(value="abc"), rf"wls.parameters\[0\] \({first}\): value is 'abc'"),
             (lambda d: d["wls"]["parameters"][0].update(value=True), "value is True, not a number"),
             (lambda d: d["wls"]["parameters"][0].update(name=5), r"wls.parameters\[0\].name is 5"),
             (lambda d: d["wls"]["parameters"].append(dict(d["wls"]["parameters"][0])), f"lists {first} twice"),
             (lambda d: d["wls"]["parameters"].pop(0), f"lacks the base parameter\\(s\\) {first} of robot 'tx40'")]
    for edit, message in cases:
        bad = copy.deepcopy(doc)
        edit(bad)
        with pytest.raises(InputError, match=message):
            dynid.identify_payload(loaded, tx40, model=bad)
    unsigned = copy.deepcopy(doc)
    unsigned["robot_signature"] = None
    res = dynid.identify_payload(loaded, tx40, model=unsigned, max_rel_halfwidth=10.0)   # 4 s: a wide payload
    assert any("no robot_signature" in n for n in res.notices)
    # a result object is named by its method, not its class (the report printed "IDIMResult"); the run's
    # result is the IDIMResult dynid.identify gives of the same recording (same estimate and covariance)
    res = dynid.identify_payload(loaded, tx40, model=empty_run.result, max_rel_halfwidth=10.0)
    assert "robot fixed: the IDIM identification given as model; its parameters' uncertainty is propagated" \
        in res.notices


def test_one_recording_shifted_by_a_sample_is_not_a_second_recording(planar2):
    robot, rec, _ = planar2
    exp = rec.experiment
    other = dynid.simulate(robot, 8.0, seed=5).experiment
    assert shared_run(exp, other) == 0 and shared_run(exp, _shifted(exp)) == exp.n_samples - 1
    assert same_samples(exp, _shifted(exp)) and not same_samples(exp, other)
    with pytest.raises(InputError, match=r"share \d+ consecutive samples, bit for bit"):
        dynid.identify([exp, _shifted(exp)], robot)
    with pytest.raises(InputError, match=r"--validation \(validation=\) shifted.csv shares"):
        dynid.run(exp, robot, validation=_shifted(exp, 5))
    # a robot at rest logs the same sample over and over: a few shared samples are no duplicate
    still = Experiment(t=exp.t[:500], q=np.zeros((500, 2)), qr=None, qd=None, qdd=None, tau=np.ones((500, 2)))
    assert not same_samples(still, still)


def test_a_one_sample_position_jump_is_named_and_blamed(planar2):
    robot, rec, _ = planar2
    exp = rec.experiment
    q = exp.q.copy()
    q[300, 1] += 2 * np.pi                    # an encoder wrap-around glitch
    notices = []
    position_jumps({"q": q}, None, None, "glitch.csv", notices)
    assert len(notices) == 1 and "sample 301" in notices[0] and "q2 jumps by 6.2" in notices[0]
    notices = []
    position_jumps({"q": exp.q, "qr": exp.qr}, None, None, "clean.csv", notices)
    assert notices == []
    # on a slower motion the glitch zeroes joint 2's rows through the velocity dead zone (1 % of
    # the peak |qd|): the rank-deficiency error says what the loader found
    slow = dynid.simulate(robot, 4.0, f0=0.5, harmonics=4).experiment
    q = slow.q.copy()
    q[300, 1] += 2 * np.pi
    notices = []
    position_jumps({"q": q}, None, None, "glitch.csv", notices)
    glitched = dataclasses.replace(slow, q=q, notices=notices)
    with pytest.raises(IdentificationError, match="all zero.*The data hold glitches.*q2 jumps by"):
        dynid.run(glitched, robot)


def test_the_verdict_says_when_ml_reads_a_motion_that_is_not_periodic():
    rec = dynid.simulate("planar2", 10.0, seed=3, f0=0.5, harmonics=5)   # its start-up transient
    run = dynid.run(rec, "planar2", method="ml", f0=0.5, ml_harmonics=5)
    assert "the motion is not periodic at maximum likelihood's f0" in run.verdict.reasons
    assert any("latent trajectory" in f["text"] and f["level"] == "warn" for f in run.verdict.findings)


def test_results_that_lacked_parts_of_the_interface(planar2, tmp_path):
    robot, rec, r = planar2
    train, held = dynid.holdout_split(rec, 2.0)
    v = dynid.verdict(r, held)
    frame = pd.read_csv(pd.io.common.StringIO(v.to_csv()), index_col=0)
    assert list(frame.index) == list(r.model.names) and "unit" in frame.columns
    assert repr(v).startswith("<Verdict ") and "\n" not in repr(v)
    run = dynid.run(train, robot, effects="spring:all")
    assert run["ZZ1R"].value == run.result["ZZ1R"].value
    assert run.cov_params().shape == (len(run.result.names),) * 2
    eff = pd.read_csv(pd.io.common.StringIO(run.effects.to_csv()), index_col=0)
    assert list(eff.index) == ["Ks1", "Ks2"] and set(eff["unit"]) == {"N m/rad"}
    assert "\n" not in repr(run.effects)
    ex = dynid.excite(robot, 0.5, 2, n_starts=1)
    assert repr(ex).startswith("<ExcitationResult robot 'planar2'") and "\n" not in repr(ex)
    didim = dynid.identify(rec, robot, "didim", max_iter=2, progress=lambda f: None)
    assert pickle.loads(pickle.dumps(didim)).params.equals(didim.params)


def test_a_still_joint_is_named_when_the_identification_fails(planar2):
    robot, rec, _ = planar2
    exp = rec.experiment
    q = exp.q.copy()
    q[:, 1] = q[0, 1]                          # joint 2 held (its torque still recorded)
    still = dataclasses.replace(exp, q=q, qr=None if exp.qr is None else exp.qr.copy())
    with pytest.raises(IdentificationError, match=r"Joint 2 does not move in .* \(q2 spans 0 rad\)"):
        dynid.run(still, robot)


def test_independent_runs_of_one_excitation_on_coarse_sensors_are_two_recordings():
    """Two runs of the same reference on a 2-joint arm with a 12-bit encoder and 0.1 N m torque
    steps share half their samples bit for bit, scattered; a copy shares one unbroken run."""
    from dynid.analysis.data.synthetic import apriori_parameters, random_fourier_trajectory, simulate_experiment
    from dynid.dynamics.base_parameters import base_parameters
    robot = dynid.load_robot("planar2")
    rng = np.random.default_rng(3)
    e = simulate_experiment(robot, apriori_parameters(robot, base_parameters(robot)),
                            random_fourier_trajectory(robot, 0.1, 5, rng), 20.0, rng=rng, q_noise=0.0, tau_noise=0.0)
    runs = []
    for seed in (10, 11):
        r = np.random.default_rng(seed)
        q = np.round((e.q + 1e-5 * r.standard_normal(e.q.shape)) / (2 * np.pi / 2 ** 12)) * (2 * np.pi / 2 ** 12)
        tau = np.round((e.tau + 0.03 * r.standard_normal(e.tau.shape)) / 0.1) * 0.1
        runs.append(dataclasses.replace(e, q=q, tau=tau, source=f"run{seed}.csv"))
    assert shared_run(*runs) < 20 and not same_samples(*runs)
    assert same_samples(runs[0], _shifted(runs[0], 3))


def test_a_seed_keeps_every_digit():
    from dynid.ranges import check_range
    assert check_range("seed", np.int64(10 ** 17 + 1)) == 10 ** 17 + 1
    assert check_range("seed", 7.0) == 7 and isinstance(check_range("seed", 7.0), int)


def test_maximum_likelihood_refuses_a_jacobian_it_cannot_afford():
    """BIC chose 60 harmonics on a 4 s, 5 kHz TX40 log: a 240,000 x 786 dense Jacobian, still
    running after 15 minutes and 10 GB. Refused before any work, with the K that fits."""
    rec = dynid.simulate("tx40", 4.0, seed=1, f0=0.5, harmonics=3)
    with pytest.raises(InputError, match=r"60 harmonics \(chosen by BIC on q\).*too large.*11 fit"):
        dynid.identify(rec, "tx40", "ml", f0=0.5)


def test_a_holdout_too_short_for_the_decimation_says_how_long_it_must_be(planar2):
    robot, rec, _ = planar2
    with pytest.raises(InputError, match=r"held-out data \(\d+ samples.*needs about [\d.]+ s\. Hold out more"):
        dynid.run(rec, robot, holdout=0.3)


def test_the_posterior_does_not_run_off_where_its_expansion_cancels(tmp_path):
    """On a 0.1 s recording the sampler reached sigma1 = 1.2e-148 (exit 0): the expanded residual
    s - 2 d'g + d'G d cancels terms of 1e20 far out along the directions the data hardly see, and
    came out near 0. Such points are outside the support now: the chains do not converge (the
    posterior is flat along those directions, and the result says so), but sigma stays the noise's."""
    # as `dynid simulate --duration 0.1 --f0 1 --harmonics 5 --out short.csv` wrote it
    dynid.simulate("planar2", 0.1, seed=1, f0=1.0, harmonics=5).to_csv(tmp_path / "short.csv")
    r = dynid.identify(dynid.load_experiment(tmp_path / "short.csv", "planar2"), "planar2")
    try:
        post = dynid.sample(r, max_seconds=5)
    except IdentificationError as exc:            # no start where the density can be evaluated
        assert "could not place the initial walkers" in str(exc)
        return
    assert not post.converged
    assert post.params[["sigma1", "sigma2"]].min() > 0.05      # simulated with 0.5 N m torque noise


def test_simulate_says_when_its_loop_tracks_the_reference_poorly():
    """The LWR4+ under a soft PD (wn = 8 rad/s, no gravity model) follows a random reference to
    0.4 rad on joint 2: the recording is valid, but not what a tuned robot logs. Sampled at
    200 Hz the robot file's PD is unstable near the aligned wrist: that is said instead, and the
    poor tracking not blamed on soft gains. The bundled robots' loops are not flagged."""
    import dataclasses
    lwr = dynid.load_robot("kuka_lwr4")
    soft = dataclasses.replace(lwr, controller=dataclasses.replace(lwr.controller, wn=np.full(7, 8.0)))
    assert any("tracks its reference poorly" in n and "j2 0.4" in n
               for n in dynid.simulate(soft, 6.0, seed=1).notices)
    slow = dataclasses.replace(lwr, controller=dataclasses.replace(lwr.controller, rate=200.0))
    notices = dynid.simulate(slow, 6.0, seed=1).notices
    assert any("is unstable at 200 Hz" in n for n in notices)
    assert not any("tracks its reference poorly" in n for n in notices)
    for robot in ("tx40", "planar2", "kuka_lwr4"):
        assert not any("tracks its reference poorly" in n for n in dynid.simulate(robot, 6.0, seed=1).notices)


def test_ml_says_when_no_sample_is_clear_of_every_joints_reversal():
    """Each joint kept enough equations, but no sample had every joint away from a reversal (the
    guard 1 / (4 K f0) with 2 harmonics at 0.2 Hz is 0.625 s): the error was "only 0 equations
    are used for 13 parameters ... decimate less"."""
    from dynid.analysis.estimators.maximum_likelihood import _kept_equations
    t = np.arange(0.0, 10.0, 1e-3)
    w = 2 * np.pi * 0.2
    # four joints reversing in turn, an eighth of a period apart: each keeps half its equations
    qdf = np.column_stack([np.sin(w * t), np.cos(w * t), np.sin(w * t + np.pi / 4), np.cos(w * t + np.pi / 4)])
    with pytest.raises(InputError, match=r"keeps [01] of 10000 samples with every joint's.*K = 2 harmonics.*fit more"):
        _kept_equations(t, qdf, "auto", "auto", 2, 0.2, 13)


def test_excite_takes_the_command_lines_names_and_refuses_unknown_ones():
    """`starts=` gave a TypeError naming an internal function; the command line's names work."""
    a = dynid.excite("planar2", 0.2, 2, starts=1, seed=0, max_iter=5)
    b = dynid.excite("planar2", 0.2, 2, n_starts=1, rng=0, max_iter=5)
    assert a.cond_result == b.cond_result
    with pytest.raises(InputError, match=r"excite: unknown option\(s\) startz; the options are .*n_starts"):
        dynid.excite("planar2", 0.2, 2, startz=1)
    with pytest.raises(InputError, match="give n_starts= or starts=, not both"):
        dynid.excite("planar2", 0.2, 2, starts=1, n_starts=2)


def test_a_recording_where_the_robot_goes_is_named_for_the_arguments_order():
    """dynid.diagnose(result, held_out) said "unknown robot 'Experiment(...)': not a file"."""
    rec = dynid.simulate("planar2", 3.0, seed=1)
    with pytest.raises(InputError, match="not Experiment; the recording comes first and the robot second"):
        dynid.diagnose(rec.experiment, rec.experiment)
    # paths swapped: "robot file 'p2.csv': unknown extension '.csv'" (a first-hour review)
    for call in (dynid.run, dynid.identify):
        with pytest.raises(InputError, match="'p2.csv' is a data file.*the recording comes first"):
            call("planar2", "p2.csv")
    with pytest.raises(InputError, match=r"qd_threshold \(--qd-threshold\) must be a number"):
        dynid.identify(rec, "planar2", qd_threshold="abc")


def test_the_python_api_never_writes_over_its_inputs(tmp_path, monkeypatch):
    """`dynid.run(..., csv=...)`, `dynid.report(..., path)` and `dynid.demo(path=...)` refuse, before
    any work, what `dynid identify` refuses: an output that is the recording (under any name), a
    file the TOML reads, or the robot file; an output in a folder that does not exist."""
    monkeypatch.chdir(tmp_path)
    rec = dynid.simulate("planar2", 4.0, seed=1)
    pd.DataFrame({"t": rec.experiment.t, **{f"q{j + 1}": rec.experiment.q[:, j] for j in range(2)},
                  **{f"tau{j + 1}": rec.experiment.tau[:, j] for j in range(2)}}).to_csv("run.csv", index=False)
    (tmp_path / "run.toml").write_text('[experiment]\nname = "r"\n[positions]\nfile = "run.csv"\n'
                                       'columns = ["q1", "q2"]\n[torques]\nfile = "run.csv"\n'
                                       'columns = ["tau1", "tau2"]\n')
    from dynid.dynamics.robot_file import bundled_path
    robot_file = tmp_path / "arm.toml"
    robot_file.write_bytes(bundled_path("planar2").read_bytes())
    before = (tmp_path / "run.csv").read_bytes()
    (tmp_path / "held.csv").write_bytes(before)
    work = []
    monkeypatch.setattr("dynid.analysis.run.run", lambda *a, **k: work.append(1))    # no work may start
    for call, words in [
            (lambda: dynid.run("run.csv", "planar2", csv="run.csv"), "csv= run.csv is the data file"),
            (lambda: dynid.run(str(tmp_path / "run.csv"), "planar2", json="./run.csv"), "json= ./run.csv is the data"),
            (lambda: dynid.run("run.toml", "planar2", csv="run.csv"), "the file run.toml reads"),
            (lambda: dynid.run(rec, "planar2", json="a.json", csv="sub/../a.json"), "the same file"),
            (lambda: dynid.run("run.csv", "planar2", report="nodir/r.html"), "does not exist"),
            (lambda: dynid.report("run.csv", "planar2", "run.csv"), "report (path=) run.csv is the data file"),
            (lambda: dynid.run("run.csv", "planar2", settings=dynid.Settings(validation="held.csv", csv="held.csv")),
             "csv= held.csv is the validation= file"),
            (lambda: dynid.report("run.csv", "planar2", "held.csv", validation="held.csv"),
             "is the validation= file"),
            (lambda: dynid.demo(path="nodir/demo.html"), "does not exist")]:
        with pytest.raises(InputError, match=re.escape(words)):
            call()
    with pytest.raises(InputError, match="is the robot file"):
        dynid.run("run.csv", str(robot_file), json=str(robot_file))
    with pytest.raises(InputError, match="the bundled robot planar2's file"):
        dynid.run("run.csv", "planar2", json=str(bundled_path("planar2")))
    assert not work and (tmp_path / "run.csv").read_bytes() == before


def test_diagnose_refuses_its_identification_data_as_validation():
    """dynid.diagnose(data, robot, validation=data) measured its "validation" errors on the training
    data; the command line, dynid.run and dynid.verdict refused it (bad-input hunt)."""
    rec = dynid.simulate("planar2", 3.0, seed=1).experiment
    half = dynid.holdout_split(rec, 1.0)[0]
    for same in (rec, half):
        with pytest.raises(InputError, match=r"validation=\) .*consecutive samples, bit for bit"):
            dynid.diagnose(rec, "planar2", validation=same)
