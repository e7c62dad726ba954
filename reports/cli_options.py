"""The command line's options: argument types, the parser of every subcommand, and the
mapping of the parsed options to the orchestrator's Settings (dynid.analysis.run).

Kept free of the numerical modules: `dynid --help` and argument errors answer at once,
and the command's signal handler is in place before the heavy imports (reports.cli).
"""
from __future__ import annotations

import argparse
import math
import textwrap

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


def _number(text):
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


#: the names of --gain-update: the keys of dynid.analysis.run.GAIN_UPDATES, which maps them
#: (not imported: the parser starts without the numerical modules; a test checks they agree)
GAIN_UPDATE_CHOICES = ("every", "initial", "none")
JSON_HELP = "write the results as JSON here ('-': to stdout)"


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
    p.add_argument("--gain-update", choices=list(GAIN_UPDATE_CHOICES), default="every",
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
    p.add_argument("--gain-update", choices=list(GAIN_UPDATE_CHOICES), default="initial",
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
    p.add_argument("--gain-update", choices=list(GAIN_UPDATE_CHOICES), default="initial",
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


