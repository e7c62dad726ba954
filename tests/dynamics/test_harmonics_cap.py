"""The number of harmonics of a designed Fourier trajectory is capped alike in Python and on the
command line (bad-input hunt, B2: `dynid.excite('planar2', 0.1, 10**6)` raised MemoryError)."""
import pytest

import dynid
from dynid.dynamics.excitation import design_excitation
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.trajectories import MAX_HARMONICS, check_harmonics, random_fourier_trajectory
from dynid.errors import InputError
from dynid.reports import cli_options


def test_the_cap_is_the_command_lines():
    # one limit: the parser keeps its own copy (it starts without the numerical modules)
    assert MAX_HARMONICS == cli_options.MAX_HARMONICS == 1000


def test_check_harmonics_accepts_the_cap_and_refuses_beyond():
    assert check_harmonics(MAX_HARMONICS) == MAX_HARMONICS
    assert check_harmonics(float(MAX_HARMONICS)) == MAX_HARMONICS
    for n in (MAX_HARMONICS + 1, 10**6, 10**30):
        with pytest.raises(InputError, match=rf"--harmonics\) {n} is more than {MAX_HARMONICS}"):
            check_harmonics(n)


@pytest.mark.parametrize("n", [MAX_HARMONICS + 1, 10**6])
def test_excite_refuses_too_many_harmonics_before_any_work(n):
    with pytest.raises(InputError, match=rf"n_harmonics \(harmonics=, --harmonics\) {n} is more than 1000"):
        dynid.excite("planar2", 0.1, n)
    with pytest.raises(InputError, match="is more than 1000"):
        design_excitation(load_robot("planar2"), 0.1, n)
    with pytest.raises(InputError, match="is more than 1000"):
        random_fourier_trajectory(load_robot("planar2"), 0.1, n, 0)
