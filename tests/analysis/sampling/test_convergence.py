"""The sampler's memory guard (dynid.analysis.sampling.convergence.check_chain_memory)."""
import pytest

from dynid.analysis.sampling import convergence as cv
from dynid.errors import InputError


def test_an_ensemble_too_large_for_memory_is_refused(monkeypatch):
    """--walkers 100000 over 11 parameters wanted ~47 GiB and the process was killed: refused first."""
    monkeypatch.setattr(cv, "_available_memory", lambda: 8 * 2**30)
    with pytest.raises(InputError, match=r"walkers = 100000 \(--walkers\).*GiB"):
        cv.check_chain_memory(2048, 100_000, 11)
    cv.check_chain_memory(2048, 64, 11)                  # the default ensemble: a few MiB
    assert cv.chain_memory_bytes(2048, 64, 11) < 2**25
