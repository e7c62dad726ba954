"""The command line's terminal and files: printing the summaries, checking every input and
output path before any work, and writing the outputs all or none.
"""
from __future__ import annotations

import filecmp
import os
import sys

from dynid.errors import InputError
from dynid.outputs import check_output_formats, check_outputs, same_file, write_all
from dynid.reports.input_files import input_files
from dynid.reports.progress import clean_text

EXIT_OK, EXIT_INPUT = 0, 2

def commit_outputs(outputs, say):
    """Write `(path, text)` pairs all or none (dynid.outputs.write_all)."""
    write_all(outputs, say)


OUTPUT_OPTIONS = ("json", "report", "csv", "out", "urdf", "mjcf")
def _input_files(args):
    """`(what, path)` of every input file the options name (data, validation, robot file)."""
    named = {opt: getattr(args, opt, None) for opt in ("validation", "model", "unloaded", "payload")}
    return input_files(getattr(args, "data", None), robot=getattr(args, "robot", None) or None,
                       robot_what="the robot file" if args.command == "robot" else "the --robot file",
                       **{opt: v for opt, v in named.items() if v})


def check_input_paths(args):
    """Before any computation: input names without NUL bytes, no recording given twice."""
    inputs = _input_files(args)
    for what, p in inputs:
        if "\0" in p:
            raise InputError(f"{what} {p!r}: the name contains a NUL byte, which no file name can; "
                             f"check how the command line was built")
    for what, p in inputs:
        # report reads its --payload recordings after every method has run (payload reads them first)
        if args.command == "report" and what == "the --payload file" and not os.path.exists(p):
            raise InputError(f"{p}: file not found ({what}); check the path")
    data = [p for what, p in inputs if what == "the data file"]
    for i, p in enumerate(data):
        for q in data[:i]:
            how = _one_recording(p, q)
            if how:
                extra = f" (as {q} and {p}{', a copy' if how == 'copy' else ''})" if p != q else ""
                raise InputError(f"the data file {p} is given twice{extra}: the same recording counted "
                                 f"twice doubles its weight and proves nothing; give each recording once")
    others = (("validation", "validating on the identification data says nothing about the model; give "
                             "another recording, or --holdout SECONDS to hold out the end of this one"),
              ("unloaded", "the recordings without the payload must be other recordings than the loaded "
                           "ones; give the recording made without the payload"),
              ("payload", "the payload recordings must be other recordings than the identification ones; "
                          "give the recording made with the payload"))
    for opt, why in others:
        value = getattr(args, opt, None)
        for o in [value] if isinstance(value, (str, os.PathLike)) else (value or []):
            for p in data:
                how = _one_recording(o, p)
                if how:
                    raise InputError(f"--{opt} {o} is {'a copy of' if how == 'copy' else 'the same file as'} "
                                     f"the data file {p}: {why}")


def _one_recording(a, b):
    """`"same"` when paths `a` and `b` are one file, `"copy"` when two data files hold the same
    bytes, else "". Experiment descriptions (TOML) are not compared by their bytes: two equal
    ones in two folders read two recordings, and two descriptions may read different parts of
    one file."""
    if same_file(a, b):
        return "same"
    if any(str(p).lower().endswith(".toml") for p in (a, b)):
        return ""
    try:
        if os.path.isfile(a) and os.path.isfile(b) and os.path.getsize(a) == os.path.getsize(b) \
                and filecmp.cmp(a, b, shallow=False):
            return "copy"
    except OSError:
        pass
    return ""


def check_output_paths(args):
    """Before any computation: every output's folder exists and is writable; '-' only for --json;
    no output is an input or another output; names are valid file names (dynid.outputs.check_outputs);
    no output is named as another output's format (`--mjcf arm.urdf`)."""
    check_input_paths(args)
    # an output that would destroy an input says so first: that is the graver mistake
    outputs = [(f"--{opt}", getattr(args, opt, None)) for opt in OUTPUT_OPTIONS]
    check_outputs(outputs, _input_files(args))
    if getattr(args, "command", None) != "fleet":    # the fleet's inputs are its catalogue's: dynid.fleet.run
        check_output_formats(outputs)
    _check_stdout(args)


def _check_stdout(args):
    """--json - needs a standard output to write to (not closed with >&-)."""
    if getattr(args, "json", None) != "-":
        return
    ok = sys.stdout is not None and not getattr(sys.stdout, "closed", False)
    if ok:
        try:
            fd = sys.stdout.fileno()
        except (AttributeError, ValueError, OSError):     # a Python stream without a descriptor
            fd = None
        if fd is not None:
            try:
                os.fstat(fd)
            except OSError:                               # descriptor 1 closed
                ok = False
    if not ok:
        raise InputError("--json -: cannot write the JSON to stdout: standard output is closed; "
                         "give a file name (--json out.json) or leave stdout open")


def stdout_failed(args):
    """A BrokenPipe while writing: the exit code (2 if the JSON went to stdout, else 0)."""
    try:                       # further writes (and the flush at exit) go nowhere
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass
    if getattr(args, "json", None) == "-":
        try:
            print(f"dynid {args.command}: error: cannot write the JSON to stdout: the pipe was closed "
                  f"before it was written (broken pipe); the reader of --json - must read to the end, "
                  f"or give --json a file name", file=sys.stderr, flush=True)
        except (OSError, ValueError, AttributeError):
            pass
        return EXIT_INPUT
    try:
        sys.stderr.close()
    except (OSError, ValueError, AttributeError):
        pass
    return EXIT_OK


def show_clean(args, *texts):
    """`_show` with control characters escaped (names read from files reach summaries)."""
    show(args, *(clean_text(t) if t else t for t in texts))


def show(args, *texts):
    """Print human-readable summaries: on stdout, or on stderr when stdout carries the JSON."""
    if args.quiet:
        return
    stream = sys.stderr if getattr(args, "json", None) == "-" else sys.stdout
    print("\n\n".join(t for t in texts if t), file=stream)

