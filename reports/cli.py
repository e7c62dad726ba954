"""The `dynid` command line: it parses the options (reports.cli_options), calls the
orchestrator (dynid.analysis.run through dynid.reports.pipeline) and prints
(reports.terminal). Every command is a function of the dynid package.

Exit codes: 0 ok; 1 internal error (a bug: please report it); 2 bad input
(data, robot file, options); 3 an iterative method did not converge;
130 interrupted. Errors are printed as one message, never a traceback
(`--debug` shows it).

The numerical modules are imported inside the commands, never at the top: `dynid --help`
answers at once and the SIGTERM handler of `main` is in place before those imports
(several seconds), so an interrupted run still leaves no partial output.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import os
import signal
import sys

from dynid.errors import DynidError, InputError
from dynid.pages import small_pages
from dynid.progress import LOGGER
from dynid.reports.cli_options import build_parser, parse_command_line
from dynid.reports.progress import Reporter, clean_text
from dynid.reports.terminal import check_output_paths, commit_outputs, show, show_clean, stdout_failed
from dynid.threads import single_blas_thread

__all__ = ["main", "build_parser", "COMMANDS", "commit_outputs", "settings_of"]

EXIT_OK, EXIT_BUG, EXIT_INPUT, EXIT_NOT_CONVERGED, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


def settings_of(args):
    """The orchestrator's Settings of the parsed options (same names, `_` for `-`)."""
    from dynid.analysis.run import Settings  # heavy: see the module docstring
    names = {f.name for f in dataclasses.fields(Settings)}
    return Settings(**{k: v for k, v in vars(args).items() if k in names and v is not None})


def _robot(args, settings=None):
    """The robot of --robot (--base, --tip), with the options that depend on it checked."""
    from dynid.analysis import run as steps
    robot = steps.as_robot(args.robot, base=getattr(args, "base", None), tip=getattr(args, "tip", None))
    steps.check_robot_options(settings or settings_of(args), robot)
    return robot


def cmd_robot(args, say):
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import bundled_robots
    from dynid.provenance import dumps_json
    from dynid.reports.robot_text import robot_doc, robot_text
    if args.list or not args.robot:
        print("bundled robots: " + ", ".join(bundled_robots()))
        return EXIT_OK
    robot = _robot(args)
    bp = base_parameters(robot)
    show(args, clean_text(robot_text(robot, bp)))
    if args.json:
        commit_outputs([(args.json, dumps_json(robot_doc(robot, bp)))], say)
    return EXIT_OK


def _unconverged_outputs(args, csv_holds):
    """Which outputs of a run that did not converge say so (a CSV has no field for it)."""
    said = [name for name, given in (("the JSON", getattr(args, "json", None)),
                                     ("the report", getattr(args, "report", None))) if given]
    if said:
        text = " and ".join(said) + (" says so" if len(said) == 1 else " say so")
    else:
        text = "its summary says so" if not getattr(args, "quiet", False) else "no output file says so (--json would)"
    if getattr(args, "csv", None):
        text += f"; the CSV holds {csv_holds}, with no mark of it"
    return text


