"""dynid: identify the dynamic model of a robot arm from measured data, and say how far to trust it."""
from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("dynid")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

from dynid.errors import ConvergenceError, DataError, DynidError, IdentificationError, InputError, RobotFileError
