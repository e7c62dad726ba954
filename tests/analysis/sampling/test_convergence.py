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


def test_a_container_limit_counts(monkeypatch, tmp_path):
    """Inside a container the host's MemAvailable overstates the room: the cgroup's limit decides."""
    limit, usage = tmp_path / "memory.max", tmp_path / "memory.current"
    limit.write_text(str(2 * 2**30))
    usage.write_text(str(2**30))
    real_open = open

    def fake_open(path, *a, **k):
        return real_open({"/sys/fs/cgroup/memory.max": limit, "/sys/fs/cgroup/memory.current": usage}.get(path, path),
                         *a, **k)
    monkeypatch.setattr("builtins.open", fake_open)
    assert cv._cgroup_room() == 2**30
    assert cv._available_memory() <= 2**30
