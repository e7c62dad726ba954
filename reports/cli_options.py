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
  dynid robot tx40                       DH table, standard and base parameters
  dynid robot arm.urdf --json arm.json   the same for a URDF, also as JSON
  dynid robot --list                     the bundled robots
"""
EPILOG_IDENTIFY = """examples:
  dynid identify run.csv --robot tx40 --report out.html --json out.json
  dynid identify run.csv --robot arm.toml --holdout 3      validate on the last 3 s
  dynid identify rec2.toml rec3.toml --robot kuka_lwr4 --validation rec1.toml
  dynid identify run.csv --robot tx40 --method didim --report didim.html
  dynid identify run.csv --robot planar2 --method ml --f0 0.1 --json ml.json
  dynid identify rec1.toml --robot kuka_lwr4 --validation rec2.toml --physical --urdf arm.urdf
"""
EPILOG_SIMULATE = """examples:
  dynid simulate --robot tx40 --out run.csv                    20 s of a random Fourier reference
  dynid simulate --robot tx40 --seed 2 --payload 2,0,0,0.05 --out loaded.csv   carrying 2 kg
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
  dynid report examples/staubli_tx40/experiment.toml --robot tx40 --holdout 3 --skip didim --report tx40.html
  dynid report run.csv --robot tx40 --validation run2.csv --max-seconds 30 --seed 2 --report full.html
"""
EPILOG_DEMO = """examples:
  dynid demo                             simulated TX40 -> identification -> dynid-demo.html
  dynid demo --report demo.html --json demo.json --seed 7
  dynid demo --skip didim,sample,diagnose          IDIM only (10-20 s)
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


def payload_type(text):
    """argparse type of simulate's --payload: KG or KG,X,Y,Z (the centre of mass in m); the ranges are
    the simulation's (dynid.analysis.data.synthetic.add_payload)."""
    try:
        vals = [float(x) for x in str(text).split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (1, 4):
        raise argparse.ArgumentTypeError(f"expected KG or KG,X,Y,Z (mass in kg, centre of mass in m in the last "
                                         f"link's frame), got {text!r}; e.g. --payload 2,0,0,0.05")
    return vals[0] if len(vals) == 1 else (vals[0], tuple(vals[1:]))


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


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Examples kept as written; every option's default shown unless its text gives it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (action.option_strings and action.default not in (None, False, argparse.SUPPRESS, "")
                and "default" not in text and "%(default)" not in text):
            text += " (default: %(default)s)"
        return text


