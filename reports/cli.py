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

from dynid.errors import DynidError
from dynid.reports.progress import Reporter, clean_text

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
  dynid identify run.csv --robot planar2 --method projection --json pm.json
  dynid identify run.csv --robot planar2 --method ml --f0 0.1 --ml-harmonics 20 --json ml.json
  dynid identify run.csv --robot tx40 --asymmetric-friction --report out.html
  dynid identify rec1.toml --robot kuka_lwr4 --urdf kuka_identified.urdf
  dynid identify rec1.toml --robot kuka_lwr4 --validation rec2.toml --physical --effects spring:all
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
EPILOG_EXCITE = """examples:
  dynid excite --robot tx40 --f0 0.1 --harmonics 5 --out traj.csv --json ex.json
  dynid excite --robot planar2 --f0 0.2 --harmonics 4 --criterion logdet --starts 8 --report ex.html
  dynid excite --robot tx40 --f0 0.1 --harmonics 5 --fs 5000 --periods 25 --out traj.csv
"""
EPILOG_DIAGNOSE = """examples:
  dynid diagnose run.csv --robot tx40 --holdout 3 --report diag.html --json diag.json
  dynid diagnose run.csv --robot tx40 --validation run2.csv --effects stribeck,offset,spring
  dynid diagnose examples/staubli_tx40/experiment.toml --robot tx40 --holdout 3 --no-offsets
  effects: offset asymmetric_coulomb asymmetric_viscous stribeck position_ripple spring
           coupling time_delay drift load_friction payload
"""
EPILOG_REPORT = """examples:
  dynid report run.csv --robot tx40 --holdout 3 --report full.html --json full.json
  dynid report examples/staubli_tx40/experiment.toml --robot tx40 --holdout 3 --skip didim
  dynid report run.csv --robot tx40 --validation run2.csv --max-seconds 30 --seed 2
"""
EPILOG_DEMO = """examples:
  dynid demo                             simulated TX40 -> identification -> dynid-demo.html
  dynid demo --report demo.html --json demo.json --seed 7
  dynid demo --skip didim,sample,diagnose          IDIM only (a few seconds)
"""


#: largest --harmonics of a reference or excitation trajectory
MAX_HARMONICS = 1000
#: smallest --fc as a fraction of the sampling rate: below it the zero-phase filter's
#: transient (about fs / fc samples at each end) is longer than any recording
MIN_FC_PER_FS = 1e-4


def _number(text):
    import math
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_float(text):
    """argparse type: a finite number > 0."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


def _v_s_arg(text):
    """argparse type of --v-s: 'auto' or a finite number > 0."""
    return "auto" if str(text).strip().lower() == "auto" else positive_float(text)


def non_negative_float(text):
    """argparse type: a finite number >= 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative (0 for none), got {text!r}")
    return value


def _integer(text):
    try:
        return int(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def seed_type(text):
    """argparse type of --seed: a non-negative integer (numpy's generators refuse others)."""
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"a random seed must be a non-negative integer, got {text!r}; "
                                         f"use e.g. --seed 1")
    return value


