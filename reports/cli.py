"""The ``dynid`` command line.

Exit codes: 0 ok; 1 internal error (a bug: please report it); 2 bad input
(data, robot file, options); 3 an iterative method did not converge;
130 interrupted. Errors are printed as one message, never a traceback
(``--debug`` shows it).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import textwrap

from dynamics.errors import DynidError

EXIT_OK, EXIT_BUG, EXIT_INPUT, EXIT_NOT_CONVERGED, EXIT_INTERRUPTED = 0, 1, 2, 3, 130

EPILOG_ROBOT = """examples:
  dynid robot tx40                     DH table, standard and base parameters
  dynid robot arm.urdf --json arm.json the same for a URDF, also as JSON
  dynid robot --list                   the bundled robots
"""
EPILOG_IDENTIFY = """examples:
  dynid identify run.csv --robot tx40 --report out.html --json out.json
  dynid identify run.csv --robot arm.toml --holdout 3      validate on the last 3 s
  dynid identify run.csv --robot tx40 --validation run2.csv --fc 50 --nd 100
  dynid identify tx40.toml --robot tx40   a TOML experiment file (motor-side logs)
  dynid identify rec2.toml rec3.toml --robot kuka_lwr4 --validation rec1.toml
  dynid identify run.csv --robot tx40 --method didim --report didim.html
"""
EPILOG_SIMULATE = """examples:
  dynid simulate --robot tx40 --out run.csv                    20 s of a random Fourier reference
  dynid simulate --robot planar2 --f0 0.2 --harmonics 5 --duration 30 --seed 4 --out run.csv
  dynid simulate --robot tx40 --noise-q 0 --noise-tau 0 --out clean.csv
"""
EPILOG_SAMPLE = """examples:
  dynid sample run.csv --robot tx40 --report post.html --json post.json
  dynid sample examples/staubli_tx40/experiment.toml --robot tx40 --which base --seed 3
  dynid sample run.csv --robot tx40 --csv samples.csv --max-seconds 60
"""
EPILOG_DEMO = """examples:
  dynid demo                             simulated TX40 -> identification -> dynid-demo.html
  dynid demo --report demo.html --json demo.json --seed 7
