"""Fast checks of the diagnosis' building blocks on synthetic arrays."""
import numpy as np
from scipy import signal

from dynid.analysis.diagnosis.structure import WHITE_MIN, whiteness


def test_whiteness_separates_white_from_prefiltered_torque():
    rng = np.random.default_rng(0)
    t = np.arange(20000) / 5000.0
    smooth = 50.0 * np.sin(2 * np.pi * 0.5 * t)[:, None]
    tau = smooth + 0.2 * rng.standard_normal((t.size, 3))
    r = whiteness(tau)
    assert np.all(np.abs(r - 20.0 / 6.0) < 0.3), r
    sos = signal.butter(4, 100.0, fs=5000.0, output="sos")
    rf = whiteness(signal.sosfiltfilt(sos, tau, axis=0))
    assert np.all(rf < 0.1 * WHITE_MIN), rf
