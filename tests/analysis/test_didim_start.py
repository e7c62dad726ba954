"""dynid.run's DIDIM start: IDIM's estimate (default) or the robot file's a-priori values (issue 26)."""
from __future__ import annotations

import pytest

import dynid.analysis.run as run_module
from dynid.analysis.run import Settings
from dynid.dynamics.robot_file import load_robot
from dynid.errors import InputError


class _Stop(Exception):
    pass


@pytest.fixture
def captured(monkeypatch):
    seen = {}

    def fake_didim(exp, robot, **kwargs):
        seen.update(kwargs)
        raise _Stop

    monkeypatch.setattr(run_module, "identify_didim", fake_didim)
    monkeypatch.setattr(run_module, "identify_gains", lambda exp, robot: type(
        "G", (), {"controller": lambda self, r: r.controller})())
    return seen


def _exp():
    return type("Exp", (), {"qr": object(), "source": "log.csv"})()


def test_apriori_start_uses_the_robot_files_values_and_the_option_reaches_didim(captured):
    robot = load_robot("tx40")
    settings = Settings(method="didim", gains="identify", didim_start="apriori", uncertainty="hac")
    with pytest.raises(_Stop):
        run_module._didim(_exp(), robot, settings, None)
    assert captured["chi0"] == dict(robot.apriori) and captured["chi0"]
    assert captured["uncertainty"] == "hac" and captured["update_gains"] is False


def test_apriori_start_without_apriori_values_is_refused(captured):
    robot = load_robot("tx40")
    robot.apriori = {}
    with pytest.raises(InputError, match="no \\[apriori\\] values"):
        run_module._didim(_exp(), robot, Settings(method="didim", didim_start="apriori"), None)


def test_an_unknown_start_is_refused_before_any_work():
    with pytest.raises(InputError, match="didim_start must be 'idim' or 'apriori'"):
        run_module.check_identify(Settings(method="didim", didim_start="zero"))
