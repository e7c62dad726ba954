"""Small bad-input messages found from outside: each names the file or option and what to do."""
import pytest

from dynid.analysis.fleet.catalogue import read_catalogue
from dynid.dynamics.robot_file import load_robot
from dynid.errors import InputError, RobotFileError
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