"""


class _Reporter:
    """Prints human messages on stderr unless --quiet."""

    def __init__(self, quiet):
        self.quiet = quiet

    def __call__(self, msg):
        if not self.quiet:
            print(msg, file=sys.stderr, flush=True)

    def progress(self, label):
        from reports.progress import Progress
        return Progress(label, quiet=self.quiet)


def _add_processing_options(p):
    g = p.add_argument_group("processing (defaults derived from the data)")
    g.add_argument("--fc", type=float, metavar="HZ", help="cut-off of the zero-phase filter of q")
    g.add_argument("--nd", type=int, metavar="N", help="decimation factor (1 = none)")
    g.add_argument("--decimation-cutoff", type=float, metavar="HZ",
                   help="low-pass of the parallel decimation (default 0.8 fs / (2 nd))")
    g.add_argument("--qd-threshold", metavar="RAD_S",
                   help="velocity dead zone: a number, comma-separated per-joint numbers, "
                        "'auto' (default, 1%% of each joint's peak speed) or 0 to keep all rows")
    g.add_argument("--max-error-growth", type=float, default=0.02, metavar="F",
                   help="essential parameters: largest accepted growth of the relative error "
                        "(default 0.02 = 2%%)")


def _processing_settings(args):
    from dynamics.errors import InputError
    s = {}
    if args.fc is not None:
        s["fc_position"] = args.fc
    if args.nd is not None:
        s["nd"] = args.nd
    if args.decimation_cutoff is not None:
        s["f_decimation_cutoff"] = args.decimation_cutoff
    if args.qd_threshold is not None:
        v = args.qd_threshold.strip()
        if v == "auto":
            s["qd_threshold"] = "auto"
        else:
            try:
                vals = [float(x) for x in v.split(",")]
            except ValueError:
                raise InputError(f"--qd-threshold must be a number, per-joint numbers separated by "
                                 f"commas, or 'auto'; got {v!r}") from None
            s["qd_threshold"] = vals[0] if len(vals) == 1 else vals
    return s


def build_parser():
    parser = argparse.ArgumentParser(
        prog="dynid",
        description="Identify the dynamic model of a robot arm from measured data, "
                    "and say how far to trust it.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=textwrap.dedent("""\
            commands:
              robot     show a robot's kinematics, standard and base parameters
              simulate  simulate a robot in closed loop and write a recording (CSV)
              identify  IDIM identification (OLS, WLS, essential parameters) of a recording
              sample    Bayesian posterior of the identified parameters (emcee)
              demo      simulate the TX40, identify it and write an HTML report

            exit codes: 0 ok, 1 internal error, 2 bad input, 3 did not converge, 130 interrupted
            """))
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    common.add_argument("--debug", action="store_true", help="show tracebacks")

    p = sub.add_parser("robot", parents=[common], help="show a robot's parameters",
                       description="Print a robot's DH table, standard parameters and base "
                                   "parameters with their regrouping relations.",
                       epilog=EPILOG_ROBOT, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("robot", nargs="?", help="bundled name (tx40, planar2, kuka_lwr4) or .toml/.urdf file")
    p.add_argument("--json", metavar="PATH", help="also write the parameters as JSON")
    p.add_argument("--list", action="store_true", help="list the bundled robots")

    p = sub.add_parser("identify", parents=[common], help="IDIM identification of a recording",
                       description="Identify the base and essential parameters of a robot from a "
                                   "recording of q and tau (IDIM: OLS, per-joint WLS, essential "
                                   "parameters), validate, and report.",
                       epilog=EPILOG_IDENTIFY, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="+", help="experiment file(s) (.csv, .parquet, .npz, .mat, or .toml "
                                          "description); several recordings are identified together")
    p.add_argument("--robot", required=True, help="bundled robot name or .toml/.urdf file")
    p.add_argument("--method", choices=["idim", "didim"], default="idim",
                   help="idim (needs q and tau) or didim (needs qr and tau and the robot's controller; "
                        "when the file has no qr, the measured q is tracked instead, with a notice)")
    p.add_argument("--max-iter", type=int, default=10, help="DIDIM: largest number of Gauss-Newton steps")
    p.add_argument("--validation", metavar="DATA", help="a second recording to validate on")
    p.add_argument("--holdout", type=float, metavar="SECONDS",
                   help="identify on all but the last SECONDS, validate on them")
    p.add_argument("--report", metavar="PATH", help="write the HTML report here")
    p.add_argument("--json", metavar="PATH", help="write the results as JSON here")
    p.add_argument("--csv", metavar="PATH", help="write the essential parameters as CSV here")
    _add_processing_options(p)

    p = sub.add_parser("simulate", parents=[common], help="simulate a robot in closed loop to a CSV",
                       description="Simulate the robot (a-priori parameters of its robot file) tracking a "
                                   "random Fourier-series reference under its controller, add sensor "
                                   "noise, and write a dynid CSV (t, q*, qr*, tau*).",
                       epilog=EPILOG_SIMULATE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", required=True, help="bundled robot name or .toml/.urdf file")
    p.add_argument("--out", required=True, metavar="CSV", help="where to write the recording")
    p.add_argument("--duration", type=float, default=20.0, metavar="SECONDS")
    p.add_argument("--f0", type=float, default=0.1, metavar="HZ", help="fundamental of the reference")
    p.add_argument("--harmonics", type=int, default=10, metavar="N")
    p.add_argument("--noise-q", type=float, default=4e-5, metavar="RAD", help="position noise std")
    p.add_argument("--noise-tau", type=float, default=0.5, metavar="NM", help="torque noise std")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")

    p = sub.add_parser("sample", parents=[common], help="Bayesian posterior of the parameters (emcee)",
                       description="Identify like 'identify', then sample the posterior of the essential "
                                   "(or base) parameters and one noise level per joint with emcee, until "
                                   "the chains are 50 autocorrelation times long. Exit code 3 if they are not.",
                       epilog=EPILOG_SAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="+", help="experiment file(s), as for 'identify'")
    p.add_argument("--robot", required=True, help="bundled robot name or .toml/.urdf file")
    p.add_argument("--which", choices=["essential", "base"], default="essential")
    p.add_argument("--seed", type=int, default=1, help="random seed of the sampler (default 1)")
    p.add_argument("--walkers", type=int, default=None,
                   help="emcee walkers (default: max(64, 2 x dimensions + 2))")
    p.add_argument("--max-steps", type=int, default=200_000)
    p.add_argument("--max-seconds", type=float, default=300.0)
    p.add_argument("--report", metavar="PATH", help="write the HTML report here")
    p.add_argument("--json", metavar="PATH", help="write the posterior summary as JSON here")
    p.add_argument("--csv", metavar="PATH", help="write the posterior samples as CSV here")
    p.add_argument("--allow-unconverged", action="store_true",
                   help="exit 0 even if the chains did not converge (the outputs still say so)")
    _add_processing_options(p)

    p = sub.add_parser("demo", parents=[common], help="simulated TX40 -> identification -> report",
                       description="Simulate the Staubli TX40 in closed loop with the parameters of "
                                   "Table 2 of Gautier, Janot, Vandanjon (2010), 5 kHz torque and "
                                   "position noise, identify it (OLS, WLS, essential parameters), "
                                   "validate on a second trajectory and write an HTML report.",
                       epilog=EPILOG_DEMO, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--report", metavar="PATH", default="dynid-demo.html",
                   help="HTML report path (default dynid-demo.html)")
    p.add_argument("--json", metavar="PATH", help="write the results as JSON here")
    p.add_argument("--seed", type=int, default=1, help="random seed of the noise and trajectories (default 1)")
    p.add_argument("--duration", type=float, default=20.0, metavar="SECONDS",
                   help="length of the identification recording (default 20 s)")
    return parser


def cmd_robot(args, say):
    from analysis.provenance import atomic_write_text, dumps_json
    from dynamics.base_parameters import base_parameters
    from dynamics.robot_file import bundled_robots, load_robot
    if args.list or not args.robot:
        print("bundled robots: " + ", ".join(bundled_robots()))
        return EXIT_OK
    robot = load_robot(args.robot)
    bp = base_parameters(robot)
    out = [f"robot '{robot.name}': {robot.n_joints} joints"
           + (f" — {robot.description}" if robot.description else "")]
    dh = robot.dh_table()
    if dh:
        out.append("\nmodified DH (Khalil-Kleinfinger):")
        out.append(f"  {'j':>2} {'name':<10} {'sigma':>5} {'alpha':>9} {'d':>8} {'theta':>9} {'r':>8}")
        for (j, sg, a, d, th, r), name in zip(dh, robot.joint_names):
            out.append(f"  {j:>2} {name:<10} {sg:>5} {a:>9.4f} {d:>8.4f} {th:>9.4f} {r:>8.4f}")
    else:
        out.append("\njoints (from URDF; frames rotated so each axis is z): " + ", ".join(robot.joint_names))
    for c in robot.couplings:
        out.append(f"coupling: motor {c.motor} turns with joints {list(c.joints)} "
                   f"(coefficients {list(c.coefficients)})")
    out.append(f"\n{robot.n_standard} standard parameters:")
    names = robot.standard_names
    for k in range(0, len(names), 14):
        out.append("  " + " ".join(names[k:k + 14]))
    out.append(f"\n{bp.n_base} base parameters:")
    for rel in bp.relations:
        out.append("  " + rel)
    if bp.unidentifiable:
        out.append(f"\nno effect on the dynamics ({len(bp.unidentifiable)}): " + " ".join(bp.unidentifiable))
    print("\n".join(out))
    if args.json:
        doc = {"robot": robot.name, "n_joints": robot.n_joints, "source": robot.source,
               "standard": names, "base": bp.table(), "unidentifiable": bp.unidentifiable,
               "dh": [dict(zip(("j", "sigma", "alpha", "d", "theta", "r"), row)) for row in dh] if dh else None,
               "couplings": [{"motor": c.motor, "joints": list(c.joints),
                              "coefficients": list(c.coefficients)} for c in robot.couplings],
               "regrouping_matrix": bp.matrix.tolist(), "provenance": robot.provenance}
        atomic_write_text(args.json, dumps_json(doc))
        say(f"wrote {args.json}")
    return EXIT_OK


def _write_outputs(args, say, result, robot, experiment, validation):
    """Render every requested output in memory, then write them all or none.

    Each file is written atomically (temp file + rename); if the run is
    interrupted between two files, the ones already written are removed, so a
    report never sits next to a JSON of another run or without its JSON.
    """
    from analysis.provenance import dumps_json
    outputs = []
    if args.json:
        doc = result.to_dict()
        if validation is not None:
            doc["validation"] = validation.to_dict()
        outputs.append((args.json, dumps_json(doc)))
    if getattr(args, "csv", None):
        outputs.append((args.csv, result.model.to_frame().to_csv()))
    if args.report:
        from reports.html import render_idim_report
        outputs.append((args.report, render_idim_report(result, robot, experiment, validation)))
    commit_outputs(outputs, say)


def commit_outputs(outputs, say):
    from analysis.provenance import atomic_write_text
    written = []
    try:
        for path, text in outputs:
            atomic_write_text(path, text)
            written.append(path)
    except BaseException:
        for path in written:
            try:
                os.remove(path)
            except OSError:
                pass
        raise
    for path in written:
        say(f"wrote {path}")


def cmd_identify(args, say):
    from analysis.experiment import load_experiment
    from analysis.idim import identify_idim
    from analysis.validation import validate
    from dynamics.errors import InputError
    from dynamics.robot_file import load_robot
    robot = load_robot(args.robot)
    say(f"robot '{robot.name}' ({robot.n_joints} joints)")
    experiments = []
    for path in args.data:
        experiments.append(load_experiment(path, robot))
        say(f"loaded {path}: {experiments[-1].n_samples} samples at {experiments[-1].fs:g} Hz")
    if args.validation and args.holdout:
        raise InputError("give either --validation or --holdout, not both")
    valid = None
    if args.validation:
        valid = load_experiment(args.validation, robot)
    elif args.holdout:
        if len(experiments) > 1:
            raise InputError("--holdout splits one recording; with several, use --validation")
        experiment = experiments[0]
        t_split = experiment.t[-1] - args.holdout
        if not experiment.t[0] < t_split:
            raise InputError(f"--holdout {args.holdout} s is longer than the recording "
                             f"({experiment.duration:.3g} s)")
        experiments, valid = [experiment.segment(None, t_split)], experiment.segment(t_split, None)
    ident = experiments if len(experiments) > 1 else experiments[0]
    if args.method == "didim":
        return _identify_didim(args, say, robot, experiments, valid)
    with say.progress("regressor and decimation") as bar:
        result = identify_idim(ident, robot, settings=_processing_settings(args),
                               max_error_growth=args.max_error_growth, progress=bar.update)
    validation = validate(result, valid, robot) if valid is not None else None
    if not args.quiet:
        print(result.summary())
        if validation is not None:
            print()
            print(validation.summary())
    _write_outputs(args, say, result, robot, experiments[0], validation)
    return EXIT_OK


def _identify_didim(args, say, robot, experiments, valid):
    from analysis.didim import identify_didim
    from analysis.provenance import dumps_json
    from dynamics.errors import InputError
    if len(experiments) > 1:
        raise InputError("--method didim identifies one recording at a time")
    if robot.controller is None:
        raise InputError(f"DIDIM simulates the robot under its controller, but '{robot.name}' "
                         f"({robot.source}) has no [controller] table")
    exp = experiments[0]
    reference = "qr" if exp.qr is not None else "q"
    with say.progress("DIDIM iterations") as bar:
        result = identify_didim(exp, robot, settings=_processing_settings(args), reference=reference,
                                max_iter=args.max_iter, max_error_growth=args.max_error_growth,
                                progress=bar.update)
    if not args.quiet:
        print(result.summary())
    outputs = []
    if args.json:
        outputs.append((args.json, dumps_json(result.to_dict())))
    if getattr(args, "csv", None):
        outputs.append((args.csv, result.model.to_frame().to_csv()))
    if args.report:
        from reports.didim_section import didim_sections
        from reports.html import render_sections
        outputs.append((args.report, render_sections(didim_sections(result),
                                                     title=f"DIDIM identification of {robot.name}")))
    commit_outputs(outputs, say)
    if not result.converged:
        print(f"dynid identify: DIDIM did not converge ({result.stop_reason}); the outputs say so",
              file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def cmd_simulate(args, say):
    import numpy as np
    from analysis.synthetic import apriori_parameters, simulate_experiment
    from dynamics.base_parameters import base_parameters
    from dynamics.errors import InputError
    from dynamics.robot_file import load_robot
    from dynamics.trajectories import random_fourier_trajectory
    robot = load_robot(args.robot)
    if robot.controller is None:
        raise InputError(f"robot '{robot.name}' ({robot.source}) has no [controller]; add one to simulate")
    if args.duration <= 0 or args.f0 <= 0 or args.harmonics < 1:
        raise InputError("--duration and --f0 must be positive and --harmonics at least 1")
    chi = apriori_parameters(robot, base_parameters(robot))
    rng = np.random.default_rng(args.seed)
    traj = random_fourier_trajectory(robot, args.f0, args.harmonics, rng)
    exp = simulate_experiment(robot, chi, traj, args.duration, rng=rng, q_noise=args.noise_q,
                              tau_noise=args.noise_tau, name=f"simulated {robot.name} (seed {args.seed})")
    commit_outputs([(args.out, exp.to_frame().to_csv(index=False, float_format="%.10g"))], say)
    return EXIT_OK


def cmd_sample(args, say):
    from analysis.bayes import sample_idim
    from analysis.experiment import load_experiment
    from analysis.idim import identify_idim
    from analysis.provenance import dumps_json
    from dynamics.robot_file import load_robot
    robot = load_robot(args.robot)
    experiments = [load_experiment(p, robot) for p in args.data]
    result = identify_idim(experiments if len(experiments) > 1 else experiments[0], robot,
                           settings=_processing_settings(args), max_error_growth=args.max_error_growth)
    say(f"sampling the posterior of the {args.which} parameters")
    post = sample_idim(result, which=args.which, seed=args.seed, n_walkers=args.walkers,
                       max_steps=args.max_steps, max_seconds=args.max_seconds)
    if not args.quiet:
        print(post.summary())
    outputs = []
    if args.json:
        outputs.append((args.json, dumps_json(post.to_dict())))
    if args.csv:
        outputs.append((args.csv, post.samples_frame().to_csv(index=False, lineterminator="\n",
                                                              float_format="%.17g")))
    if args.report:
        from reports.bayes_section import bayes_sections
        from reports.html import render_idim_report
        outputs.append((args.report, render_idim_report(result, robot, experiments[0],
                                                        extra_sections=bayes_sections(post))))
    commit_outputs(outputs, say)
    if not post.converged and not args.allow_unconverged:
        print(f"dynid sample: the chains did not converge ({post.reason}); the outputs say so",
              file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def cmd_demo(args, say):
    from analysis.demo import run_demo
    result, robot, experiment, validation = run_demo(seed=args.seed, duration=args.duration,
                                                     say=say)
    if not args.quiet:
        print(result.summary())
        print()
        print(validation.summary())
    _write_outputs(args, say, result, robot, experiment, validation)
    return EXIT_OK


COMMANDS = {"robot": cmd_robot, "simulate": cmd_simulate, "identify": cmd_identify, "sample": cmd_sample,
            "demo": cmd_demo}


def _terminate(signum, frame):
    raise KeyboardInterrupt


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.version:
        from analysis.provenance import versions
        print(f"dynid {versions().get('dynid', '?')}")
        return EXIT_OK
    if not args.command:
        parser.print_help()
        return EXIT_INPUT
    signal.signal(signal.SIGTERM, _terminate)
    say = _Reporter(args.quiet)
    try:
        return COMMANDS[args.command](args, say)
    except BrokenPipeError:           # output piped into head & co.
        sys.stderr.close()
        return EXIT_OK
    except KeyboardInterrupt:
        print("dynid: interrupted; no partial output was written", file=sys.stderr)
        return EXIT_INTERRUPTED
    except DynidError as exc:
        if args.debug:
            raise
        print(f"dynid {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except (FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        if args.debug:
            raise
        print(f"dynid {args.command}: error: {exc.strerror}: '{exc.filename}'", file=sys.stderr)
        return EXIT_INPUT
    except Exception as exc:  # a bug: say so plainly
        if args.debug:
            raise
        print(f"dynid {args.command}: internal error ({type(exc).__name__}: {exc}). This is a bug in "
              f"dynid; rerun with --debug and report the traceback.", file=sys.stderr)
        return EXIT_BUG


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
