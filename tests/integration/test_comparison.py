"""examples/staubli_tx40/figaroh_comparison.py on the real TX40: the mapping of FIGAROH's parameters and the counts."""
import sys
from pathlib import Path

import numpy as np
import pytest

from dynid.analysis.data.experiment import load_experiment
from dynid.analysis.estimators.idim import identify_idim
from dynid.dynamics.robot_file import load_robot
from dynid.reports.paper import DIDIM_TX40_TABLE2

TX40 = Path(__file__).resolve().parents[2] / "examples" / "staubli_tx40"
sys.path.insert(0, str(TX40))    # the comparison is the example's, beside its run.py
from figaroh_comparison import comparison_frame, comparison_section, comparison_summary


@pytest.fixture(scope="module")
def frame():
    robot = load_robot("tx40")
    res = identify_idim(load_experiment(TX40 / "experiment.toml", robot), robot)
    return res, comparison_frame(res, TX40 / "reference_results")


def test_every_source_and_parameter_is_there(frame):
    res, df = frame
    # 60 FIGAROH base parameters + dynid's Fv5, Fv6, Ia6 that FIGAROH has only in sums / not at all
    assert len(df) == 63
    assert set(DIDIM_TX40_TABLE2.names) <= set(df.index)
    assert df["fig_wls"].notna().sum() == 60 and df["fig_ess"].notna().sum() == 25
    assert df["table2"].notna().sum() == 24
    assert df["dynid_ess"].notna().sum() >= len(res.model.names)
    assert np.isnan(df.at["Iam6 (FIGAROH only)", "dynid_wls"])


def test_fv5_is_compared_with_the_sum(frame):
    res, df = frame
    i5, im = res.wls.names.index("Fv5"), res.wls.names.index("Fvm6")
    c = np.zeros(len(res.wls.names))
    c[[i5, im]] = 1.0
    assert df.at["Fv5 + Fvm6", "dynid_wls"] == pytest.approx(c @ res.wls.chi)
    assert df.at["Fv5 + Fvm6", "dynid_wls_std"] == pytest.approx(np.sqrt(c @ res.wls.cov @ c))
    assert df.at["Fv5 + Fvm6", "fig_wls"] == pytest.approx(1.854047)
    assert df.at["Fv5", "table2"] == pytest.approx(2.52)


def test_summary_and_section(frame):
    _, df = frame
    s = comparison_summary(df)
    # measured: 19 of 19 agree (README, examples/staubli_tx40/README.md)
    assert s["both_well_identified"] >= 18 and not s["disagree"]
    sec = comparison_section(df, reading=["A reading."])
    assert sec.id == "comparison" and sec.tables[0].key == "tab-comparison"