class _HelpAll(argparse.Action):
    """--help-all: this command's help with every option (--help shows the common ones)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        command = parser.prog.split()[-1]
        full = build_parser(full=True)
        sub = next(a for a in full._actions if isinstance(a, argparse._SubParsersAction))
        sub.choices[command].print_help()
        parser.exit()


def _groups(p, full):
    """The option groups of a command, common first: data, method, model, outputs, advanced
    (advanced options are listed by --help-all only)."""
    names = ("data", "method", "model", "outputs", "advanced")
    g = {k: p.add_argument_group(k) for k in names}
    return g, (lambda text: text) if full else (lambda text: argparse.SUPPRESS)


def _add_robot_options(g, adv, positional=False):
    data = g["data"]
    if positional:
        data.add_argument("robot", help="bundled robot name or .toml/.urdf file")
    else:
        data.add_argument("--robot", required=True, help="bundled robot name or .toml/.urdf file")
    g["advanced"].add_argument("--base", metavar="LINK",
                               help=adv("URDF: the link the chain starts from (default: the root)"))
    g["advanced"].add_argument("--tip", metavar="LINK",
                               help=adv("URDF: the link the chain ends at, e.g. one arm of a two-arm robot "
                                        "or a Panda without its fingers (default: the tree must be one chain)"))


def _add_processing_options(g, adv):
    a = g["advanced"]
    a.add_argument("--fc", type=positive_float, metavar="HZ",
                   help=adv("cut-off of the zero-phase filter of q (default: from the data)"))
    a.add_argument("--nd", type=positive_int, metavar="N",
                   help=adv("decimation factor, 1 = none (default: from the data)"))
    a.add_argument("--decimation-cutoff", type=positive_float, metavar="HZ",
                   help=adv("low-pass of the parallel decimation (default 0.8 fs / (2 nd))"))
    a.add_argument("--qd-threshold", type=qd_threshold_type, metavar="RAD_S",
                   help=adv("velocity dead zone: a number, comma-separated per-joint numbers, "
                            "'auto' (default, 1%% of each joint's peak speed) or 0 to keep all rows"))
    a.add_argument("--max-error-growth", type=float, default=0.02, metavar="F",
                   help=adv("essential parameters: largest accepted growth of the relative error "
                            "(default 0.02 = 2%%)"))


def _add_data_options(g, validation=True, resample=True):
    data = g["data"]
    if validation:
        v = data.add_mutually_exclusive_group()
        v.add_argument("--holdout", type=positive_float, metavar="SECONDS",
                       help="identify on all but the last SECONDS, validate on them")
        v.add_argument("--validation", metavar="DATA", help="a second recording to validate on")
    if resample:
        data.add_argument("--resample", action="store_true",
                          help="irregular time steps: interpolate onto a uniform grid at the median step")


#: the names of --gain-update: the keys of dynid.analysis.run.GAIN_UPDATES, which maps them
#: (not imported: the parser starts without the numerical modules; a test checks they agree)
GAIN_UPDATE_CHOICES = ("every", "initial", "none")
#: --uncertainty: dynid.analysis.estimators.least_squares.UNCERTAINTY and its default
#: dynid.analysis.estimators.idim.DEFAULT_UNCERTAINTY (not imported, as above; tested to agree)
UNCERTAINTY_CHOICES = ("classic", "hac", "bootstrap")
UNCERTAINTY_DEFAULT = "bootstrap"
#: --torque-timing: dynid.analysis.data.record.TORQUE_TIMINGS (not imported, as above; tested to agree)
TORQUE_TIMING_CHOICES = ("held", "centred")
JSON_HELP = "write the results as JSON here ('-': to stdout)"
REPORT_HELP = "write the HTML report here"


def _sub(sub, common, name, help, description, epilog):
    return sub.add_parser(name, parents=[common], help=help, description=description, epilog=epilog,
                          formatter_class=HelpFormatter)


def parse_command_line(parser, argv):
    """The options of `argv`, a command's data files allowed before and after its options.

    `dynid identify a.csv --robot tx40 b.csv` names two recordings: the command's own
    parser reads its arguments intermixed (argparse's `parse_intermixed_args`), which the
    top-level parser cannot (it holds the subcommands).
    """
    argv = list(argv)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    first = next((i for i, a in enumerate(argv) if not a.startswith("-")), None)
    if first is None or argv[first] not in sub.choices or any(a != "--version" for a in argv[:first]):
        return parser.parse_args(argv)       # no command, an unknown one, or top-level -h: argparse answers
    args = sub.choices[argv[first]].parse_intermixed_args(argv[first + 1:])
    args.command, args.version = argv[first], "--version" in argv[:first]
    return args


def build_parser(full=False):
    """The parser of every command; `full`: list every option (--help-all), else the common ones."""
    parser = argparse.ArgumentParser(
        prog="dynid",
        description="Identify the dynamic model of a robot arm from measured data, "
                    "and say how far to trust it.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=textwrap.dedent("""\
            --json - writes the machine-readable result to stdout (the summary then goes to stderr);
            COMMAND --help shows a command's common options, COMMAND --help-all every option

            exit codes: 0 ok, 1 internal error, 2 bad input, 3 did not converge, 130 interrupted
            """))
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    common.add_argument("--debug", action="store_true", help="show tracebacks")
    common.add_argument("--help-all", action=_HelpAll, help="show every option of this command")

    p = _sub(sub, common, "robot", "show a robot's kinematics, standard and base parameters",
             "Print a robot's DH table, standard parameters and base parameters with their regrouping "
             "relations.", EPILOG_ROBOT)
    p.add_argument("robot", nargs="?", help="bundled name (tx40, planar2, kuka_lwr4, panda) or .toml/.urdf file")
    p.add_argument("--base", metavar="LINK", help="URDF: the link the chain starts from (default: the root)")
    p.add_argument("--tip", metavar="LINK", help="URDF: the link the chain ends at (default: one chain)")
    p.add_argument("--json", metavar="PATH", help="also write the parameters as JSON")
    p.add_argument("--list", action="store_true", help="list the bundled robots")

    _add_identify_parser(sub, common, full)

    p = _sub(sub, common, "simulate", "simulate a robot in closed loop and write a recording (CSV)",
             "Simulate the robot (a-priori parameters of its robot file) tracking a random Fourier-series "
             "reference under its controller, add sensor noise, and write a dynid CSV (t, q*, qr*, tau*).",
             EPILOG_SIMULATE)
    g, adv = _groups(p, full)
    _add_robot_options(g, adv)
    g["outputs"].add_argument("--out", required=True, metavar="CSV", help="where to write the recording")
    g["outputs"].add_argument("--json", metavar="PATH",
                              help="write the simulation's settings, reference coefficients and true base "
                                   "parameters as JSON ('-': to stdout)")
    m = g["method"]
    m.add_argument("--duration", type=positive_float, default=20.0, metavar="SECONDS", help="length of the run")
    m.add_argument("--f0", type=positive_float, default=0.1, metavar="HZ", help="fundamental of the reference")
    m.add_argument("--harmonics", type=harmonics_type, default=10, metavar="N", help="harmonics of the reference")
    m.add_argument("--noise-q", type=non_negative_float, default=4e-5, metavar="RAD", help="position noise std")
    m.add_argument("--noise-tau", type=non_negative_float, default=0.5, metavar="NM", help="torque noise std")
    m.add_argument("--seed", type=seed_type, default=1, metavar="N", help="random seed")
    m.add_argument("--payload", type=payload_type, metavar="KG[,X,Y,Z]", dest="carried_payload",
                   help="the last link carries a payload: mass (kg) and centre of mass in its frame (m)")

    p = _sub(sub, common, "excite", "design an optimal Fourier excitation trajectory (CSV for a controller)",
             "Optimise the coefficients of a finite Fourier series per joint (fundamental f0, N harmonics) "
             "to minimise the condition number of the base regressor (or -log det), within the robot's "
             "position, velocity, acceleration and torque limits (eq. (20) of Bona & Curatella 2005); "
             "several random starts; every limit checked on a dense grid. Writes the reference "
             "(t, qr, qdr, qddr) as CSV.", EPILOG_EXCITE)
    g, adv = _groups(p, full)
    _add_robot_options(g, adv)
    m = g["method"]
    m.add_argument("--f0", type=positive_float, required=True, metavar="HZ", help="fundamental frequency")
    m.add_argument("--harmonics", type=harmonics_type, required=True, metavar="N", help="harmonics per joint")
    m.add_argument("--criterion", choices=["cond", "logdet"], default="cond",
                   help="cond: condition number; logdet: D-optimality")
    m.add_argument("--starts", type=positive_int, default=4, metavar="N", help="random starts")
    m.add_argument("--margin", type=float, default=0.95, metavar="F",
                   help="fraction of every limit the design may use")
    m.add_argument("--seed", type=seed_type, default=1, metavar="N", help="random seed of the starts")
    o = g["outputs"]
    o.add_argument("--out", metavar="CSV", help="write the reference trajectory here")
    o.add_argument("--fs", type=positive_float, metavar="HZ",
                   help="sampling rate of the CSV (default: the robot's controller rate, else 1000)")
    o.add_argument("--periods", type=int, default=1, metavar="N", help="whole periods in the CSV")
    o.add_argument("--json", metavar="PATH", help="write coefficients, cond(W) and margins as JSON "
                                                  "('-': to stdout)")
    o.add_argument("--report", metavar="PATH", help=REPORT_HELP)

    _add_sample_parser(sub, common, full)
    _add_diagnose_parser(sub, common, full)
    _add_report_parsers(sub, common, full)
    _add_fleet_parser(sub, common)
    _add_payload_parser(sub, common, full)
    return parser


def _add_payload_parser(sub, common, full):
    p = _sub(sub, common, "payload", "identify the payload (or the drive gains with a known one)",
             "Identify the payload a robot carries (mass, first moments, inertia about --frame) from a "
             "recording with it and either an identified robot (--model, the robot-fixed route) or "
             "recordings without it (--unloaded, the global route). With --gains, identify the drive "
             "gains instead, from --unloaded and a payload of known --mass. Guide: docs/payload.md.",
             textwrap.dedent("""\
                 examples:
                   dynid payload --robot tx40 --loaded loaded.toml --model identified.json
                   dynid payload --robot tx40 --loaded loaded.toml --unloaded empty.toml --physical
                   dynid payload --robot tx40 --loaded loaded.toml --unloaded empty.toml --mass 2.5 --gains
                 """))
    g, adv = _groups(p, full)
    g["data"].add_argument("--loaded", dest="data", nargs="+", required=True, metavar="FILE",
                           help="recording(s) with the payload (.toml description or data file)")
    _add_robot_options(g, adv)
    src = g["data"].add_mutually_exclusive_group(required=True)
    src.add_argument("--model", metavar="JSON", help="the identified robot: dynid identify --json output")
    src.add_argument("--unloaded", nargs="+", metavar="FILE", help="recording(s) without the payload")
    m = g["method"]
    m.add_argument("--frame", default="flange",
                   help="link carrying the payload: flange (last link), a joint name or a link number")
    m.add_argument("--gains", nargs="?", const="marked", metavar="JOINTS",
                   help="identify the drive gains from --unloaded and --mass: of the joints the recordings' "
                        "[currents] identify_gains marks (all if none), or of JOINTS (all, or e.g. 1,2,3)")
    m.add_argument("--mass", type=float, metavar="KG", help="the payload's known mass (kg), for --gains")
    m.add_argument("--com", metavar="X,Y,Z", help="--gains: its known centre of mass in the frame (m)")
    m.add_argument("--physical", action="store_true", help="also the physically consistent payload (SDP)")
    m.add_argument("--zoh", action="store_true",
                   help="the torques are commands held over the next sample period (a controller's log): "
                        "centre them on the position samples (every recording; with --model, identify the "
                        "model from centred torques too)")
    m.add_argument("--com-box", metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="--physical: box holding the centre of mass (m); with a negative first value "
                        "write --com-box=-0.1,...")
    o = g["outputs"]
    o.add_argument("--json", metavar="PATH", help=JSON_HELP)
    o.add_argument("--report", metavar="PATH", help="write the result as an HTML section")


def _add_identify_parser(sub, common, full):
    p = _sub(sub, common, "identify", "identify a recording: IDIM (default), DIDIM, Projection Method, ML",
             "Identify the base and essential parameters of a robot from a recording of q and tau (IDIM: "
             "OLS, per-joint WLS, essential parameters), validate, and report; the verdict comes first.",
             EPILOG_IDENTIFY)
    g, adv = _groups(p, full)
    g["data"].add_argument("data", nargs="+", help="recording(s): .csv, .parquet, .npz, .mat, or a .toml "
                                                   "description; several are identified together")
    _add_robot_options(g, adv)
    _add_data_options(g)
    m = g["method"]
    m.add_argument("--method", choices=["idim", "didim", "projection", "ml"], default="idim",
                   help="idim (q, tau); didim (qr or q, tau, a controller); projection (q, qr, tau); "
                        "ml (periodic: --f0)")
    g["advanced"].add_argument("--uncertainty", choices=list(UNCERTAINTY_CHOICES), default=UNCERTAINTY_DEFAULT,
                               help=adv("sigma of IDIM and DIDIM: bootstrap (circular blocks over time), hac "
                                        "(Newey-West), classic (the papers' eqs. (14)-(15), samples independent)"))
    m.add_argument("--f0", type=positive_float, metavar="HZ", help="ML: fundamental of the excitation")
    a = g["advanced"]
    a.add_argument("--ml-harmonics", type=harmonics_type, metavar="K",
                   help=adv("ML: harmonics of the latent trajectory (default: chosen by BIC on q)"))
    a.add_argument("--max-iter", type=int, default=None, metavar="N",
                   help=adv("DIDIM: largest number of Gauss-Newton steps (default: 20)"))
    a.add_argument("--gain-update", choices=list(GAIN_UPDATE_CHOICES), default="initial",
                   help=adv("DIDIM: scale the simulated derivative gains by J_j/J_ap_j (eq. 27) only for "
                            "the first simulation (initial, the default), at every step (every, as the "
                            "paper; it oscillates when the robot file's J_ap is not max M_jj), or never"))
    a.add_argument("--gains", choices=["assumed", "identify"], default="assumed",
                   help=adv("DIDIM: the controller gains of the robot file (assumed, as the paper), or "
                            "identified first from the logged qr, q and tau (the structure, pd or pid, "
                            "from the robot file)"))
    a.add_argument("--didim-start", choices=["idim", "apriori"], default="idim",
                   help=adv("DIDIM: the start: idim (IDIM's estimate with --gains identify, the paper's "
                            "eq. (31) with the assumed gains) or apriori (the robot file's a-priori "
                            "values, projected onto the physically consistent set if needed)"))
    a.add_argument("--torque-timing", choices=list(TORQUE_TIMING_CHOICES), default=None,
                   help=adv("DIDIM: the logged torque is the command held over each period (held, the "
                            "default, as the paper) or centred on the samples (an integrating sensor; "
                            "what dynid simulate logs)"))
    a.add_argument("--v-s", type=_v_s_arg, metavar="RAD_PER_S|auto", dest="v_s",
                   help=adv("DIDIM: velocity over which the simulated Coulomb friction changes sign "
                            "(default auto: the smallest DIDIM residual on a factor-2 walk from 0.05 "
                            "rad/s); smaller values cost more integration substeps"))
    md = g["model"]
    md.add_argument("--gravity-tilt", action="store_true",
                    help="first estimate the direction of gravity (a base tilt) on the identification data")
    md.add_argument("--asymmetric-friction", action="store_true",
                    help="also fit friction with different coefficients for q' > 0 and q' < 0")
    md.add_argument("--physical", action="store_true",
                    help="refit the WLS under physical consistency (an SDP; needs dynid[physical]); "
                         "with --method didim: PC-DIDIM")
    md.add_argument("--effects", metavar="SPEC",
                    help="fit effects beside the rigid body (name:joint[:order]), e.g. spring:all")
    a.add_argument("--prior", choices=["apriori", "geometric"],
                   help=adv("--physical: regularise toward the robot file's a-priori values: 'apriori' by "
                            "the scaled Euclidean distance, 'geometric' by the entropic divergence of each "
                            "link's pseudo-inertia (Lee, Wensing & Park 2020)"))
    a.add_argument("--prior-weight", type=non_negative_float, default=1.0, metavar="W",
                   help=adv("--physical --prior: weight of the a-priori term"))
    a.add_argument("--mass-tolerance", type=non_negative_float, metavar="F",
                   help=adv("--physical: keep each link mass within this fraction of its a-priori value"))
    a.add_argument("--physical-set", choices=["base", "essential"], default="base",
                   help=adv("--physical (IDIM): constrain the WLS of all base parameters or of the essential ones"))
    a.add_argument("--bootstrap", type=int, default=100, metavar="N",
                   help=adv("--physical: bootstrap refits for the %%sigma of the PC fit"))
    o = g["outputs"]
    o.add_argument("--report", metavar="PATH", help=REPORT_HELP)
    o.add_argument("--json", metavar="PATH", help=JSON_HELP)
    o.add_argument("--csv", metavar="PATH", help="write the essential parameters as CSV here (the other parts: --json)")
    o.add_argument("--urdf", metavar="PATH",
                   help="write a URDF of the closest physically consistent set (the summary says "
                        "if it reproduces the identified one)")
    o.add_argument("--mjcf", metavar="PATH", help="write the same set as MuJoCo MJCF (with --effects "
                                                  "spring:...: its springs as joint stiffness)")
    _add_processing_options(g, adv)


def _add_sample_parser(sub, common, full):
    p = _sub(sub, common, "sample", "Bayesian posterior of the identified parameters (emcee)",
             "Identify like 'identify', then sample the posterior of the essential (or base) parameters "
             "and one noise level per joint with emcee, until the chains are 50 autocorrelation times "
             "long. Exit code 3 if they are not.", EPILOG_SAMPLE)
    g, adv = _groups(p, full)
    g["data"].add_argument("data", nargs="+", help="recording(s), as for 'identify'")
    _add_robot_options(g, adv)
    _add_data_options(g, validation=False)
    m = g["method"]
    m.add_argument("--which", choices=["essential", "base"], default="essential",
                   help="the parameters to sample")
    m.add_argument("--noise", choices=["sandwich", "neff", "white"], default="sandwich",
                   help="noise model of the likelihood: sandwich (its curvature matched to the robust "
                        "covariance of the fit, the intervals of --uncertainty bootstrap), neff (each "
                        "joint's rows count as its residual's effective sample size) or white "
                        "(independent rows)")
    m.add_argument("--seed", type=seed_type, default=1, metavar="N", help="random seed of the sampler")
    m.add_argument("--max-seconds", type=positive_float, default=None, metavar="S",
                   help="wall-clock safety limit of the sampler (default: none; the sampler stops on "
                        "its step budget, so the output depends only on the seed)")
    g["model"].add_argument("--physical", action="store_true",
                            help="with --which base: sample on the physically consistent set (one "
                                 "feasibility SDP per point, needs dynid[physical])")
    a = g["advanced"]
    a.add_argument("--walkers", type=positive_int, default=None, metavar="N",
                   help=adv("emcee walkers (default: max(64, 2 x dimensions + 2))"))
    a.add_argument("--max-steps", type=positive_int, default=200_000, metavar="N",
                   help=adv("most steps of every walker"))
    a.add_argument("--allow-unconverged", action="store_true",
                   help=adv("exit 0 even if the chains did not converge (the outputs still say so)"))
    o = g["outputs"]
    o.add_argument("--report", metavar="PATH", help=REPORT_HELP)
    o.add_argument("--json", metavar="PATH", help="write the posterior summary as JSON here ('-': to stdout)")
    o.add_argument("--csv", metavar="PATH", help="write the posterior samples as CSV here")
    _add_processing_options(g, adv)


def _add_diagnose_parser(sub, common, full):
    p = _sub(sub, common, "diagnose", "find the effects the model lacks in the residual, add them, compare",
             "Identify like 'identify', then look for effects the model lacks (offsets, asymmetric or "
             "Stribeck friction, position ripple, springs, couplings, time delay, drift, load-dependent "
             "friction, payload): rank them by blocked cross-validation and a likelihood-ratio test, "
             "add those that pass, and report the errors before and after.", EPILOG_DIAGNOSE)
    g, adv = _groups(p, full)
    # nargs="+": a second recording gets the diagnosis' own message, not argparse's "unrecognized arguments"
    g["data"].add_argument("data", nargs="+", metavar="data",
                           help="one recording (.csv, .parquet, .npz, .mat, or .toml description)")
    _add_robot_options(g, adv)
    _add_data_options(g)
    m = g["method"]
    m.add_argument("--effects", metavar="LIST", help="comma-separated effects to consider (default: all)")
    m.add_argument("--max-effects", type=int, default=3, metavar="N", help="most effects added")
    m.add_argument("--alpha", type=float, default=0.01, metavar="P",
                   help="family-wise level of the test at each step")
    m.add_argument("--no-offsets", action="store_true",
                   help="remove the torque offsets Off_j from the model first (to test for them)")
    o = g["outputs"]
    o.add_argument("--report", metavar="PATH", help=REPORT_HELP)
    o.add_argument("--json", metavar="PATH", help=JSON_HELP)
    _add_processing_options(g, adv)


def _add_report_parsers(sub, common, full):
    p = _sub(sub, common, "report", "everything at once: IDIM, DIDIM, posterior and diagnosis in one report",
             "Run every analysis the data and the robot file allow and write one HTML report: IDIM (OLS, "
             "WLS, essential parameters, validation), DIDIM (if the robot has a controller), the Bayesian "
             "posterior of the essential parameters, and the residual diagnosis. Exit code 3 if DIDIM or "
             "the sampler did not converge (the report says so).", EPILOG_REPORT)
    g, adv = _groups(p, full)
    g["data"].add_argument("data", nargs="+", help="recording(s), as for 'identify'")
    _add_robot_options(g, adv)
    _add_data_options(g)
    m = g["method"]
    m.add_argument("--skip", metavar="LIST", action="append", default=None,
                   help="parts to leave out, comma-separated or repeated: didim, sample, diagnose")
    m.add_argument("--seed", type=seed_type, default=1, metavar="N", help="random seed of the sampler")
    m.add_argument("--max-seconds", type=positive_float, default=None, metavar="S",
                   help="wall-clock safety limit of the sampler (default: none; the sampler stops on "
                        "its step budget, so the output depends only on the seed)")
    m.add_argument("--payload", nargs="+", metavar="FILE",
                   help="recording(s) with a payload: identify it with the robot fixed to this report's "
                        "model and add its section (docs/payload.md)")
    a = g["advanced"]
    a.add_argument("--max-iter", type=int, default=20, metavar="N",
                   help=adv("DIDIM: largest number of Gauss-Newton steps (default: 20)"))
    a.add_argument("--gain-update", choices=list(GAIN_UPDATE_CHOICES), default="initial",
                   help=adv("DIDIM's derivative-gain update (see identify --help-all); initial: the "
                            "paper's every-step update oscillated on the demo data"))
    a.add_argument("--torque-timing", choices=list(TORQUE_TIMING_CHOICES), default=None,
                   help=adv("DIDIM: the logged torque is held over each period (the default) or centred "
                            "on the samples (see identify --help-all)"))
    o = g["outputs"]
    o.add_argument("--report", metavar="PATH", required=True, help=REPORT_HELP)
    o.add_argument("--json", metavar="PATH", help=JSON_HELP)
    _add_processing_options(g, adv)

    p = _sub(sub, common, "demo", "simulate the TX40, identify it and write an HTML report",
             "Simulate the Staubli TX40 in closed loop with the parameters of Table 2 of Gautier, Janot, "
             "Vandanjon (2010), 5 kHz torque and position noise, identify it (IDIM; DIDIM from torque and "
             "reference only; the Bayesian posterior; the residual diagnosis), validate on a second "
             "trajectory and write an HTML report. --skip leaves parts out.", EPILOG_DEMO)
    g, adv = _groups(p, full)
    m = g["method"]
    m.add_argument("--seed", type=seed_type, default=1, metavar="N",
                   help="random seed of the noise and trajectories")
    m.add_argument("--duration", type=positive_float, default=20.0, metavar="SECONDS",
                   help="length of the identification recording")
    m.add_argument("--skip", metavar="LIST", action="append", default=None,
                   help="parts to leave out, comma-separated or repeated: didim, sample, diagnose")
    m.add_argument("--max-seconds", type=positive_float, default=None, metavar="S",
                   help="wall-clock safety limit of the sampler (default: none; the sampler stops on "
                        "its step budget, so the output depends only on the seed)")
    a = g["advanced"]
    a.add_argument("--max-iter", type=int, default=20, metavar="N",
                   help=adv("DIDIM: largest number of Gauss-Newton steps (default: 20)"))
    a.add_argument("--gain-update", choices=list(GAIN_UPDATE_CHOICES), default="initial",
                   help=adv("DIDIM's derivative-gain update (see identify --help-all)"))
    o = g["outputs"]
    o.add_argument("--report", metavar="PATH", default="dynid-demo.html", help="HTML report path")
    o.add_argument("--json", metavar="PATH", help=JSON_HELP)


def _add_fleet_parser(sub, common):
    """The `fleet` command (its own function, so that its options stay together)."""
    p = sub.add_parser("fleet", parents=[common], help="identify a fleet's recordings on Dask, watch friction",
                       description="Identify every new or changed recording of a fleet catalogue (IDIM, one "
                                   "Dask task per recording) into a Parquet results store, then monitor "
                                   "each robot's friction (temperature-compensated, two-sided CUSUM) and "
                                   "raise alarms naming robot, joint, parameter, onset and size. Needs "
                                   "the fleet extra (Dask distributed and pyarrow: pip install "
                                   '".[fleet]" in the source folder). Formats: docs/formats.md.',
                       epilog=textwrap.dedent("""\
                           examples:
                             dynid fleet catalogue.csv --out store/ --report fleet.html --json fleet.json
                             dynid fleet catalogue.csv --out store/ --workers 2 --parameters Fv,Fc,Ia
                             dynid fleet catalogue.parquet --out store/ --scheduler tcp://head:8786

                           A rerun computes only the recordings that are new or changed; failed
                           recordings are listed and stored with their error, the rest goes on.
                           """), formatter_class=HelpFormatter)
    p.add_argument("catalogue", help="fleet catalogue (.csv or .parquet): robot_id, timestamp, path, robot "
                                     "[, temperature | temperature1..N]")
    p.add_argument("--out", dest="store", metavar="STORE", required=True,
                   help="results store folder (created; a rerun computes only what is missing or changed)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. tcp://host:8786 "
                                                          "(default: a local cluster on this machine)")
    p.add_argument("--workers", type=int, metavar="N", help="local cluster: worker processes (default: cores)")
    p.add_argument("--parameters", default="Fv,Fc", metavar="LIST",
                   help="base parameters to monitor, by family (Fv: every joint's) or name (Fv2)")
    p.add_argument("--false-alarm-rate", type=float, default=None, metavar="P",
                   help="accepted false alarms per monitored parameter and recording (default 1e-4)")
    p.add_argument("--baseline", type=int, default=None, metavar="N",
                   help="the first N recordings of each robot are its healthy baseline (default 8)")
    p.add_argument("--diagnose", action="store_true", help="also run the residual diagnosis per recording")
    p.add_argument("--report", metavar="PATH", help="write the fleet's HTML report here")
    p.add_argument("--json", metavar="PATH", help="write the fleet's results and alarms as JSON here ('-': stdout)")
