"""Gear ratios in the experiment description's metadata (issue 27): joint-side data whose
robot file has no gear ratio can name a line at a harmonic of the motor turn."""
import numpy as np
import pandas as pd
import pytest

from dynid import load_experiment
from dynid.analysis.diagnosis.hypotheses import gear_ratios_of, name_flags
from dynid.analysis.diagnosis.structure import StructureResult, StructureTest, Unexplained
from dynid.errors import DataError

N = 200


def _csv(tmp_path):
    rng = np.random.default_rng(0)
    df = pd.DataFrame(rng.normal(size=(N, 6)), columns=["q1", "q2", "q3", "t1", "t2", "t3"])
    df.to_csv(tmp_path / "d.csv", index=False)


JOINT_SIDE = """
[experiment]
sampling_rate = 250.0
gear_ratios = [160, 160, 100]
[positions]
file = "d.csv"
columns = ["q1", "q2", "q3"]
[torques]
file = "d.csv"
columns = ["t1", "t2", "t3"]
"""

MOTOR_SIDE = JOINT_SIDE.replace("gear_ratios = [160, 160, 100]\n", "").replace(
    '["q1", "q2", "q3"]', '["q1", "q2", "q3"]\nside = "motor"') + """
[transmission]
gear_ratios = [32, -48, 45]
"""


def _load(tmp_path, text, name="e.toml"):
    _csv(tmp_path)
    (tmp_path / name).write_text(text)
    return load_experiment(tmp_path / name, n_joints=3)


def test_joint_side_description_gives_the_gear_ratios(tmp_path):
    e = _load(tmp_path, JOINT_SIDE)
    assert e.meta["gear_ratios"] == [160.0, 160.0, 100.0]
    np.testing.assert_array_equal(gear_ratios_of(e), [160.0, 160.0, 100.0])
    # metadata only: the joint-side signals are not converted by it
    raw = pd.read_csv(tmp_path / "d.csv")
    np.testing.assert_allclose(e.q, raw[["q1", "q2", "q3"]].to_numpy())
    # kept through a window (the hold-out split)
    assert e.segment(0.0, 0.4).meta["gear_ratios"] == [160.0, 160.0, 100.0]


def test_motor_side_transmission_gives_them_and_none_without(tmp_path):
    assert _load(tmp_path, MOTOR_SIDE).meta["gear_ratios"] == [32.0, -48.0, 45.0]
    plain = JOINT_SIDE.replace("gear_ratios = [160, 160, 100]\n", "")
    e = _load(tmp_path, plain)
    assert "gear_ratios" not in e.meta and gear_ratios_of(e) is None
    # the same ratios in both places are accepted
    both = MOTOR_SIDE.replace("sampling_rate = 250.0", "sampling_rate = 250.0\ngear_ratios = [32, -48, 45]")
    assert _load(tmp_path, both).meta["gear_ratios"] == [32.0, -48.0, 45.0]


def test_top_level_key_and_column_format(tmp_path):
    text = "gear_ratios = [2, 3, 4]\n" + JOINT_SIDE.replace("gear_ratios = [160, 160, 100]\n", "")
    assert _load(tmp_path, text).meta["gear_ratios"] == [2.0, 3.0, 4.0]
    t = np.arange(N) / 250.0
    rng = np.random.default_rng(1)
    cols = {"t": t, **{f"q{j}": rng.normal(size=N) for j in (1, 2, 3)},
            **{f"tau{j}": rng.normal(size=N) for j in (1, 2, 3)}}
    pd.DataFrame(cols).to_csv(tmp_path / "cols.csv", index=False)
    (tmp_path / "c.toml").write_text('[experiment]\nfile = "cols.csv"\ngear_ratios = [5, 6, 7]\n')
    assert load_experiment(tmp_path / "c.toml", n_joints=3).meta["gear_ratios"] == [5.0, 6.0, 7.0]


@pytest.mark.parametrize("edit,words", [
    (lambda s: s.replace("[160, 160, 100]", "[160, 0, 100]"), ["[experiment]", "gear_ratios[1] = 0", "joint 2"]),
    (lambda s: s.replace("[160, 160, 100]", "[160, 160]"), ["[experiment]", "gear_ratios", "2 entries", "3 joints"]),
    (lambda s: s.replace("[160, 160, 100]", '["a", 1, 2]'), ["[experiment]", "gear_ratios", "list of numbers"]),
    (lambda s: MOTOR_SIDE.replace("sampling_rate = 250.0", "sampling_rate = 250.0\ngear_ratios = [32, 48, 45]"),
     ["[experiment]", "differ from [transmission]", "remove"]),
])
def test_bad_gear_ratios_one_clear_error(tmp_path, edit, words):
    with pytest.raises(DataError) as e:
        _load(tmp_path, edit(JOINT_SIDE), "bad.toml")
    msg = str(e.value)
    assert "bad.toml" in msg
    for w in words:
        assert w in msg, (w, msg)


def test_description_gear_ratios_name_the_motor_harmonic(tmp_path):
    """A joint-side recording (no [transmission]): the line of period 2 pi / (160 x 3) on joint 1
    is named the 3rd harmonic of motor 1 only with the description's gear ratios."""
    e = _load(tmp_path, JOINT_SIDE)
    per = 2 * np.pi / (160 * 3)

    def structure():
        t = StructureTest(1, "line", "q1", 0.0, 1e-9, p_value=1e-9, rms=1.0, noise_rms=0.5,
                          ratio=2.0, large=True, flagged=True, detail={"period_rad": per})
        u = Unexplained(joint=1, depends_on="q1", rms=1.0, p_value=1e-9, test="line",
                        noise_rms=0.5, period=per)
        return StructureResult(tests=[t], unexplained=[u], alpha=0.01, n_tests=1,
                               noise_floor=np.zeros(3), block_length=8, rule="")

    class Eobs:   # speeds that put the line below Nyquist: 0.05 rad/s / 0.013 rad ~ 4 Hz < 125 Hz
        qd = np.full((100, 3), 0.05)
        fs = e.fs
        obs = type("O", (), {"settings": {"qd_threshold": [0.001] * 3}})()

    named = name_flags(structure(), Eobs, gear_ratios=gear_ratios_of(e))[0]
    assert named.mechanism == "motor_ripple" and named.harmonic == 3 and named.gear_ratio == 160
    assert "3rd harmonic of motor 1" in named.text
    unknown = name_flags(structure(), Eobs, gear_ratios=None)[0]
    assert unknown.mechanism == "position_ripple" and "gear ratio unknown" in unknown.text
