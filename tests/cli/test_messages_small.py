"""Small bad-input messages found from outside: each names the file or option and what to do."""
import numpy as np
import pandas as pd
import pytest

import dynid
from dynid.analysis.data.experiment import load_experiment
from dynid.analysis.estimators.maximum_likelihood import maximum_likelihood, robot_model
from dynid.analysis.fleet.catalogue import read_catalogue
from dynid.dynamics.robot_file import load_robot
from dynid.errors import DataError, InputError, RobotFileError
from dynid.ranges import check_range


def test_empty_fleet_catalogue(tmp_path):
    p = tmp_path / "cat.csv"
    p.write_text("")
    with pytest.raises(InputError, match=r"cat\.csv: the fleet catalogue is empty; write a header line"):
        read_catalogue(p)


def test_fleet_temperature_out_of_range_is_a_number(tmp_path):
    p = tmp_path / "cat.csv"
    p.write_text("robot_id,timestamp,path,robot,temperature\nr1,2026-01-01T00:00:00Z,a.csv,tx40,-500\n")
    with pytest.raises(InputError, match=r"row 1: -500 is not a joint temperature") as exc:
        read_catalogue(p)
    assert "np." not in str(exc.value)


def test_max_effects_range_starts_at_one():
    with pytest.raises(InputError, match=r"--max-effects"):
        check_range("max_effects", 0)
    assert check_range("max_effects", 1) == 1


def test_robot_toml_names_its_missing_urdf(tmp_path):
    (tmp_path / "arm.toml").write_text('name = "arm"\nurdf = "missing.urdf"\n')
    with pytest.raises(RobotFileError, match=r"arm\.toml: urdf = 'missing\.urdf': no such file"):
        load_robot(tmp_path / "arm.toml")


def test_comment_or_json_above_the_header(tmp_path):
    """A comment line above the header, or JSON saved as .csv, is named as such."""
    p = tmp_path / "c.csv"
    p.write_text("# exported by X\nt,q1,tau1\n0,0,0\n0.001,0,0\n")
    with pytest.raises(DataError, match=r"c\.csv: the first line, '# exported by X', is a comment"):
        load_experiment(p)
    p.write_text('{\n"method": "IDIM",\n"robot": "tx40"\n}\n')
    with pytest.raises(DataError, match=r"looks like JSON"):
        load_experiment(p)


def test_float32_time_stamps_are_named(tmp_path):
    """Time stamps 1e6 s from 0 in float32 repeat: the message says why (their digits), not "sort the rows"."""
    t = np.arange(2000) / 1000.0
    q = 0.3 * np.sin(t)[:, None] * np.ones((1, 2))
    np.savez(tmp_path / "t32.npz", t=(t + 1e6).astype(np.float32), q=q, tau=q)
    with pytest.raises(DataError, match=r"too few digits .*float32") as exc:
        load_experiment(tmp_path / "t32.npz")
    assert "sort the rows" not in str(exc.value)
    t32 = (1.7e9 + t).astype(np.float32)                # epoch seconds in float32, through a CSV
    pd.DataFrame({"t": t32, "q1": q[:, 0], "q2": q[:, 1], "tau1": q[:, 0], "tau2": q[:, 1]}).to_csv(
        tmp_path / "e32.csv", index=False)
    with pytest.raises(DataError, match=r"does not advance in 1999 of its 1999 steps.*too few digits"):
        load_experiment(tmp_path / "e32.csv")
    t64 = 1.7e9 + t                                     # float64 epoch seconds: a repeat is a repeat
    t64[100] = t64[99]
    np.savez(tmp_path / "t64.npz", t=t64, q=q, tau=q)
    with pytest.raises(DataError, match=r"sort the rows") as exc:
        load_experiment(tmp_path / "t64.npz")
    assert "float32 values" not in str(exc.value)


def test_ml_refuses_data_not_periodic_at_f0():
    """ML's latent trajectory is a Fourier series of f0: at the wrong f0 it left 70 % of the torque
    unexplained and exited 0; now the recording is refused, naming --f0."""
    robot = load_robot("planar2")
    rec = dynid.simulate(robot, 6.0, seed=4, f0=0.5, harmonics=3)
    e = rec.experiment
    with pytest.raises(InputError, match=r"f0 = 0.2 Hz leave .* does not describe the recording.*--f0"):
        maximum_likelihood(e.t, e.q, e.tau, robot_model(robot), f0=0.2, n_harmonics=3)
    r = maximum_likelihood(e.t, e.q, e.tau, robot_model(robot), f0=0.5, n_harmonics=3)
    assert not any("unexplained" in n for n in r.notices)


def test_simulated_noise_has_an_upper_bound():
    """--noise-tau 1e30 wrote a recording that identify then refused: refused at once."""
    with pytest.raises(InputError, match=r"1e\+30 \(--noise-tau\) is out of range"):
        dynid.simulate(load_robot("planar2"), 1.0, noise_tau=1e30)


@pytest.mark.parametrize("kw, match", [(dict(seed=-1), r"--seed"), (dict(f0=1000.0), r"too high for the controller rate"),
                                       (dict(gain_update="every2"), r"--gain-update")])
def test_python_api_options_named(kw, match):
    robot = load_robot("planar2")
    with pytest.raises(InputError, match=match):
        if "gain_update" in kw:
            dynid.Settings(method="didim", **kw)
        else:
            dynid.simulate(robot, 2.0, **kw)


def test_holdout_split_names_what_it_needs():
    with pytest.raises(InputError, match="must be an Experiment"):
        dynid.holdout_split("x.csv", 1.0)
    e = dynid.simulate(load_robot("planar2"), 2.0).experiment
    with pytest.raises(InputError, match="leaves nothing to identify"):
        dynid.holdout_split(e, e.duration)


def test_identify_refuses_an_option_of_another_method():
    """identify(exp, robot, f0=...) ran IDIM and ignored f0; a Settings' method is kept unless
    method= is given."""
    rec = dynid.simulate(load_robot("planar2"), 4.0, seed=1)
    for kw in (dict(f0=0.1), dict(max_iter=5), dict(didim_start="idim")):
        with pytest.raises(InputError, match=r"is an option of (ml|didim), not of method 'idim'"):
            dynid.identify(rec.experiment, rec.robot, **kw)
    r = dynid.identify(rec.experiment, rec.robot, settings=dynid.Settings(method="didim"), method="idim")
    assert r.method == "IDIM"


def test_report_refuses_options_it_would_ignore(tmp_path):
    rec = dynid.simulate(load_robot("planar2"), 4.0, seed=1)
    with pytest.raises(InputError, match=r"json= is an output of the command line"):
        dynid.report(rec.experiment, rec.robot, tmp_path / "r.html", json=tmp_path / "x.json")
    with pytest.raises(InputError, match=r"method='didim': the full report is IDIM's"):
        dynid.report(rec.experiment, rec.robot, tmp_path / "r.html", method="didim")
    assert not (tmp_path / "r.html").exists()
