"""An Experiment built in Python and given to identify / run / diagnose / validate gets the checks
`load_experiment` makes of a file (time steps, gaps, the robot's limits, complex values; spikes,
jumps and saturation as notices), by the loader's own functions and in its words; simulated and
loaded recordings pass as they are."""
import dataclasses
import json
import warnings

import numpy as np
import pytest

import dynid
from dynid.analysis.data import record
from dynid.analysis.data.record import Experiment, checked_experiment
from dynid.analysis.identify import as_experiments
from dynid.errors import DataError

MEMORY = r"recording 1 \(an Experiment in memory\)"


@pytest.fixture(scope="module")
def planar2():
    robot = dynid.load_robot("planar2")
    return robot, dynid.simulate(robot, 6.0, seed=3).experiment


def _user(e, **arrays):
    """The recording as a user builds it from arrays: no source, name, notices or meta."""
    a = {"t": e.t, "q": e.q, "tau": e.tau}
    a.update(arrays)
    return Experiment(**a)


def _refused(data, robot, match):
    with pytest.raises(DataError, match=match) as err:
        dynid.identify(data, robot)
    return str(err.value)


def test_irregular_time_steps_are_refused(planar2):
    """1 ms steps for the first half, then 2 ms: a file is refused; in memory it gave ZZ1R = 14
    (true 2.72) with no notice."""
    robot, e = planar2
    h = e.n_samples // 2
    t = np.r_[e.t[:h], e.t[h - 1] + 2 * (e.t[h:] - e.t[h - 1])]
    msg = _refused(_user(e, t=t), robot, MEMORY + r": t: irregular time steps")
    assert "sample" in msg and "Resample" in msg


def test_irregular_time_steps_are_resampled_when_asked(planar2):
    robot, e = planar2
    h = e.n_samples // 2
    t = np.r_[e.t[:h], e.t[h - 1] + 1.03 * (e.t[h:] - e.t[h - 1])]      # 3 % off: irregular
    (out,) = as_experiments(_user(e, t=t), robot, resample=True)
    assert out.meta.get("resampled") is True
    assert np.allclose(np.diff(out.t), np.median(np.diff(t)))
    assert out.fs == pytest.approx(1.0 / np.median(np.diff(t)))
    assert any("resampled" in n for n in out.notices)
    assert out.q.shape == (out.t.size, 2) and out.tau.shape == (out.t.size, 2)


def test_gap_in_time_is_refused(planar2):
    robot, e = planar2
    h = e.n_samples // 2
    t = np.r_[e.t[:h], e.t[h:] + 0.5]
    msg = _refused(_user(e, t=t), robot, MEMORY + r": t: the recording has a gap")
    assert f"sample {h}" in msg and f"sample {h + 1}" in msg


def test_float32_time_is_refused(planar2):
    """Epoch-like time in float32: its steps are whole multiples of 0.98 ms, not the 1 ms
    recorded (5 % off in the parameters before)."""
    robot, e = planar2
    t = (e.t + 1e4).astype(np.float32)
    _refused(_user(e, t=t), robot, MEMORY + r": t: irregular time steps")


def test_time_repeats_in_the_loaders_words(planar2):
    robot, e = planar2
    t = e.t.copy()
    t[1001] = t[1000]
    _refused(_user(e, t=t), robot, MEMORY + r": t: time repeats at sample 1002")


def test_positions_in_degrees_are_refused(planar2):
    robot, e = planar2
    _refused(_user(e, q=np.degrees(e.q)), robot, MEMORY + r": q1: .*are the positions in degrees\?")


def test_torques_in_mNm_are_refused(planar2):
    robot, e = planar2
    _refused(_user(e, tau=e.tau * 1000), robot, MEMORY + r": tau1: .*are the torques in mN·m")


def test_one_joint_in_mNm_is_refused(planar2):
    robot, e = planar2
    _refused(_user(e, tau=e.tau * [1, 1000]), robot, MEMORY + r": tau2: .*mN·m")


def test_time_in_ms_is_refused(planar2):
    robot, e = planar2
    _refused(_user(e, t=e.t * 1000), robot, MEMORY + r": t: .*is t in ms\?")


def test_implausibly_large_value_is_refused(planar2):
    robot, e = planar2
    q = e.q.copy()
    q[10, 1] = 1e15
    _refused(_user(e, q=q), robot, MEMORY + r": q2, sample 11: .*implausibly large")


def test_complex_values_are_refused_without_a_warning(planar2):
    robot, e = planar2
    with warnings.catch_warnings():
        warnings.simplefilter("error")           # numpy's ComplexWarning was all there was
        with pytest.raises(DataError, match=r"complex values in tau: dynid needs real numbers"):
            dynid.identify(_user(e, tau=e.tau + 5j), robot)
        with pytest.raises(DataError, match=r"complex values in t: dynid needs real numbers"):
            Experiment(t=list(e.t + 0j), q=e.q, tau=e.tau)


