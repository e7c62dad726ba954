"""Where numba keeps dynid's compiled kernels: the user's cache folder, not the package's.

numba's `cache=True` writes `__pycache__/*.nbi` and `*.nbc` beside the source. pip's
record of an installed package does not list them, so `pip uninstall dynid` leaves
`site-packages/dynid/...` behind holding only those files; Python then imports that
leftover folder as an empty namespace package ahead of a later editable install, and
`import dynid.reports.cli` fails. `install` sends the cache of dynid's own kernels to
numba's user-wide folder instead (`~/.cache/numba` on Linux; one subfolder per source
folder, so two installs never share an entry, and an entry is used only while its
source file's time stamp and size match).

`NUMBA_CACHE_DIR` still decides when set (numba's first locator), and so does
`NUMBA_CACHE_LOCATOR_CLASSES`. Where the user-wide folder cannot be written, numba's own
order applies (beside the source, as before). Other packages' kernels are not touched.
"""
from __future__ import annotations

import importlib.util
import os

from numba.core import caching, config

__all__ = ["install"]

_SUBPACKAGES = ("dynid.dynamics", "dynid.analysis", "dynid.reports")


def _locator(name):
    """numba's locator class `name` (numba < 0.62 spells them with a leading underscore), or None."""
    return getattr(caching, name, None) or getattr(caching, "_" + name, None)


_UserWide, _InTree = _locator("UserWideCacheLocator"), _locator("InTreeCacheLocator")


def _package_folders() -> tuple[str, ...]:
    folders = []
    for name in _SUBPACKAGES:
        spec = importlib.util.find_spec(name)
        for path in (spec.submodule_search_locations or []) if spec is not None else []:
            folders.append(os.path.join(os.path.abspath(path), ""))
    return tuple(folders)


class DynidCacheLocator(_UserWide or object):
    """numba's user-wide locator, for the source files of dynid's packages only."""

    folders: tuple[str, ...] = ()

    @classmethod
    def from_function(cls, py_func, py_file):
        if _UserWide is None or config.CACHE_DIR or not os.path.abspath(py_file).startswith(cls.folders):
            return None
        return super().from_function(py_func, py_file)


def install() -> None:
    """Put `DynidCacheLocator` ahead of numba's in-tree locator (once per process).

    Call before the first `@njit(cache=True)` of a module runs: numba picks a function's
    cache locator when it decorates it. A numba without the locator list this relies on
    keeps its own behaviour.
    """
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    classes = getattr(impl, "_locator_classes", None)
    if _UserWide is None or not isinstance(classes, list) or DynidCacheLocator in classes:
        return
    DynidCacheLocator.folders = _package_folders()
    if not DynidCacheLocator.folders:
        return
    at = classes.index(_InTree) if _InTree in classes else 0
    classes.insert(at, DynidCacheLocator)
