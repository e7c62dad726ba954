"""The files a run reads, named as its messages name them: what no output of the run may replace.

Shared by the command line (`dynid.reports.terminal`, from its options) and the Python API
(`dynid.run`, `dynid.report`, `dynid.demo`, from their arguments), so that `dynid.run(...,
csv="run.csv")` refuses to destroy the recording `run.csv` exactly as `dynid identify run.csv
--csv run.csv` does.
"""
from __future__ import annotations

import os

from dynid.dynamics.robot_file import bundled_path, is_bundled_name
from dynid.errors import InputError
from dynid.outputs import check_output_formats, check_outputs, referenced_files

__all__ = ["input_files", "check_python_outputs"]


def _paths(value):
    """The file names in `value`: a path, or a list of paths and other things (Experiments,
    arrays), whose non-paths are not files."""
    items = value if isinstance(value, (list, tuple)) else [value]
    return [os.fspath(v) for v in items if isinstance(v, (str, os.PathLike))]


def input_files(data=None, *, robot=None, robot_what="the --robot file", option="--{}", **named):
    """`(what, path)` of every input file: the data, the robot file, the files named in `named`
    (validation=, model=, unloaded=, payload=, labelled with `option`), and the files an
    experiment description (TOML) or robot file reads.

    Parameters
    ----------
    data : path, or list of them, optional
        The recordings (an Experiment is not a file: skipped).
    robot : Robot, str or path, optional
        A bundled name stands for the package's own file, which no output may replace.
    robot_what : str
        How the messages name the robot file.
    option : str
        How an option's name is shown: `"--{}"` (command line) or `"{}="` (Python).
    **named
        Other inputs by option name (`validation`, `model`, `unloaded`, `payload`).
    """
    out = [("the data file", p) for p in _paths(data)]
    for opt, value in named.items():
        out += [(f"the {option.format(opt)} file", p) for p in _paths(value)]
    if isinstance(robot, (str, os.PathLike)) and os.fspath(robot):
        robot = os.fspath(robot)
        if is_bundled_name(robot):
            out.append((f"the bundled robot {robot}'s file", str(bundled_path(robot))))
        else:
            out.append((robot_what, robot))
    for _what, p in list(out):
        for key, ref in referenced_files(p):
            out.append((f"the file {p} reads ({key} = {os.path.basename(ref)!r})", ref))
            if "\0" in ref:
                raise InputError(f"{p}: {key} = {os.path.basename(ref)!r} contains a NUL byte, which no "
                                 f"file name can; fix '{key}' in {p}")
    return out


def check_python_outputs(outputs, data=None, robot=None, **named) -> None:
    """Refuse, before any work, the outputs of a Python call (`(label, path)`, label such as
    `"csv="`) that would destroy one of its inputs or each other, or that cannot be written
    (`dynid.outputs.check_outputs`), or that are named as another output's format."""
    outputs = [(label, path) for label, path in outputs if path is not None]
    if not outputs:
        return
    inputs = input_files(data, robot=robot, robot_what="the robot file", option="{}=", **named)
    check_outputs(outputs, inputs)
    check_output_formats(outputs)