def positive_int(text):
    """argparse type: a whole number >= 1."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def harmonics_type(text):
    """argparse type of --harmonics: 1 to MAX_HARMONICS."""
    value = positive_int(text)
    if value > MAX_HARMONICS:
        raise argparse.ArgumentTypeError(f"{value} harmonics is more than {MAX_HARMONICS}, the most dynid "
                                         f"designs (a trajectory needs a few, typically 3 to 20)")
    return value


def qd_threshold_type(text):
    """argparse type of --qd-threshold: 'auto', or comma-separated finite numbers >= 0."""
    import math
    v = str(text).strip()
    if v == "auto":
        return v
    try:
        vals = [float(x) for x in v.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, per-joint numbers separated by commas, or "
                                         f"'auto'; got {text!r}") from None
    if not all(math.isfinite(x) and x >= 0 for x in vals):
        raise argparse.ArgumentTypeError(f"the velocity dead zone must be finite and non-negative "
                                         f"(0 keeps every row); got {text!r}")
    return v


def _add_robot_options(p, positional=False):
    if positional:
        p.add_argument("robot", help="bundled robot name or .toml/.urdf file")
    else:
        p.add_argument("--robot", required=True, help="bundled robot name or .toml/.urdf file")
    p.add_argument("--base", metavar="LINK", help="URDF: the link the chain starts from (default: the root)")
    p.add_argument("--tip", metavar="LINK",
                   help="URDF: the link the chain ends at, e.g. one arm of a two-arm robot or a Panda "
                        "without its fingers (default: the tree must be one chain)")


def _robot(args):
    from dynid.dynamics.robot_file import load_robot
    robot = load_robot(args.robot, base=getattr(args, "base", None), tip=getattr(args, "tip", None))
    _check_robot_options(args, robot)
    return robot


def _check_robot_options(args, robot):
    """Options whose valid values depend on the robot, checked before any data is loaded."""
    from dynid.errors import InputError
    v = getattr(args, "qd_threshold", None)
    if v and v != "auto":
        k = len(v.split(","))
        if k not in (1, robot.n_joints):
            raise InputError(f"--qd-threshold {v}: {k} values for the {robot.n_joints} joints of robot "
                             f"'{robot.name}'; give one value for every joint or {robot.n_joints} "
                             f"comma-separated ones (one per joint)")


def _check_cutoffs(args, experiments):
    """--fc against the sampling rate of every recording (after loading)."""
    from dynid.errors import InputError
    fc = getattr(args, "fc", None)
    if fc is None:
        return
    for exp in experiments:
        fs = getattr(exp, "fs", None)
        if exp is None or not fs:
            continue
        name = getattr(exp, "name", None) or getattr(exp, "source", None) or "the recording"
        if fc >= fs / 2:
            raise InputError(f"--fc {fc:g} Hz is not below half the sampling rate ({fs:g} Hz) of {name}; "
                             f"give --fc below {fs / 2:g} Hz")
        if fc < MIN_FC_PER_FS * fs:
            raise InputError(f"--fc {fc:g} Hz is below {MIN_FC_PER_FS * fs:g} Hz ({MIN_FC_PER_FS:g} of the "
                             f"sampling rate {fs:g} Hz of {name}): the filter's transient would last about "
                             f"{fs / fc:.3g} samples at each end, longer than a recording; give --fc "
                             f"{MIN_FC_PER_FS * fs:g} or more (typically 10 to 100 Hz)")


def _add_processing_options(p):
    g = p.add_argument_group("processing (defaults derived from the data)")
    g.add_argument("--fc", type=positive_float, metavar="HZ", help="cut-off of the zero-phase filter of q")
    g.add_argument("--nd", type=positive_int, metavar="N", help="decimation factor (1 = none)")
    g.add_argument("--decimation-cutoff", type=positive_float, metavar="HZ",
                   help="low-pass of the parallel decimation (default 0.8 fs / (2 nd))")
    g.add_argument("--qd-threshold", type=qd_threshold_type, metavar="RAD_S",
                   help="velocity dead zone: a number, comma-separated per-joint numbers, "
                        "'auto' (default, 1%% of each joint's peak speed) or 0 to keep all rows")
    g.add_argument("--max-error-growth", type=float, default=0.02, metavar="F",
                   help="essential parameters: largest accepted growth of the relative error "
                        "(default 0.02 = 2%%)")


def _add_validation_options(p):
    g = p.add_mutually_exclusive_group()
    g.add_argument("--validation", metavar="DATA", help="a second recording to validate on")
    g.add_argument("--holdout", type=positive_float, metavar="SECONDS",
                   help="identify on all but the last SECONDS, validate on them")


GAIN_UPDATES = {"every": True, "initial": "initial", "none": False}
JSON_HELP = "write the results as JSON here ('-': to stdout)"


def _processing_settings(args):
    from dynid.errors import InputError
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
              excite    design an optimal Fourier excitation trajectory (CSV for a controller)
              identify  identify a recording: IDIM (default), DIDIM or the Projection Method
              sample    Bayesian posterior of the identified parameters (emcee)
              diagnose  find the effects the model lacks in the residual, add them, compare errors
              report    everything at once: IDIM, DIDIM, posterior and diagnosis in one report
              demo      simulate the TX40, identify it and write an HTML report
              fleet     identify a fleet's recordings on Dask, store them, raise friction-wear alarms

            --json - writes the machine-readable result to stdout (the summary then goes to stderr)

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
    p.add_argument("robot", nargs="?", help="bundled name (tx40, planar2, kuka_lwr4, panda) or .toml/.urdf file")
    p.add_argument("--base", metavar="LINK", help="URDF: the link the chain starts from (default: the root)")
    p.add_argument("--tip", metavar="LINK", help="URDF: the link the chain ends at (default: one chain)")
    p.add_argument("--json", metavar="PATH", help="also write the parameters as JSON")
    p.add_argument("--list", action="store_true", help="list the bundled robots")

    p = sub.add_parser("identify", parents=[common], help="identify a recording (IDIM, DIDIM, Projection Method)",
                       description="Identify the base and essential parameters of a robot from a "
                                   "recording of q and tau (IDIM: OLS, per-joint WLS, essential "
                                   "parameters), validate, and report.",
                       epilog=EPILOG_IDENTIFY, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="+", help="experiment file(s) (.csv, .parquet, .npz, .mat, or .toml "
                                          "description); several recordings are identified together")
    _add_robot_options(p)
    p.add_argument("--method", choices=["idim", "didim", "projection", "ml"], default="idim",
                   help="idim (needs q and tau); didim (needs qr and tau and the robot's controller; "
                        "when the file has no qr, the measured q is tracked instead, with a notice); "
                        "projection (Bona & Curatella's Projection Method for closed-loop data: needs "
                        "q, qr and tau; removes the bias of noise fed back by the controller); ml "
                        "(maximum likelihood with noise on q and tau, for a periodic excitation: give --f0)")
    p.add_argument("--f0", type=positive_float, metavar="HZ",
                   help="ML: fundamental frequency of the periodic excitation")
    p.add_argument("--ml-harmonics", type=harmonics_type, metavar="K",
                   help="ML: harmonics of the latent trajectory (default: chosen by BIC on q)")
    p.add_argument("--asymmetric-friction", action="store_true",
                   help="IDIM: also give each joint's friction with different viscous and Coulomb "
                        "coefficients for positive and negative velocity (Bona & Curatella eq. (2))")
    p.add_argument("--max-iter", type=int, default=10, help="DIDIM: largest number of Gauss-Newton steps")
    p.add_argument("--gain-update", choices=list(GAIN_UPDATES), default="every",
                   help="DIDIM: scale the simulated derivative gains by J_j/J_ap_j (eq. 27) at every "
                        "step (default, as the paper), only for the first simulation (initial), or never")
    p.add_argument("--gains", choices=["assumed", "identify"], default="assumed",
                   help="DIDIM: the controller gains of the robot file (assumed, as the paper), or "
                        "identified first from the logged reference qr, q and tau (identify: the "
                        "controller's structure, pd or pid, comes from the robot file)")
    p.add_argument("--v-s", type=_v_s_arg, metavar="RAD_PER_S|auto", dest="v_s",
                   help="DIDIM: velocity over which the simulated Coulomb friction changes sign "
                        "(smooth sign). Default auto: chosen from the data, the smallest DIDIM "
                        "residual on a factor-2 walk from 0.05 rad/s (on an independent plant whose "
                        "friction switches over 0.01 rad/s, 0.05 biased Ia3 by 3-6 %%; auto found "
                        "0.006-0.01). A number fixes it; smaller values cost more integration substeps")
    _add_validation_options(p)
    p.add_argument("--report", metavar="PATH", help="write the HTML report here")
    p.add_argument("--json", metavar="PATH", help=JSON_HELP)
    p.add_argument("--csv", metavar="PATH", help="write the essential parameters as CSV here")
    p.add_argument("--urdf", metavar="PATH",
                   help="IDIM: write a URDF with a physically consistent standard parameter set that "
                        "reproduces the identified essential parameters as closely as consistency allows "
                        "(with --physical: the PC-WLS set)")
    p.add_argument("--mjcf", metavar="PATH",
                   help="IDIM: write a MuJoCo MJCF of the same physically consistent set (inertials, "
                        "armature = Ia, damping = Fv, frictionloss = Fc). With --physical --effects "
                        "spring:...: the PC-WLS rigid body and its springs (stiffness = Ks, springref 0)")
    p.add_argument("--gravity-tilt", action="store_true",
                   help="IDIM: first estimate the direction of gravity (a base tilt about the base x and y "
                        "axes, |g| kept, with sigma and a likelihood-ratio test of no tilt) on the "
                        "identification data, then identify, validate and export with that gravity; JSON "
                        "block \"gravity_tilt\"")
    g = p.add_argument_group("physically consistent identification (IDIM, DIDIM; needs dynid[physical])")
    g.add_argument("--physical", action="store_true",
                   help="refit the WLS under physical consistency (pseudo-inertias PSD, Ia, Fv, Fc >= 0), "
                        "an SDP; JSON block \"physical\" and a report section. With --method didim: "
                        "PC-DIDIM, every Gauss-Newton step refitted so")
    g.add_argument("--prior", choices=["apriori", "geometric"],
                   help="--physical: regularise toward the robot file's a-priori values: 'apriori' by the "
                        "scaled Euclidean distance, 'geometric' by the entropic divergence of each link's "
                        "pseudo-inertia (Lee, Wensing & Park 2020; needs physical a-priori links), "
                        "Euclidean for Ia, Fv, Fc, Off")
    g.add_argument("--prior-weight", type=non_negative_float, default=1.0, metavar="W",
                   help="--physical --prior: weight of the a-priori term (default 1; reported)")
    g.add_argument("--mass-tolerance", type=non_negative_float, metavar="F",
                   help="--physical: keep each link mass within this fraction of its a-priori value")
    g.add_argument("--physical-set", choices=["base", "essential"], default="base",
                   help="--physical (IDIM): constrain the WLS of all base parameters (default) or the "
                        "essential parameters")
    g.add_argument("--bootstrap", type=int, default=100, metavar="N",
                   help="--physical: bootstrap refits for the %%sigma of the PC fit (default 100)")
    g.add_argument("--effects", metavar="SPEC",
                   help="IDIM: fit these effects beside the rigid body, e.g. spring:all or "
                        "spring:all,position_ripple:7:1 (name:joint[:order], joint 1-based or all; "
                        "offset, asymmetric_coulomb, asymmetric_viscous, spring, position_ripple): "
                        "the unconstrained WLS of the model with them and, with --physical, its "
                        "PC-WLS (the rigid body constrained, the effects free); JSON block \"effects\"")
    _add_processing_options(p)

    p = sub.add_parser("simulate", parents=[common], help="simulate a robot in closed loop to a CSV",
                       description="Simulate the robot (a-priori parameters of its robot file) tracking a "
                                   "random Fourier-series reference under its controller, add sensor "
                                   "noise, and write a dynid CSV (t, q*, qr*, tau*).",
                       epilog=EPILOG_SIMULATE, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_robot_options(p)
    p.add_argument("--out", required=True, metavar="CSV", help="where to write the recording")
    p.add_argument("--duration", type=positive_float, default=20.0, metavar="SECONDS")
    p.add_argument("--f0", type=positive_float, default=0.1, metavar="HZ", help="fundamental of the reference")
    p.add_argument("--harmonics", type=harmonics_type, default=10, metavar="N")
    p.add_argument("--noise-q", type=non_negative_float, default=4e-5, metavar="RAD", help="position noise std")
    p.add_argument("--noise-tau", type=non_negative_float, default=0.5, metavar="NM", help="torque noise std")
    p.add_argument("--seed", type=seed_type, default=1, help="random seed (default 1)")
    p.add_argument("--json", metavar="PATH",
                   help="write the simulation's settings, reference coefficients and true base "
                        "parameters as JSON ('-': to stdout)")

    p = sub.add_parser("sample", parents=[common], help="Bayesian posterior of the parameters (emcee)",
                       description="Identify like 'identify', then sample the posterior of the essential "
                                   "(or base) parameters and one noise level per joint with emcee, until "
                                   "the chains are 50 autocorrelation times long. Exit code 3 if they are not.",
                       epilog=EPILOG_SAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="+", help="experiment file(s), as for 'identify'")
    _add_robot_options(p)
    p.add_argument("--which", choices=["essential", "base"], default="essential")
    p.add_argument("--physical", action="store_true",
                   help="with --which base: the posterior's support is the physically consistent set "
                        "(draws whose base parameters no rigid body with Ia, Fv, Fc >= 0 gives are "
                        "rejected; one feasibility SDP per point, needs dynid[physical])")
    p.add_argument("--seed", type=seed_type, default=1, help="random seed of the sampler (default 1)")
    p.add_argument("--walkers", type=positive_int, default=None,
                   help="emcee walkers (default: max(64, 2 x dimensions + 2))")
    p.add_argument("--max-steps", type=positive_int, default=200_000)
    p.add_argument("--max-seconds", type=positive_float, default=300.0)
    p.add_argument("--report", metavar="PATH", help="write the HTML report here")
    p.add_argument("--json", metavar="PATH", help="write the posterior summary as JSON here ('-': to stdout)")
    p.add_argument("--csv", metavar="PATH", help="write the posterior samples as CSV here")
    p.add_argument("--allow-unconverged", action="store_true",
                   help="exit 0 even if the chains did not converge (the outputs still say so)")
    _add_processing_options(p)

    p = sub.add_parser("excite", parents=[common], help="optimal Fourier excitation (Bona & Curatella)",
                       description="Optimise the coefficients of a finite Fourier series per joint "
                                   "(fundamental f0, N harmonics) to minimise the condition number of "
                                   "the base regressor (or -log det), within the robot's position, "
                                   "velocity, acceleration and torque limits (eq. (20) of Bona & "
                                   "Curatella 2005); several random starts; every limit checked on a "
                                   "dense grid. Writes the reference (t, qr, qdr, qddr) as CSV.",
                       epilog=EPILOG_EXCITE, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_robot_options(p)
    p.add_argument("--f0", type=positive_float, required=True, metavar="HZ", help="fundamental frequency")
    p.add_argument("--harmonics", type=harmonics_type, required=True, metavar="N", help="harmonics per joint")
    p.add_argument("--starts", type=positive_int, default=4, help="random starts (default 4)")
    p.add_argument("--criterion", choices=["cond", "logdet"], default="cond",
                   help="cond: condition number (default); logdet: D-optimality")
    p.add_argument("--margin", type=float, default=0.95,
                   help="fraction of every limit the design may use (default 0.95)")
    p.add_argument("--seed", type=seed_type, default=1, help="random seed of the starts (default 1)")
    p.add_argument("--out", metavar="CSV", help="write the reference trajectory here")
    p.add_argument("--fs", type=positive_float, metavar="HZ",
                   help="sampling rate of the CSV (default: the robot's controller rate, else 1000)")
    p.add_argument("--periods", type=int, default=1, help="whole periods in the CSV (default 1)")
    p.add_argument("--json", metavar="PATH", help="write coefficients, cond(W) and margins as JSON "
                                                  "('-': to stdout)")
    p.add_argument("--report", metavar="PATH", help="write an HTML report here")

    p = sub.add_parser("diagnose", parents=[common], help="find what the model lacks in the residual",
                       description="Identify like 'identify', then look for effects the model lacks "
                                   "(offsets, asymmetric or Stribeck friction, position ripple, springs, "
                                   "couplings, time delay, drift, load-dependent friction, payload): "
                                   "rank them by blocked cross-validation and a likelihood-ratio test, "
                                   "add those that pass, and report the errors before and after.",
                       epilog=EPILOG_DIAGNOSE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="experiment file (.csv, .parquet, .npz, .mat, or .toml description)")
    _add_robot_options(p)
    _add_validation_options(p)
    p.add_argument("--effects", metavar="LIST", help="comma-separated effects to consider (default all)")
    p.add_argument("--max-effects", type=int, default=3, help="most effects added (default 3)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="family-wise level of the test at each step (default 0.01)")
    p.add_argument("--no-offsets", action="store_true",
                   help="remove the torque offsets Off_j from the model first (to test for them)")
    p.add_argument("--report", metavar="PATH", help="write the HTML report here")
    p.add_argument("--json", metavar="PATH", help=JSON_HELP)
    _add_processing_options(p)

    p = sub.add_parser("report", parents=[common], help="IDIM, DIDIM, posterior and diagnosis in one report",
                       description="Run every analysis the data and the robot file allow and write one "
                                   "HTML report: IDIM (OLS, WLS, essential parameters, validation), "
                                   "DIDIM (if the robot has a controller), the Bayesian posterior of the "
                                   "essential parameters, and the residual diagnosis. Exit code 3 if "
                                   "DIDIM or the sampler did not converge (the report says so).",
                       epilog=EPILOG_REPORT, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="+", help="experiment file(s), as for 'identify'")
    _add_robot_options(p)
    _add_validation_options(p)
    p.add_argument("--report", metavar="PATH", required=True, help="write the HTML report here")
    p.add_argument("--json", metavar="PATH", help=JSON_HELP)
    p.add_argument("--skip", metavar="LIST", default="",
                   help="comma-separated parts to leave out: didim, sample, diagnose")
    p.add_argument("--seed", type=seed_type, default=1, help="random seed of the sampler (default 1)")
    p.add_argument("--max-seconds", type=positive_float, default=60.0,
                   help="time limit of the sampler (default 60 s)")
    p.add_argument("--max-iter", type=int, default=15, help="DIDIM: largest number of Gauss-Newton steps")
    p.add_argument("--gain-update", choices=list(GAIN_UPDATES), default="initial",
                   help="DIDIM's derivative-gain update (see identify --help); default initial: "
                        "the paper's every-step update oscillated on the demo data")
    _add_processing_options(p)

    p = sub.add_parser("demo", parents=[common], help="simulated TX40 -> identification -> report",
                       description="Simulate the Staubli TX40 in closed loop with the parameters of "
                                   "Table 2 of Gautier, Janot, Vandanjon (2010), 5 kHz torque and "
                                   "position noise, identify it (IDIM: OLS, WLS, essential parameters; "
                                   "DIDIM from torque and reference only; the Bayesian posterior; the "
                                   "residual diagnosis), validate on a second trajectory and write an "
                                   "HTML report. --skip leaves parts out.",
                       epilog=EPILOG_DEMO, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--report", metavar="PATH", default="dynid-demo.html",
                   help="HTML report path (default dynid-demo.html)")
    p.add_argument("--json", metavar="PATH", help=JSON_HELP)
    p.add_argument("--seed", type=seed_type, default=1, help="random seed of the noise and trajectories (default 1)")
    p.add_argument("--duration", type=positive_float, default=20.0, metavar="SECONDS",
                   help="length of the identification recording (default 20 s)")
    p.add_argument("--skip", metavar="LIST", default="",
                   help="comma-separated parts to leave out: didim, sample, diagnose")
    p.add_argument("--max-seconds", type=positive_float, default=60.0,
                   help="time limit of the sampler (default 60 s)")
    p.add_argument("--max-iter", type=int, default=15, help="DIDIM: largest number of Gauss-Newton steps")
    p.add_argument("--gain-update", choices=list(GAIN_UPDATES), default="initial",
                   help="DIDIM's derivative-gain update (see identify --help); default initial: "
                        "the paper's every-step update oscillated on the demo data")
    _add_fleet_parser(sub, common)
    return parser


def _add_fleet_parser(sub, common):
    """The `fleet` command (its own function, so that its options stay together)."""
    p = sub.add_parser("fleet", parents=[common], help="identify a fleet's recordings on Dask, watch friction",
                       description="Identify every new or changed recording of a fleet catalogue (IDIM, one "
                                   "Dask task per recording) into a Parquet results store, then monitor "
                                   "each robot's friction (temperature-compensated, two-sided CUSUM) and "
                                   "raise alarms naming robot, joint, parameter, onset and size. Needs "
                                   'pip install "dynid[fleet]". Formats: docs/formats.md.',
                       epilog=textwrap.dedent("""\
                           examples:
                             dynid fleet catalogue.csv --out store/ --report fleet.html --json fleet.json
                             dynid fleet catalogue.csv --out store/ --workers 2 --parameters Fv,Fc,Ia
                             dynid fleet catalogue.parquet --out store/ --scheduler tcp://head:8786

                           A rerun computes only the recordings that are new or changed; failed
                           recordings are listed and stored with their error, the rest goes on.
                           """), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("catalogue", help="fleet catalogue (.csv or .parquet): robot_id, timestamp, path, robot "
                                     "[, temperature | temperature1..N]")
    p.add_argument("--out", dest="store", metavar="STORE", required=True,
                   help="results store folder (created; a rerun computes only what is missing or changed)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. tcp://host:8786 "
                                                          "(default: a local cluster on this machine)")
    p.add_argument("--workers", type=int, metavar="N", help="local cluster: worker processes (default: cores)")
    p.add_argument("--parameters", default="Fv,Fc", metavar="LIST",
                   help="base parameters to monitor, by family (Fv: every joint's) or name (Fv2); default Fv,Fc")
    p.add_argument("--false-alarm-rate", type=float, default=None, metavar="P",
                   help="accepted false alarms per monitored parameter and recording (default 1e-4)")
    p.add_argument("--baseline", type=int, default=None, metavar="N",
                   help="the first N recordings of each robot are its healthy baseline (default 8)")
    p.add_argument("--diagnose", action="store_true", help="also run the residual diagnosis per recording")
    p.add_argument("--report", metavar="PATH", help="write the fleet's HTML report here")
    p.add_argument("--json", metavar="PATH", help="write the fleet's results and alarms as JSON here ('-': stdout)")


def cmd_robot(args, say):
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import bundled_robots
    from dynid.provenance import dumps_json
    if args.list or not args.robot:
        print("bundled robots: " + ", ".join(bundled_robots()))
        return EXIT_OK
    robot = _robot(args)
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
    _show(args, clean_text("\n".join(out)))
    if args.json:
        doc = {"robot": robot.name, "n_joints": robot.n_joints, "source": robot.source,
               "standard": names, "base": bp.table(), "unidentifiable": bp.unidentifiable,
               "dh": [dict(zip(("j", "sigma", "alpha", "d", "theta", "r"), row)) for row in dh] if dh else None,
               "couplings": [{"motor": c.motor, "joints": list(c.joints),
                              "coefficients": list(c.coefficients)} for c in robot.couplings],
               "regrouping_matrix": bp.matrix.tolist(), "provenance": robot.provenance}
        commit_outputs([(args.json, dumps_json(doc))], say)
    return EXIT_OK


def _verdict(args, result, validation=None, **kw):
    """The verdict of ``result`` (:func:`dynid.analysis.statistics.verdict.verdict`), shown first."""
    from dynid.analysis.statistics.verdict import verdict
    v = verdict(result, validation, **kw)
    _show(args, v.summary())
    return v


def _write_outputs(args, say, result, robot, experiment, validation, asym=None, export=None,
                   physical=None, effects=None, tilt=None):
    """Render every requested output in memory, then write them all or none.

    Each file is written atomically (temp file + rename); if the run is
    interrupted between two files, the ones already written are removed, so a
    report never sits next to a JSON of another run or without its JSON.
    """
    from dynid.provenance import dumps_json
    outputs = []
    the_verdict = _verdict(args, result, validation, robot=robot)
    if args.json:
        doc = result.to_dict()
        doc["verdict"] = the_verdict.to_dict()
        if validation is not None:
            doc["validation"] = validation.to_dict()
        if tilt is not None:
            doc["gravity_tilt"] = tilt.to_dict()
        if asym is not None:
            doc["asymmetric_friction"] = asym.to_dict()
        if export is not None:
            doc["urdf_export"] = export.to_dict()
        if physical is not None:
            doc["physical"] = physical.physical_block()
        if effects is not None:
            doc["effects"] = effects.to_dict()
            if physical is not None:
                doc["physical"]["effects"] = doc["effects"]
        outputs.append((args.json, dumps_json(doc)))
    if export is not None and args.urdf:
        outputs.append((args.urdf, export.text))
    if export is not None and getattr(args, "mjcf", None):
        from dynid.reports.urdf_export import mjcf_of
        outputs.append((args.mjcf, mjcf_of(export, robot)))
    if getattr(args, "csv", None):
        outputs.append((args.csv, result.model.to_frame().to_csv()))
    if args.report:
        from dynid.reports.html import render_idim_report
        extra = []
        if tilt is not None:
            from dynid.reports.html import Section, para
            extra.append(Section("gravity-tilt", "Direction of gravity (base tilt)", para(
                "The robot file's gravity was rotated by the base tilt estimated on the identification "
                "data (Gauss-Newton on the two angles with the base parameters profiled out), and "
                "every result of this report uses the rotated gravity. " + tilt.sentence())))
        if asym is not None:
            from dynid.reports.friction_section import asymmetric_friction_section
            extra.append(asymmetric_friction_section(asym))
        if physical is not None:
            from dynid.reports.physical_section import physical_section
            extra.append(physical_section(physical))
        if effects is not None:
            from dynid.reports.physical_section import effects_section
            extra.append(effects_section(effects))
        if export is not None:
            extra.append(export.section())
        outputs.append((args.report, render_idim_report(result, robot, experiment, validation,
                                                        extra_sections=extra, verdict=the_verdict)))
    commit_outputs(outputs, say)


def commit_outputs(outputs, say):
    """Write ``(path, text)`` pairs all or none (:func:`dynid.outputs.write_all`)."""
    from dynid.outputs import write_all
    write_all(outputs, say)


OUTPUT_OPTIONS = ("json", "report", "csv", "out", "urdf", "mjcf")
#: longest file name (bytes) when the file system does not say
NAME_MAX = 255
#: the largest robot / experiment TOML read for the file names it refers to
_TOML_PEEK_BYTES = 1 << 20


def _same_file(a, b) -> bool:
    """Whether paths ``a`` and ``b`` are one file (symlinks followed, hard links too)."""
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _referenced_files(path):
    """Files a robot or experiment TOML refers to (``urdf``, ``file``), relative to its folder."""
    try:
        if not path.lower().endswith(".toml") or not os.path.isfile(path) \
                or os.path.getsize(path) > _TOML_PEEK_BYTES:
            return []
        import tomllib
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except Exception:           # noqa: BLE001 - the loader reports a bad file properly later
        return []
    found = []
    tables = [doc] + [v for k, v in doc.items() if k == "experiment" and isinstance(v, dict)]
    for tab in tables:
        for key in ("urdf", "file"):
            v = tab.get(key)
            if isinstance(v, str) and v:
                found.append((key, os.path.join(os.path.dirname(path), v)))
    return found


def _input_files(args):
    """``(what, path)`` of every input file the options name (data, validation, robot file)."""
    out = []
    data = getattr(args, "data", None)
    for p in [data] if isinstance(data, str) else (data or []):
        out.append(("the data file", p))
    if getattr(args, "validation", None):
        out.append(("the --validation file", args.validation))
    robot = getattr(args, "robot", None)
    if robot:
        out.append(("the robot file" if args.command == "robot" else "the --robot file", robot))
    for _what, p in list(out):
        for key, ref in _referenced_files(p):
            out.append((f"the file {key} = ... of {p}", ref))
            if "\0" in ref:
                from dynid.errors import InputError
                raise InputError(f"{p}: {key} = {os.path.basename(ref)!r} contains a NUL byte, which no "
                                 f"file name can; fix '{key}' in {p}")
    return out


def check_input_paths(args):
    """Before any computation: input names without NUL bytes, no recording given twice."""
    from dynid.errors import InputError
    inputs = _input_files(args)
    for what, p in inputs:
        if "\0" in p:
            raise InputError(f"{what} {p!r}: the name contains a NUL byte, which no file name can; "
                             f"check how the command line was built")
    data = [p for what, p in inputs if what == "the data file"]
    for i, p in enumerate(data):
        for q in data[:i]:
            if _same_file(p, q):
                extra = "" if p == q else f" (as {q} and {p})"
                raise InputError(f"the data file {p} is given twice{extra}: the same recording counted "
                                 f"twice doubles its weight and proves nothing; give each recording once")
    valid = getattr(args, "validation", None)
    if valid:
        for p in data:
            if _same_file(valid, p):
                raise InputError(f"--validation {valid} is the same file as the data file {p}: validating "
                                 f"on the identification data says nothing about the model; give another "
                                 f"recording, or --holdout SECONDS to hold out the end of this one")


def check_output_paths(args):
    """Before any computation: every output's folder exists and is writable; '-' only for --json;
    no output is an input or another output; names are valid file names."""
    from dynid.errors import InputError
    check_input_paths(args)
    inputs = _input_files(args)
    seen = []
    for opt in OUTPUT_OPTIONS:
        path = getattr(args, opt, None)
        if not path:
            continue
        if path == "-":
            if opt != "json":
                raise InputError(f"--{opt} -: only --json can be written to stdout")
            continue
        if "\0" in path:
            raise InputError(f"--{opt} {path!r}: the name contains a NUL byte, which no file name can; "
                             f"give --{opt} a plain file name")
        folder = os.path.dirname(os.path.abspath(path)) or "."
        name = os.path.basename(os.path.abspath(path))
        try:
            name_max = os.pathconf(folder, "PC_NAME_MAX")
        except (OSError, ValueError):
            name_max = NAME_MAX
        if len(os.fsencode(name)) > name_max:
            raise InputError(f"--{opt} {name[:40]}...: the file name is {len(os.fsencode(name))} bytes "
                             f"long, more than the {name_max} the file system allows; give --{opt} a "
                             f"shorter name")
        if not os.path.isdir(folder):
            raise InputError(f"--{opt} {path}: the folder {folder} does not exist")
        if not os.access(folder, os.W_OK):
            raise InputError(f"--{opt} {path}: the folder {folder} is not writable")
        if os.path.isdir(path):
            raise InputError(f"--{opt} {path} is a folder; give a file name")
        for what, p in inputs:
            if "\0" not in p and os.path.exists(p) and _same_file(path, p):
                how = "" if os.path.abspath(path) == os.path.abspath(p) else " (through a link)"
                raise InputError(f"--{opt} {path} is {what} {p}{how}: writing it would destroy the "
                                 f"input; give --{opt} another path")
        for other, q in seen:
            if _same_file(path, q):
                raise InputError(f"--{other} {q} and --{opt} {path} are the same file: one would "
                                 f"overwrite the other; give each its own path")
        seen.append((opt, path))
    _check_stdout(args)


def _check_stdout(args):
    """--json - needs a standard output to write to (not closed with >&-)."""
    from dynid.errors import InputError
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


def _stdout_failed(args):
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


def _show_clean(args, *texts):
    """:func:`_show` with control characters escaped (names read from files reach summaries)."""
    _show(args, *(clean_text(t) if t else t for t in texts))


def _show(args, *texts):
    """Print human-readable summaries: on stdout, or on stderr when stdout carries the JSON."""
    if args.quiet:
        return
    stream = sys.stderr if getattr(args, "json", None) == "-" else sys.stdout
    print("\n\n".join(t for t in texts if t), file=stream)


def _load_data(args, say, robot, paths):
    """The identification experiments and the validation experiment (or None) of the options."""
    from dynid.analysis.data.experiment import load_experiment
    from dynid.errors import InputError
    experiments = []
    for path in paths:
        experiments.append(load_experiment(path, robot))
        say(f"loaded {path}: {experiments[-1].n_samples} samples at {experiments[-1].fs:g} Hz")
    _check_cutoffs(args, experiments)
    valid = None
    if getattr(args, "validation", None):
        valid = load_experiment(args.validation, robot)
        say(f"validation {args.validation}: {valid.n_samples} samples")
        _check_cutoffs(args, [valid])
    elif getattr(args, "holdout", None) is not None:
        from dynid.analysis.data.split import holdout_split
        if len(experiments) > 1:
            raise InputError("--holdout splits one recording; with several, use --validation")
        train, valid = holdout_split(experiments[0], args.holdout)
        experiments = [train]
    return experiments, valid


def cmd_identify(args, say):
    from dynid.analysis.identify import identify
    from dynid.analysis.statistics.validation import validate
    from dynid.errors import InputError
    if args.method != "idim":
        given = [f"--{o}" for o, v in (("validation", args.validation), ("holdout", args.holdout),
                                       ("urdf", args.urdf), ("asymmetric-friction", args.asymmetric_friction),
                                       ("mjcf", args.mjcf), ("effects", args.effects),
                                       ("physical", args.physical and args.method != "didim"),
                                       ("gravity-tilt", args.gravity_tilt))
                 if v]
        if given:
            raise InputError(f"{', '.join(given)} work with --method idim only, not with --method "
                             f"{args.method}; run the IDIM identification for them")
    if args.v_s is not None and args.method != "didim":
        raise InputError(f"--v-s is the simulated Coulomb friction's sign width of DIDIM; it does not "
                         f"apply to --method {args.method}")
    if args.bootstrap < 0:
        raise InputError(f"--bootstrap must be 0 or more refits, got {args.bootstrap}")
    if not args.physical and (args.prior or args.mass_tolerance is not None):
        raise InputError("--prior and --mass-tolerance are options of --physical")
    if args.physical:
        from dynid.analysis.estimators.physical import require_cvxpy
        require_cvxpy()                      # before any work
    robot = _robot(args)
    say(f"robot '{robot.name}' ({robot.n_joints} joints)")
    candidates = _effect_candidates(args, robot)
    experiments, valid = _load_data(args, say, robot, args.data)
    if args.method in METHODS:
        if len(experiments) > 1:
            raise InputError(f"--method {args.method} identifies one recording at a time")
        return METHODS[args.method](args, say, robot, experiments[0])
    tilt = None
    if args.gravity_tilt:
        from dynid.analysis.estimators.gravity_tilt import gravity_tilt
        say("estimating the direction of gravity (base tilt) on the identification data")
        tilt = gravity_tilt(experiments, robot, settings=_processing_settings(args))
        _show_clean(args, tilt.summary())
        robot = tilt.robot                   # everything below runs with the tilted gravity
    with say.progress("regressor and decimation") as bar:
        result = identify(experiments, robot, settings=_processing_settings(args),
                          max_error_growth=args.max_error_growth, progress=bar.update)
    validation = validate(result, valid, robot) if valid is not None else None
    asym = None
    if args.asymmetric_friction:
        from dynid.analysis.estimators.asymmetric_friction import asymmetric_friction
        if len(experiments) > 1:
            raise InputError("--asymmetric-friction works on one recording at a time")
        asym = asymmetric_friction(experiments[0], robot, result)
    _show_clean(args, result.summary(), validation.summary() if validation is not None else "",
          asym.summary() if asym is not None else "")
    physical = effects = None
    if candidates is not None:
        from dynid.analysis.diagnosis.physical_fit import identify_physical_effects
        say(f"effects beside the rigid body: {args.effects}"
            + ("; physically consistent WLS (SDP)" if args.physical else ""))
        effects = identify_physical_effects(experiments, robot, result, candidates, physical=args.physical,
                                            validation=valid, spec=args.effects, prior=args.prior,
                                            prior_weight=args.prior_weight, mass_tolerance=args.mass_tolerance,
                                            n_boot=args.bootstrap)
        physical = effects.physical
        if physical is not None:
            physical.idim, physical.data_hash = result, getattr(result, "data_hash", "") or ""
            physical.rel_error, physical.wls_rel_error = effects.rel_error_pc, effects.rel_error_wls
            physical.validation = effects.validation
        _show_clean(args, effects.summary(), physical.summary() if physical is not None else "")
    elif args.physical:
        from dynid.analysis.estimators.physical import identify_physical
        say("physically consistent WLS (SDP)")
        physical = identify_physical(result, robot, prior=args.prior, prior_weight=args.prior_weight,
                                     mass_tolerance=args.mass_tolerance, n_boot=args.bootstrap,
                                     which=args.physical_set)
        if valid is not None:
            physical.validation = physical.held_out_block(valid, robot)
        _show_clean(args, physical.summary())
    export = None
    if args.urdf or args.mjcf:
        from dynid.reports.urdf_export import export_urdf
        say("choosing a physically consistent standard parameter set for the URDF/MJCF")
        export = export_urdf(result, robot, physical=physical, effects=effects)
        say(f"URDF: {'consistent' if export.consistent else 'NOT consistent'}; "
            f"{'reproduces the identified values' if export.reproduces else 'does not reproduce the identified values (details in --report / --json)'}")
        if export.springs:
            say("MJCF: with the springs of --effects as joint stiffness: "
                + ", ".join(f"Ks{j} = {k:.4g}" for j, k in export.springs.items()))
    _write_outputs(args, say, result, robot, experiments[0], validation, asym, export, physical, effects,
                   tilt=tilt)
    return EXIT_OK


def _effect_candidates(args, robot):
    """The candidates of ``--effects`` (None without it), refused early with the options they
    do not combine with."""
    from dynid.errors import InputError
    if not getattr(args, "effects", None):
        return None
    from dynid.analysis.diagnosis.physical_fit import effect_candidates
    if args.physical_set != "base":
        raise InputError("--effects fits the effects beside all base parameters: drop --physical-set "
                         f"{args.physical_set}")
    if args.urdf:
        raise InputError("--urdf writes a rigid body, and URDF has no field for the effects of --effects: "
                         "--mjcf PATH writes the rigid body with its springs (MuJoCo joint stiffness), "
                         "or export the URDF from a run without --effects")
    out = effect_candidates(args.effects, robot.n_joints)
    if not out:
        raise InputError(f"--effects {args.effects!r} names no effect; e.g. --effects spring:all")
    if args.mjcf:
        if not args.physical:
            raise InputError("--mjcf with --effects writes the physically consistent rigid body fitted "
                             "with the springs (an unconstrained fit may not be a body MuJoCo accepts, "
                             "and another consistent set does not go with these springs): add --physical")
        other = [f"{c.name} on joint {c.joint}" for c in out if c.name != "spring"]
        if other:
            raise InputError("--mjcf with --effects: MJCF has no field for " + ", ".join(other) +
                             "; only spring (joint stiffness) can be written: drop the others from "
                             "--effects, or drop --mjcf")
    return out


def _write_method_outputs(args, say, result, frame, sections, title, robot=None):
    """Verdict and summary, then JSON / CSV (``frame``) / HTML (``sections``) of a DIDIM, PM or ML result."""
    from dynid.provenance import dumps_json
    from dynid.reports.html import render_sections, verdict_block
    the_verdict = _verdict(args, result, robot=robot)
    _show_clean(args, result.summary())
    outputs = []
    if args.json:
        doc = result.to_dict()
        doc["verdict"] = the_verdict.to_dict()
        outputs.append((args.json, dumps_json(doc)))
    if args.csv:
        outputs.append((args.csv, frame.to_csv()))
    if args.report:
        outputs.append((args.report, render_sections(sections(), title=title,
                                                     highlights=[("verdict", the_verdict.status)],
                                                     verdict=verdict_block(the_verdict))))
    commit_outputs(outputs, say)


def _identify_ml(args, say, robot, exp):
    from dynid.analysis.identify import identify
    from dynid.errors import InputError
    from dynid.reports.projection_section import ml_section
    if args.f0 is None:
        raise InputError("--method ml needs --f0, the fundamental frequency of the periodic excitation")
    say("maximum likelihood (noise on q and tau), from the LS start")
    res = identify(exp, robot, "ml", f0=args.f0, ml_harmonics=args.ml_harmonics)
    _write_method_outputs(args, say, res, res.to_frame(), lambda: [ml_section(res)],
                          f"Maximum-likelihood identification of {robot.name}", robot=robot)
    return EXIT_OK


def _identify_projection(args, say, robot, exp):
    from dynid.analysis.identify import identify
    from dynid.reports.projection_section import projection_section
    say("Projection Method: FIR sensitivity per joint, then two-stage LS")
    res = identify(exp, robot, "projection", settings=_processing_settings(args))
    _write_method_outputs(args, say, res, res.to_frame(), lambda: [projection_section(res)],
                          f"Projection Method identification of {robot.name}", robot=robot)
    return EXIT_OK


def _identify_didim(args, say, robot, exp):
    from dynid.analysis.identify import identify
    from dynid.reports.didim_section import didim_sections
    settings = _processing_settings(args)
    if args.v_s is not None:
        settings["v_s"] = args.v_s
    with say.progress("DIDIM iterations") as bar:
        res = identify(exp, robot, "didim", settings=settings, max_iter=args.max_iter,
                       max_error_growth=args.max_error_growth, gains=args.gains,
                       update_gains=GAIN_UPDATES[args.gain_update], progress=bar.update,
                       physical=args.physical, prior=args.prior, prior_weight=args.prior_weight,
                       mass_tolerance=args.mass_tolerance, n_boot=args.bootstrap)
    if res.gains is not None:
        _show(args, res.gains.summary())
    def sections():
        out = didim_sections(res)
        if res.physical is not None:
            from dynid.reports.physical_section import physical_section
            out.append(physical_section(res.physical))
        return out
    _write_method_outputs(args, say, res, res.model.to_frame(), sections,
                          f"{'PC-' if res.physical is not None else ''}DIDIM identification of {robot.name}",
                          robot=robot)
    if not res.converged:
        print(f"dynid identify: DIDIM did not converge ({res.stop_reason}); the outputs say so",
              file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


METHODS = {"didim": _identify_didim, "projection": _identify_projection, "ml": _identify_ml}


def cmd_simulate(args, say):
    from dynid.analysis.data.synthetic import simulate
    from dynid.provenance import dumps_json
    with say.progress(f"closed-loop simulation ({args.duration:g} s)") as bar:
        sim = simulate(_robot(args), args.duration, seed=args.seed, f0=args.f0, harmonics=args.harmonics,
                       noise_q=args.noise_q, noise_tau=args.noise_tau, progress=bar.update)
    outputs = [(args.out, sim.experiment.to_frame().to_csv(index=False, float_format="%.10g"))]
    if args.json:
        doc = sim.to_dict()
        doc["csv"] = args.out
        outputs.append((args.json, dumps_json(doc)))
    commit_outputs(outputs, say)
    return EXIT_OK


def cmd_sample(args, say):
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.sampling.posterior import sample_idim
    from dynid.errors import InputError
    from dynid.provenance import dumps_json
    if args.physical:
        if args.which != "base":
            raise InputError("--physical samples the base parameters: add --which base")
        from dynid.analysis.estimators.physical import require_cvxpy
        require_cvxpy()
    robot = _robot(args)
    experiments, _ = _load_data(args, say, robot, args.data)
    with say.progress("regressor and decimation") as bar:
        result = identify_idim(experiments if len(experiments) > 1 else experiments[0], robot,
                               settings=_processing_settings(args),
                               max_error_growth=args.max_error_growth, progress=bar.update)
    say(f"sampling the posterior of the {args.which} parameters")
    with say.progress("sampling (steps / steps needed)") as bar:
        post = sample_idim(result, which=args.which, physical=args.physical, robot=robot,
                           seed=args.seed, n_walkers=args.walkers,
                           max_steps=args.max_steps, max_seconds=args.max_seconds,
                           progress=lambda n, need: bar.update(n / max(need, 1)))
    the_verdict = _verdict(args, result, robot=robot)
    _show_clean(args, post.summary())
    outputs = []
    if args.json:
        doc = post.to_dict()
        doc["verdict"] = the_verdict.to_dict()
        outputs.append((args.json, dumps_json(doc)))
    if args.csv:
        outputs.append((args.csv, post.samples_frame().to_csv(index=False, lineterminator="\n",
                                                              float_format="%.17g")))
    if args.report:
        from dynid.reports.bayes_section import bayes_sections
        from dynid.reports.html import render_idim_report
        outputs.append((args.report, render_idim_report(result, robot, experiments[0],
                                                        extra_sections=bayes_sections(post),
                                                        verdict=the_verdict)))
    commit_outputs(outputs, say)
    if not post.converged and not args.allow_unconverged:
        print(f"dynid sample: the chains did not converge ({post.reason}); the outputs say so",
              file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def cmd_excite(args, say):
    from dynid.dynamics.excitation import design_excitation
    from dynid.errors import InputError
    from dynid.provenance import dumps_json
    robot = _robot(args)
    if args.periods < 1:
        raise InputError(f"--periods must be at least 1, got {args.periods}")
    fs = args.fs if args.fs is not None else (robot.controller.rate if robot.controller else 1000.0)
    if not fs > 0:
        raise InputError(f"--fs must be a positive sampling rate in Hz, got {fs:g}")
    if args.f0 > 0 and args.harmonics >= 1:
        top = args.f0 * args.harmonics
        if fs < 10 * top:
            raise InputError(f"--fs {fs:g} Hz is too low for the highest harmonic ({top:g} Hz): a "
                             f"controller reference needs at least 10 samples per period of it "
                             f"(--fs {10 * top:g} or more)")
        rows = fs * args.periods / args.f0
        if rows > 50_000_000:
            raise InputError(f"--fs {fs:g} Hz x --periods {args.periods} would write {rows:.3g} rows; "
                             "lower one of them (at most 50 million rows)")
    if not args.out and not args.json and not args.report:
        say("note: no --out, --json or --report given; only the summary is printed")
    with say.progress(f"excitation design ({args.starts} starts)") as bar:
        res = design_excitation(robot, args.f0, args.harmonics, n_starts=args.starts,
                                criterion=args.criterion, margin=args.margin, rng=args.seed,
                                progress=bar.update)
    _show_clean(args, res.summary())
    outputs = []
    if args.out:
        outputs.append((args.out, res.to_frame(fs, args.periods).to_csv(
            index=False, lineterminator="\n", float_format="%.17g")))
    if args.json:
        doc = res.to_dict()
        doc["csv"] = {"fs": fs, "periods": args.periods} if args.out else None
        outputs.append((args.json, dumps_json(doc)))
    if args.report:
        from dynid.reports.bona_section import excitation_section
        from dynid.reports.html import render_sections
        outputs.append((args.report, render_sections([excitation_section(res, robot)],
                                                     title=f"Excitation design for {robot.name}")))
    commit_outputs(outputs, say)
    if not res.feasible:
        print("dynid excite: no optimised trajectory respected every limit; the outputs hold the "
              "best random start (see the margins)", file=sys.stderr)
    return EXIT_OK


def _effects_option(value):
    from dynid.analysis.diagnosis.effects import check_effect_names
    if not value:
        return None
    names = [x.strip() for x in value.split(",") if x.strip()]
    check_effect_names(names)
    return names


def _check_diagnosis_options(args):
    from dynid.errors import InputError
    alpha = getattr(args, "alpha", 0.01)
    if not 0 < alpha < 1:
        raise InputError(f"--alpha must be between 0 and 1, got {alpha:g}")
    if getattr(args, "max_effects", 3) < 1:
        raise InputError(f"--max-effects must be at least 1, got {args.max_effects}")
    if getattr(args, "holdout", None) is not None and not args.holdout > 0:
        raise InputError(f"--holdout must be a positive number of seconds, got {args.holdout:g}")


def _diagnosis_options(args):
    return dict(effects=_effects_option(getattr(args, "effects", None)),
                max_effects=getattr(args, "max_effects", 3), alpha=getattr(args, "alpha", 0.01),
                no_offsets=getattr(args, "no_offsets", False))


def _run_diagnosis(args, say, robot, experiment, valid, idim_result):
    from dynid.reports.pipeline import run_diagnosis
    return run_diagnosis(experiment, robot, valid, idim_result, settings=_processing_settings(args),
                         max_error_growth=getattr(args, "max_error_growth", 0.02), say=say,
                         **_diagnosis_options(args))


def cmd_diagnose(args, say):
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.provenance import dumps_json
    _check_diagnosis_options(args)
    robot = _robot(args)
    _effects_option(args.effects)          # bad names fail before the long work
    experiments, valid = _load_data(args, say, robot, [args.data])
    experiment = experiments[0]
    result = None
    if not args.no_offsets:
        with say.progress("regressor and decimation") as bar:
            result = identify_idim(experiment, robot, settings=_processing_settings(args),
                                   max_error_growth=args.max_error_growth, progress=bar.update)
    say("scoring candidate effects")
    diag = _run_diagnosis(args, say, robot, experiment, valid, result)
    result = diag.idim if diag.idim is not None else result
    validation = None
    if valid is not None and result is not None:
        from dynid.analysis.statistics.validation import validate
        validation = validate(result, valid, robot)
    the_verdict = (_verdict(args, result, validation, robot=robot, diagnosis=diag)
                   if result is not None else None)
    _show_clean(args, diag.summary())
    outputs = []
    if args.json:
        doc = diag.to_dict()
        if the_verdict is not None:
            doc["verdict"] = the_verdict.to_dict()
        if validation is not None:
            doc["validation"] = validation.to_dict()
        outputs.append((args.json, dumps_json(doc)))
    if args.report:
        from dynid.reports.diagnosis_section import diagnosis_sections
        from dynid.reports.html import render_idim_report
        outputs.append((args.report, render_idim_report(result, robot, experiment, validation,
                                                        extra_sections=diagnosis_sections(diag, robot),
                                                        verdict=the_verdict)))
    commit_outputs(outputs, say)
    return EXIT_OK


def _skip_option(value):
    from dynid.reports.pipeline import check_parts
    return check_parts((value or "").split(","))


def _write_full_report(args, say, out):
    from dynid.provenance import dumps_json
    _show_clean(args, out.summary())
    outputs = []
    if args.report:
        outputs.append((args.report, out.html))
    if args.json:
        outputs.append((args.json, dumps_json(out.to_dict())))
    if getattr(args, "csv", None):
        outputs.append((args.csv, out.result.model.to_frame().to_csv()))
    commit_outputs(outputs, say)
    if out.problems:
        print(f"dynid {args.command}: " + "; ".join(out.problems) + "; the outputs say so", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def cmd_report(args, say):
    from dynid.reports.pipeline import report
    skip = _skip_option(args.skip)
    _check_diagnosis_options(args)
    _effects_option(getattr(args, "effects", None))    # bad names fail before the long work
    out = report(args.data, _robot(args), holdout=getattr(args, "holdout", None),
                 validation=getattr(args, "validation", None), skip=skip,
                 settings=_processing_settings(args), seed=args.seed, max_seconds=args.max_seconds,
                 max_error_growth=args.max_error_growth,
                 gain_update=getattr(args, "gain_update", "initial"), max_iter=getattr(args, "max_iter", 15),
                 diagnosis_options=_diagnosis_options(args), say=say)
    return _write_full_report(args, say, out)


def cmd_demo(args, say):
    from dynid.reports.pipeline import demo
    out = demo(seed=args.seed, duration=args.duration, skip=_skip_option(args.skip),
               max_seconds=args.max_seconds, say=say)
    return _write_full_report(args, say, out)


def cmd_fleet(args, say):
    """dynid fleet CATALOGUE --out STORE: identify on Dask, store, monitor, report."""
    import json as _json

    import dynid.fleet as fleet
    from dynid.analysis.fleet.health import DEFAULT_BASELINE, DEFAULT_FALSE_ALARM_RATE
    from dynid.errors import InputError
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers must be at least 1, got {args.workers}")
    if os.path.exists(args.store) and not os.path.isdir(args.store):
        raise InputError(f"--out {args.store} is a file; the results store is a folder")
    params = [p.strip() for p in args.parameters.split(",") if p.strip()]
    if not params:
        raise InputError("--parameters: name at least one base parameter (Fv, Fc, Fv2 ...)")
    say(f"fleet: {args.catalogue} -> {args.store}"
        + (f" on {args.scheduler}" if args.scheduler else f" on a local cluster of {args.workers or os.cpu_count()} workers"))
    with say.progress("identifying") as bar:
        run = fleet.run(args.catalogue, args.store, scheduler=args.scheduler, workers=args.workers,
                        diagnose=args.diagnose, parameters=params,
                        false_alarm_rate=args.false_alarm_rate or DEFAULT_FALSE_ALARM_RATE,
                        n_baseline=args.baseline or DEFAULT_BASELINE, report=args.report,
                        json=None if args.json in (None, "-") else args.json,
                        progress=lambda done, total: bar.update(done / total))
    say(f"{run.n_recordings} recordings: {run.n_computed} identified, {run.n_skipped} already in the store, "
        f"{len(run.errors)} failed ({run.wall_seconds:.1f} s)")
    for rid, path, msg in run.errors:
        say(f"  failed: {rid} {path}: {msg}")
    for a in run.health.alarms:
        say(f"  ALARM {a.robot_id} joint {a.joint} {a.parameter}: {a.direction} of {100 * a.rel_size:+.1f} % "
            f"since {a.onset_day} (alarm {a.alarm_day})")
    if not run.health.alarms:
        say("  no alarm")
    if args.json == "-":
        from dynid.reports.fleet_report import fleet_json
        print(_json.dumps(fleet_json(run, fleet.read_store(args.store), run.health), indent=1))
    return EXIT_OK


COMMANDS = {"robot": cmd_robot, "simulate": cmd_simulate, "excite": cmd_excite, "identify": cmd_identify,
            "sample": cmd_sample, "diagnose": cmd_diagnose, "report": cmd_report, "demo": cmd_demo,
            "fleet": cmd_fleet}


def _terminate(signum, frame):
    raise KeyboardInterrupt


def main(argv=None):
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:           # --help raises on; a bad option is exit 2, not an exception
        if exc.code in (0, None):
            raise
        return EXIT_INPUT if exc.code == 2 else exc.code
    if args.version:
        from dynid.provenance import versions
        print(f"dynid {versions().get('dynid', '?')}")
        return EXIT_OK
    if not args.command:
        parser.print_help()
        return EXIT_INPUT
    signal.signal(signal.SIGTERM, _terminate)
    say = Reporter(quiet=args.quiet)
    try:
        check_output_paths(args)
        return COMMANDS[args.command](args, say)
    except BrokenPipeError:           # output piped into head & co. (an error for --json -)
        return _stdout_failed(args)
    except KeyboardInterrupt:
        print("dynid: interrupted; no partial output was written", file=sys.stderr)
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