def test_spike_jump_and_saturation_are_notices_not_refusals(planar2):
    robot, e = planar2
    tau = e.tau.copy()
    tau[3000, 1] += 1000.0                          # 50x the robust scale of tau2, below 20x tau_max
    (out,) = as_experiments(_user(e, tau=tau), robot)
    assert any("tau2, sample 3001: isolated spike in tau2" in n and "a glitch?" in n for n in out.notices)
    q = e.q.copy()
    q[2000, 0] += 1.0
    (out,) = as_experiments(_user(e, q=q), robot)
    assert any("q1, sample 2001: q1 jumps by" in n for n in out.notices)
    tau = e.tau.copy()
    top = np.abs(tau[:, 0]).max()
    tau[:, 0] = np.clip(tau[:, 0], -0.6 * top, 0.6 * top)
    (out,) = as_experiments(_user(e, tau=tau), robot)
    assert any("|tau1| sits at its maximum" in n for n in out.notices)
    assert np.array_equal(out.tau, tau)                 # a notice: the data are not touched


def test_validate_checks_an_experiment_in_memory(planar2):
    robot, e = planar2
    result = dynid.identify(e, robot)
    with pytest.raises(DataError, match=r"are the torques in mN·m"):
        dynid.validate(result, _user(e, tau=e.tau * 1000), robot)


def test_simulated_recording_passes_with_identical_results(planar2, monkeypatch):
    """`dynid.simulate` data raise nothing in the loader's checks: the experiment is checked, gains
    no notice, keeps its arrays, and identifies exactly as without the checks."""
    robot, e = planar2
    checked = checked_experiment(e, 0, robot)
    assert checked.notices == e.notices and checked.source == e.source and checked.fs == e.fs
    assert all(getattr(checked, s) is getattr(e, s) for s in ("t",) + record.SIGNALS)
    assert "time_from" not in e.meta                    # the user's experiment is not touched
    with_checks = dynid.identify(e, robot).to_dict()
    monkeypatch.setattr(record, "loader_checks", lambda *a, **k: {}, raising=False)
    without = dynid.identify(e, robot).to_dict()
    keep = ("parameters", "essential", "rel_error", "rms_per_joint", "data_hash", "notices")
    assert json.dumps({k: with_checks[k] for k in keep}, sort_keys=True, default=str) == \
        json.dumps({k: without[k] for k in keep}, sort_keys=True, default=str)


def test_loaded_and_checked_recordings_are_not_checked_again(planar2, tmp_path, monkeypatch):
    """A recording from the loader (or already checked) keeps its notices and is not re-checked:
    its description may allow a wider time tolerance, and the checks cost time on long logs."""
    robot, e = planar2
    path = tmp_path / "p.npz"
    np.savez(path, t=e.t, q=e.q, tau=e.tau)
    loaded = dynid.load_experiment(path, robot)
    checked = checked_experiment(_user(e), 0, robot)
    calls = []
    monkeypatch.setattr(record, "loader_checks", lambda *a, **k: calls.append(a) or {})
    assert checked_experiment(loaded, 0, robot) is loaded
    again = checked_experiment(checked, 0, robot)
    assert again is checked and calls == []
    # a held-out part of a checked recording, cut by holdout_split / segment, is one too
    train, held_out = dynid.holdout_split(checked, 1.0)
    assert checked_experiment(held_out, 0, robot).notices == held_out.notices and calls == []


def test_replace_and_slicing_still_build_experiments(planar2):
    robot, e = planar2
    h = e.n_samples // 2
    t = np.r_[e.t[:h], e.t[h:] + 0.5]                  # Experiment itself takes it: identify refuses it
    bad = dataclasses.replace(e, t=t, fs=None)
    assert bad.n_samples == e.n_samples
    part = _user(e).segment(None, 2.0)
    train, held_out = dynid.holdout_split(_user(e), 1.0)
    assert part.n_samples == 2000 and train.n_samples + held_out.n_samples == e.n_samples
    (out,) = as_experiments(train, robot)
    assert out.source == "recording 1 (an Experiment in memory)"


def test_a_recording_loaded_without_a_robot_is_checked_against_the_robot_it_is_identified_with(tmp_path):
    """dynid.identify(dynid.load_experiment("deg.npz"), "planar2") took positions in degrees, which the
    path itself, or the same arrays in memory, are refused for (a review of the in-memory checks)."""
    rec = dynid.simulate("planar2", 4.0, seed=1).experiment
    np.savez(tmp_path / "deg.npz", t=rec.t, q=np.degrees(rec.q), tau=rec.tau)
    loaded = dynid.load_experiment(tmp_path / "deg.npz")
    with pytest.raises(dynid.DataError, match="are the positions in degrees"):
        dynid.identify(loaded, "planar2")
    with pytest.raises(dynid.DataError, match="are the positions in degrees"):
        dynid.diagnose(loaded, "planar2")


def test_identify_resamples_an_experiment_in_memory_when_asked():
    """dynid.identify had no resample= (dynid.run had): its refusal of irregular steps now names it."""
    rec = dynid.simulate("planar2", 4.0, seed=1).experiment
    t = rec.t.copy()
    half = t.size // 2
    t[half:] = t[half] + 1.05 * (t[half:] - t[half])
    bad = Experiment(t=t, q=rec.q, qr=None, qd=None, qdd=None, tau=rec.tau)
    with pytest.raises(DataError, match=r"irregular.*resample=True \(dynid.identify, dynid.run\)"):
        dynid.identify(bad, "planar2")
    res = dynid.identify(bad, "planar2", resample=True)
    assert any("resampled" in n or "interpolat" in n for n in res.notices), res.notices
