"""dynid's numba kernels cache outside the package (dynid.numba_cache): `pip uninstall`
must not leave a folder of cache files that shadows a later install."""
import os

import pytest
from numba.core import caching, config

import dynid
import dynid.analysis
import dynid.dynamics
import dynid.reports
from dynid.analysis.sampling import draws
from dynid.dynamics import _kernels, simulation
from dynid.numba_cache import DynidCacheLocator

FOLDERS = [os.path.join(os.path.dirname(os.path.abspath(m.__file__)), "")
           for m in (dynid, dynid.dynamics, dynid.analysis, dynid.reports)]


@pytest.mark.skipif(bool(config.CACHE_DIR), reason="NUMBA_CACHE_DIR decides the cache folder")
def test_kernels_cache_outside_the_package():
    kernel = simulation._closed_loop.py_func
    if caching.UserWideCacheLocator.from_function(kernel, simulation.__file__) is None:
        pytest.skip("numba's user-wide cache folder cannot be written here")
    for k in (simulation._closed_loop, _kernels.joint_transforms, draws._regenerate):
        path = os.path.abspath(k._cache._cache_path)
        assert not any(path.startswith(f) for f in FOLDERS), path


def test_other_packages_keep_numbas_order(tmp_path):
    src = tmp_path / "mine.py"
    src.write_text("def f():\n    return 1\n")
    ns = {}
    exec(compile(src.read_text(), str(src), "exec"), ns)
    assert DynidCacheLocator.from_function(ns["f"], str(src)) is None
