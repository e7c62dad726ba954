"""Tests of dynid.analysis.data.split.blocked_folds (blocked cross-validation in time).

Every sample carries its own index in tau, so which raw samples each fold holds is read off
the data and compared with index sets computed here from the times alone."""
from __future__ import annotations

import numpy as np
import pytest

from dynid.analysis.data.experiment import Experiment
from dynid.analysis.data.split import blocked_folds
from dynid.errors import InputError

FS = 100.0


def indexed(n=1000, t0=3.0):
    t = t0 + np.arange(n) / FS
    idx = np.arange(n, dtype=float)
    return Experiment(t=t, q=np.c_[np.sin(t), np.cos(t)], tau=np.c_[idx, -idx], fs=FS, source="toy")


def held(e):
    return set(e.tau[:, 0].astype(int))


@pytest.mark.parametrize("k, margin, gap", [(5, 0.7, 0.3), (3, 0.0, 0.0), (4, 1.17, 0.5), (2, 0.25, 1.0)])
def test_folds_partition_the_record(k, margin, gap):
    exp = indexed()
    t = exp.t
    folds = blocked_folds(exp, k, margin=margin, gap=gap)
    assert len(folds) == k
    # the blocks tile the processed span in k equal pieces
    lo, hi = t[0] + margin, t[-1] - margin
    spans = np.array([f.span for f in folds])
    assert spans[0, 0] == pytest.approx(lo) and spans[-1, 1] == pytest.approx(hi)
    np.testing.assert_allclose(spans[1:, 0], spans[:-1, 1])
    np.testing.assert_allclose(np.diff(spans, axis=1), (hi - lo) / k)
    cores = []
    for f in folds:
        a, b = f.span
        start = -np.inf if f.block == 0 else a - margin
        end = np.inf if f.block == k - 1 else b + margin
        want_test = set(np.flatnonzero((t >= start) & (t < end)))
        want_train = set(np.flatnonzero((t < start - gap) | (t >= end + gap)))
        assert held(f.test) == want_test
        train = set().union(*(held(p) for p in f.train))
        assert train <= want_train
        # what is left out of the training data is a part too short to survive processing
        for run in np.split(np.array(sorted(want_train - train)), np.flatnonzero(
                np.diff(sorted(want_train - train)) > 1) + 1) if want_train - train else []:
            assert t[run[-1]] - t[run[0]] <= 2 * margin
        assert all(p.duration > 2 * margin - 1 / FS for p in f.train)
        assert not train & want_test
        # every training sample is at least `gap` from every test sample
        t_train = np.concatenate([p.t for p in f.train])
        assert np.min(np.abs(t_train[:, None] - f.test.t[None, :])) >= gap - 0.5 / FS
        # the data are the record's own samples, unchanged
        for p in [f.test, *f.train]:
            i = p.tau[:, 0].astype(int)
            np.testing.assert_array_equal(p.t, t[i])
            np.testing.assert_array_equal(p.q, exp.q[i])
        cores.append(np.flatnonzero((f.test.t >= a) & (f.test.t < b)) + int(f.test.tau[0, 0]))
    # the scored cores: every sample of the processed span exactly once
    cores = np.concatenate(cores)
    assert len(cores) == len(set(cores))
    assert set(cores) == set(np.flatnonzero((t >= lo) & (t < hi)))


def test_no_gap_no_margin_fold_is_the_whole_record():
    exp = indexed(n=200)
    for f in blocked_folds(exp, 4):
        assert sorted(held(f.test) | set().union(*(held(p) for p in f.train))) == list(range(200))


def test_training_part_too_short_to_process_is_left_out():
    exp = indexed(n=1000)        # 9.99 s
    # block 2 of 5 with margin 1 s: the left part ends at 1 + 1.598 - 1 - 0.1 = 1.498 s < 2 s
    f = blocked_folds(exp, 5, margin=1.0, gap=0.1)[1]
    assert len(f.train) == 1 and f.train[0].t[0] >= f.test.t[-1]


@pytest.mark.parametrize("k, kw, words", [
    (1, {}, "k >= 2"), (2.5, {}, "k >= 2"), (True, {}, "k >= 2"),
    (5, {"margin": -0.1}, ">= 0"), (5, {"gap": "a"}, "numbers of seconds"),
    (600, {}, "fewer blocks"), (5, {"margin": 5.0}, "fewer blocks"),
    (2, {"margin": 2.0, "gap": 6.0}, "nothing is left"),
])
def test_bad_input_is_one_clear_error(k, kw, words):
    with pytest.raises(InputError, match=words):
        blocked_folds(indexed(), k, **kw)


def test_processed_blocks_hold_the_samples_of_their_span():
    """Through the real processing (filter edges, decimation transient) of a LWR4+ recording:
    once processed, each test recording's samples lie in its block and no time is scored twice;
    per block, as many samples as the whole recording processed at once has there, +-1."""
    from pathlib import Path

    from dynid.analysis.data.experiment import load_experiment
    from dynid.analysis.processing.observation import observe, resolve_settings
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    robot = load_robot("kuka_lwr4")
    exp = load_experiment(Path(__file__).resolve().parents[3] / "examples" / "kuka_lwr4" / "recording_2.toml",
                          robot)
    bp = base_parameters(robot)
    s = dict(resolve_settings(exp), qd_threshold=0.0)
    whole = observe(exp, robot, bp, s).t
    folds = blocked_folds(exp, 5, margin=whole[0] - exp.t[0], gap=0.5)
    scored = [observe(f.test, robot, bp, s).t for f in folds]
    half = 0.5 / exp.fs
    for f, ts in zip(folds, scored):
        assert f.span[0] - half <= ts[0] and ts[-1] < f.span[1] + half
        assert abs(len(ts) - np.sum((whole >= f.span[0] - half) & (whole < f.span[1] - half))) <= 1
    assert np.all(np.diff(np.concatenate(scored)) > 0)


def test_holdout_that_leaves_too_few_samples_says_which_part_and_what_to_do():
    from dynid.analysis.data.split import MIN_PART_SAMPLES, holdout_split
    exp = indexed(1000)                                      # 10 s at 100 Hz
    ident, held = holdout_split(exp, 2.0)
    assert ident.n_samples + held.n_samples == 1000 and held.n_samples >= MIN_PART_SAMPLES
    with pytest.raises(InputError, match="identification part .*hold out less"):
        holdout_split(exp, 9.95)
    with pytest.raises(InputError, match="held-out part .*hold out more"):
        holdout_split(exp, 0.05)
    with pytest.raises(InputError, match="too short to hold out"):
        holdout_split(indexed(100), 0.5)
