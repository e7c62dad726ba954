

def test_a_recording_too_short_for_the_filter_names_its_file(tmp_path):
    """The bandwidth estimate's length check knows arrays only: the error now names the file."""
    import pytest as _pytest

    import dynid
    from dynid.errors import DataError
    p = tmp_path / "short.csv"
    p.write_text("t,q1,q2,tau1,tau2\n0,0,0,1,1\n0.01,0.1,0.1,1,1\n")
    robot = dynid.load_robot("planar2")
    with _pytest.raises(DataError, match=r"short\.csv: q has 2 samples but at least 17"):
        dynid.identify(dynid.load_experiment(p, robot), robot)