def cmd_identify(args, say):
    from dynid.reports import pipeline
    settings = settings_of(args)
    robot = _robot(args, settings)
    say(f"robot '{robot.name}' ({robot.n_joints} joints)")
    ident = pipeline.run(args.data, robot, settings, say=say, write=False)
    show_clean(args, *ident.summaries())
    commit_outputs(pipeline.outputs(ident), say)
    if ident.method == "didim" and not ident.result.converged:
        where = _unconverged_outputs(args, "the last step's values")
        print(f"dynid identify: DIDIM did not converge ({ident.result.stop_reason}); {where}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def cmd_simulate(args, say):
    from dynid.analysis.data.synthetic import missing_effects, simulate
    from dynid.provenance import dumps_json
    _csv_out(args.out)
    robot = _robot(args)
    say(f"robot '{robot.name}' ({robot.n_joints} joints): simulating {args.duration:g} s")
    # before the minutes of simulation, the rest after (none for a robot that cannot be simulated)
    said = missing_effects(robot) if getattr(robot, "apriori", None) and robot.controller is not None else []
    for notice in said:
        say(f"notice: {notice}")
    with say.progress(f"closed-loop simulation ({args.duration:g} s)") as bar:
        sim = simulate(robot, args.duration, seed=args.seed, f0=args.f0, harmonics=args.harmonics,
                       noise_q=args.noise_q, noise_tau=args.noise_tau, payload=args.carried_payload,
                       progress=bar.update)
    for notice in sim.notices:
        if notice not in said:
            say(f"notice: {notice}")
    outputs = [(args.out, sim.to_csv())]
    if args.json:
        doc = sim.to_dict()
        doc["csv"] = args.out
        outputs.append((args.json, dumps_json(doc)))
    commit_outputs(outputs, say)
    return EXIT_OK


def _csv_out(path):
    """--out of simulate and excite is written as CSV: another extension would hold CSV text under
    a name the loaders read as another format (x.parquet read back failed)."""
    if path and os.path.splitext(str(path))[1].lower() != ".csv":
        raise InputError(f"--out {path}: the file is written as CSV; give a path ending in .csv")


def cmd_sample(args, say):
    from dynid.analysis import further
    from dynid.analysis import run as steps
    from dynid.reports import pipeline
    settings = settings_of(args)
    if settings.physical:
        if settings.which != "base":
            raise InputError("--physical samples the base parameters: add --which base")
        from dynid.analysis.estimators.physical import require_cvxpy
        require_cvxpy()
    robot = _robot(args, settings)
    experiments, _ = steps.load_data(args.data, robot, settings, say)
    with say.progress("regressor and decimation") as bar:
        # the unconstrained IDIM: --physical is the posterior's support, not a PC refit
        result = steps.identify_step(experiments, robot, settings.replace(physical=False), progress=bar.update)
    say(f"sampling the posterior of the {args.which} parameters")
    post = further.posterior_step(result, settings, say, robot=robot)
    verdict = steps.verdict_of(result, robot=robot)
    show(args, verdict.summary())
    show_clean(args, post.summary())
    commit_outputs(pipeline.sample_outputs(post, result, robot, experiments[0], verdict, settings), say)
    if not post.converged and not args.allow_unconverged:
        where = _unconverged_outputs(args, "the draws so far")
        print(f"dynid sample: the chains did not converge ({post.reason}); {where}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def cmd_excite(args, say):
    from dynid.dynamics.excitation import design_excitation
    from dynid.reports.pipeline import excitation_outputs, excitation_rate
    _csv_out(args.out)
    robot = _robot(args)
    fs = excitation_rate(robot, args.f0, args.harmonics, args.fs, args.periods)
    if not args.out and not args.json and not args.report:
        say("note: no --out, --json or --report given; only the summary is printed")
    with say.progress(f"excitation design ({args.starts} starts)") as bar:
        res = design_excitation(robot, args.f0, args.harmonics, n_starts=args.starts,
                                criterion=args.criterion, margin=args.margin, rng=args.seed,
                                progress=bar.update)
    show_clean(args, res.summary())
    commit_outputs(excitation_outputs(res, robot, fs, args.periods, out=args.out, json=args.json,
                                      report=args.report), say)
    if not res.feasible:
        print("dynid excite: no optimised trajectory respected every limit; the outputs hold the "
              "best random start (see the margins)", file=sys.stderr)
    return EXIT_OK


def cmd_diagnose(args, say):
    from dynid.reports import pipeline
    settings = settings_of(args)
    robot = _robot(args, settings)
    run = pipeline.diagnose_run(args.data, robot, settings, say=say)
    if run.verdict is not None:
        show(args, run.verdict.summary())
    show_clean(args, run.diagnosis.summary())
    commit_outputs(pipeline.diagnosis_outputs(run, settings), say)
    return EXIT_OK


def _write_full_report(args, say, out):
    from dynid.provenance import dumps_json
    show_clean(args, out.summary())
    outputs = []
    if args.report:
        outputs.append((args.report, out.html))
    if args.json:
        outputs.append((args.json, dumps_json(out.to_dict())))
    if getattr(args, "csv", None):
        outputs.append((args.csv, out.result.model.to_frame().to_csv()))
    commit_outputs(outputs, say)
    if out.problems:
        print(f"dynid {args.command}: " + "; ".join(p.rstrip(". ") for p in out.problems) + "; the outputs say so",
              file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def cmd_report(args, say):
    from dynid.reports.pipeline import report
    settings = settings_of(args)
    out = report(args.data, _robot(args, settings), settings=settings, say=say, payload=args.payload)
    return _write_full_report(args, say, out)


def cmd_demo(args, say):
    from dynid.reports.pipeline import demo
    out = demo(seed=args.seed, duration=args.duration, skip=args.skip, max_seconds=args.max_seconds,
               max_iter=args.max_iter, gain_update=args.gain_update, say=say)
    return _write_full_report(args, say, out)


#: failed recordings listed in fleet's error (all of them are in the store)
_FAILED_SHOWN = 20


def cmd_fleet(args, say):
    """dynid fleet CATALOGUE --out STORE: identify on Dask, store, monitor, report (dynid.fleet.run)."""
    from dynid.analysis.fleet.engine import check_local_workers, import_distributed
    from dynid.analysis.fleet.health import DEFAULT_BASELINE, DEFAULT_FALSE_ALARM_RATE
    from dynid.reports import fleet_run  # Dask (dynid[fleet]) on first use
    from dynid.reports.fleet_report import fleet_json
    check_local_workers(args.workers, args.scheduler)      # before Dask is imported
    import_distributed()            # without Dask, say so before announcing a cluster
    if os.path.exists(args.store) and not os.path.isdir(args.store):
        raise InputError(f"--out {args.store} is a file; the results store is a folder")
    outputs = [(opt, value) for opt, value in (("--json", args.json), ("--report", args.report))
               if value not in (None, "-")]
    for opt, value in outputs:      # the general output checks take the store for a file
        if os.path.realpath(value) == os.path.realpath(args.store):
            raise InputError(f"{opt} {value} is the --out store folder; give the {opt[2:]} file another path")
    params = [p.strip() for p in args.parameters.split(",") if p.strip()]
    if not params:
        raise InputError("--parameters: name at least one base parameter (Fv, Fc, Fv2 ...)")
    say(f"fleet: {args.catalogue} -> {args.store}"
        + (f" on {args.scheduler}" if args.scheduler else f" on a local cluster of {args.workers or os.cpu_count()} workers"))
    with say.progress("identifying") as bar:
        run = fleet_run.run(args.catalogue, args.store, scheduler=args.scheduler, workers=args.workers,
                            diagnose=args.diagnose, parameters=params,
                            false_alarm_rate=DEFAULT_FALSE_ALARM_RATE if args.false_alarm_rate is None
                            else args.false_alarm_rate,
                            n_baseline=DEFAULT_BASELINE if args.baseline is None else args.baseline,
                            report=args.report, json=None if args.json in (None, "-") else args.json,
                            progress=lambda done, total: bar.update(done / total),
                            quiet_interrupt=getattr(args, "program", False))
    # the result, as every command's summary: on stdout (stderr when stdout carries the JSON)
    show(args, "\n".join([run.summary_line()]
                          + [f"  ALARM {a.robot_id} joint {a.joint} {a.parameter}: {a.direction} of "
                             f"{100 * a.rel_size:+.1f} % since {a.onset_day} (alarm {a.alarm_day})"
                             for a in run.health.alarms]
                          + ([] if run.health.alarms else ["  " + run.health.status_line()])))
    if args.json == "-":
        # the catalogue's current rows, as the monitor and --json FILE (an unused result is not read)
        print(json.dumps(fleet_json(run, fleet_run.read_store(args.store, keys=run.keys), run.health), indent=1))
    if run.errors:              # the rest is stored and reported, but the run is not a success
        # on stderr even with --quiet: a scheduled run must say which file failed and why
        shown = "".join(f"\n  failed: {rid} {path}: {msg}" for rid, path, msg in run.errors[:_FAILED_SHOWN])
        more = (f"\n  ... and {len(run.errors) - _FAILED_SHOWN} more (all in the store)"
                if len(run.errors) > _FAILED_SHOWN else "")
        print(f"dynid fleet: error: {run.n_failed} of {run.n_computed} recordings could not be identified; "
              f"a failure of the machine (its message says the next run tries it again) is retried by the "
              f"next run; fix or remove from the catalogue the recordings refused for what they hold:{shown}{more}",
              file=sys.stderr)
        return EXIT_INPUT
    return EXIT_OK


def _floats(text, k, option):
    """k comma-separated numbers of a payload option."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != k:
        raise InputError(f"{option} {text}: give {k} comma-separated numbers")
    return vals


def _joint_numbers(text, n):
    """--gains JOINTS: 1-based joint numbers, comma-separated."""
    try:
        joints = [int(v) for v in text.split(",")]
    except ValueError:
        joints = []
    if not joints or any(not 1 <= j <= n for j in joints):
        raise InputError(f"--gains {text}: give joint numbers 1 to {n}, comma-separated (e.g. 1,2,3), "
                         f"or all; alone, --gains takes the joints the recordings' [currents] mark")
    return joints


def cmd_payload(args, say):
    """dynid payload: parse, call identify_payload / identify_drive_gains, print and write."""
    from dynid.analysis import run as steps
    from dynid.analysis.estimators.drive_gains import identify_drive_gains
    from dynid.analysis.estimators.payload import identify_payload
    from dynid.provenance import dumps_json
    from dynid.reports.payload_section import payload_html
    robot = steps.as_robot(args.robot, base=args.base, tip=args.tip)
    if args.gains is not None:
        if args.mass is None or args.unloaded is None:
            raise InputError("--gains needs --mass KG (the payload's known mass) and --unloaded FILE")
        joints = (None if args.gains == "marked" else list(range(1, robot.n_joints + 1)) if args.gains == "all"
                  else _joint_numbers(args.gains, robot.n_joints))
        com = None if args.com is None else _floats(args.com, 3, "--com")
        result = identify_drive_gains(args.unloaded, args.data, robot, mass=args.mass, com=com, joints=joints,
                                      frame=args.frame, zoh=args.zoh)
    else:
        if args.mass is not None or args.com is not None:
            raise InputError("--mass and --com are the known payload of --gains; the payload itself is "
                             "identified without them")
        box = None if args.com_box is None else (lambda v: (v[:3], v[3:]))(_floats(args.com_box, 6, "--com-box"))
        result = identify_payload(args.data, robot, model=args.model, unloaded=args.unloaded,
                                  frame=args.frame, physical=args.physical, com_box=box, zoh=args.zoh)
    outputs = []
    if args.json and args.json != "-":
        outputs.append((args.json, dumps_json(result.to_dict())))
    if args.report:
        outputs.append((args.report, payload_html(result)))
    commit_outputs(outputs, say)
    if args.json == "-":
        print(dumps_json(result.to_dict()))
    show(args, result.summary())
    return EXIT_OK


#: the subcommands; a new one (e.g. payload) adds its parser in reports.cli_options and its function here
COMMANDS = {"robot": cmd_robot, "simulate": cmd_simulate, "excite": cmd_excite, "identify": cmd_identify,
            "sample": cmd_sample, "diagnose": cmd_diagnose, "report": cmd_report, "demo": cmd_demo,
            "fleet": cmd_fleet, "payload": cmd_payload}


#: what an interruption leaves, where it is more than nothing
_INTERRUPTED = {"fleet": "the recordings finished so far are in the store, and the next run goes on from "
                         "them; no report was written"}


def _terminate(signum, frame):
    raise KeyboardInterrupt


def _leave(code):
    """Exit at once after an interruption: the exit handlers run (a Dask cluster is closed, the
    logs flushed), but not the interpreter's teardown, which collects every object the run
    made and took seconds after a DIDIM run on a loaded machine."""
    import atexit
    sys.stdout.flush()
    sys.stderr.flush()
    atexit._run_exitfuncs()
    os._exit(code)


def _progress_log(quiet):
    """Off a terminal (stderr redirected to a log, a batch job), the progress records of long
    steps (`dynid.progress`: one per 10 s) go to stderr, so a run is not silent for minutes;
    on a terminal the bars show it. Returns the function that detaches the handler, or None."""
    isatty = getattr(sys.stderr, "isatty", None)
    if quiet or sys.stderr is None or isatty is None or isatty() or LOGGER.hasHandlers():
        return None
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("progress: %(message)s"))
    level, propagate = LOGGER.level, LOGGER.propagate
    LOGGER.addHandler(handler)
    LOGGER.setLevel(logging.INFO)
    LOGGER.propagate = False

    def detach():
        LOGGER.removeHandler(handler)
        handler.close()
        LOGGER.setLevel(level)
        LOGGER.propagate = propagate
    return detach


def main(argv=None):
    parser = build_parser()
    try:
        args = parse_command_line(parser, sys.argv[1:] if argv is None else argv)
    except SystemExit as exc:           # --help raises on; a bad option is exit 2, not an exception
        if exc.code in (0, None):
            raise
        return EXIT_INPUT if exc.code == 2 else exc.code
    args.program = argv is None        # the program itself, which ends with the command
    if args.version:
        from dynid.provenance import versions
        print(f"dynid {versions().get('dynid', '?')}")
        return EXIT_OK
    if not args.command:
        parser.print_help()
        return EXIT_INPUT
    signal.signal(signal.SIGTERM, _terminate)
    say = Reporter(quiet=args.quiet)
    progress_log = _progress_log(args.quiet)
    try:
        check_output_paths(args)
        # tall-thin problems: a 2nd BLAS thread only spins (dynid.threads); fresh large arrays
        # stall on huge-page compaction under load (dynid.pages)
        with single_blas_thread(), small_pages():
            return COMMANDS[args.command](args, say)
    except BrokenPipeError:           # output piped into head & co. (an error for --json -)
        return stdout_failed(args)
    except KeyboardInterrupt:
        print(f"dynid: interrupted; {_INTERRUPTED.get(args.command, 'no partial output was written')}",
              file=sys.stderr)
        if argv is None:              # the program itself, not a caller's main([...]): stop now
            _leave(EXIT_INTERRUPTED)
        return EXIT_INTERRUPTED
    except DynidError as exc:
        if args.debug:
            raise
        print(clean_text(f"dynid {args.command}: error: {exc}"), file=sys.stderr)
        return exc.exit_code
    except (FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        if args.debug:
            raise
        print(clean_text(f"dynid {args.command}: error: {exc.strerror}: '{exc.filename}'"), file=sys.stderr)
        return EXIT_INPUT
    except Exception as exc:  # a bug: say so plainly
        if args.debug:
            raise
        print(clean_text(f"dynid {args.command}: internal error ({type(exc).__name__}: {exc}). This is a "
                         f"bug in dynid; rerun with --debug and report the traceback."), file=sys.stderr)
        return EXIT_BUG
    finally:
        if progress_log is not None:
            progress_log()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
