"""Errors dynid raises for bad input.

Every message names the file, column or row at fault and says what to do,
so the command-line front end can print it as is, without a traceback.
"""
import re
from importlib import metadata


class DynidError(Exception):
    """Base class of every error dynid raises on purpose."""

    exit_code = 1


class InputError(DynidError, ValueError):
    """The user's data or robot description cannot be used as given.

    The CLI maps it to exit code 2 ("bad input").
    """

    exit_code = 2


class RobotFileError(InputError):
    """A robot description (TOML or URDF) is unreadable or inconsistent."""


class DataError(InputError):
    """An experiment file is unreadable or inconsistent."""


class OutputError(InputError, OSError):
    """An output file cannot be written (missing folder, full disk, no permission ...).

    It is an `OSError` too, so code that guards file writes keeps working.
    """


class IdentificationError(DynidError):
    """The data cannot identify the model (rank deficiency, too few samples...)."""

    exit_code = 2


class ConvergenceError(DynidError):
    """An iterative method did not converge."""

    exit_code = 3


def did_you_mean(name: str, known) -> str:
    """` (did you mean 'x'?)` when `name` is a near miss of one of `known`, else ``''``.

    Returns
    -------
    str
        The phrase to append to an error message naming `name`.

    Examples
    --------
    >>> did_you_mean("holdot", ["holdout", "seed"])
    " (did you mean 'holdout'?)"
    """
    import difflib
    close = difflib.get_close_matches(str(name), [str(k) for k in known], n=1, cutoff=0.7)
    return f" (did you mean {close[0]!r}?)" if close else ""


def install_hint(extra: str) -> str:
    """The pip command that installs the optional packages of dynid's extra `extra`.

    The packages as the installed metadata lists them (pyproject.toml's
    ``[project.optional-dependencies]``): the command works however dynid was installed,
    where ``pip install "dynid[extra]"`` needs dynid on a package index.

    Returns
    -------
    str
        For example ``pip install "cvxpy>=1.4" "clarabel>=0.6"``.
    """
    try:
        requirements = metadata.requires("dynid") or []
    except metadata.PackageNotFoundError:      # run from a source tree that is not installed
        requirements = []
    wanted = re.compile(r"""extra\s*==\s*["']""" + re.escape(extra) + """["']""")
    packages = [spec.strip() for spec, _, marker in (r.partition(";") for r in requirements)
                if wanted.search(marker)]
    if not packages:
        return f'pip install ".[{extra}]" in dynid\'s source folder'
    return "pip install " + " ".join(f'"{p}"' for p in packages)

