"""How much longer the residual diagnosis takes than the identification it starts from.

A 20 s, 5 kHz closed-loop recording of the simulated TX40 (`dynid simulate --robot tx40`,
seed 1) is identified and diagnosed by the command line, each in a fresh process, with
the last 3 s held out:

    dynid identify run.csv --robot tx40 --holdout 3 --json out.json
    dynid diagnose run.csv --robot tx40 --holdout 3 --json out.json

alternately, three times each. The figure is the ratio of the medians of the CPU time
(user + system of the child, what a user pays on a loaded machine) and, beside it, of
the wall time. Both commands pay the same start-up (imports, loading, processing), so
the ratio is the cost of the diagnosis itself over one identification. Goal: <= 2.

Start-up as an installed dynid has it: the children write and reuse their bytecode (in a
cache folder of their own, `PYTHONPYCACHEPREFIX`, whatever `PYTHONDONTWRITEBYTECODE` says),
after one untimed run of each command. Compiling some 100 modules on every start costs
both commands the same ~0.8 s of CPU (measured), which would pull the ratio towards 1
(2.38 against 2.64 at one measurement); `--bytecode none` keeps the environment as it is.

The last line is a JSON object with `ratio_diagnose_to_identify` (CPU) and the times.
Run from the repository root: python benchmarks/diagnosis_speed.py [--repeats N]
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def dynid_command(python=sys.executable):
    """The `dynid` script beside `python` (default: this interpreter), else `python -m` the CLI module."""
    script = Path(python).with_name("dynid")
    return [str(script)] if script.exists() else [python, "-m", "dynid.reports.cli"]


def timed(cmd, cwd, env=None):
    """(cpu seconds, wall seconds) of one child process running ``cmd``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bytecode", choices=("cached", "none"), default="cached",
                    help="cached (default): the children reuse their compiled bytecode, after one "
                         "untimed run of each command; none: the environment as it is")
    args = ap.parse_args(argv)
    dynid = dynid_command()
    print(f"diagnose / identify on a 20 s, 5 kHz simulated TX40 recording, {os.cpu_count()} CPUs, "
          f"median of {args.repeats}, bytecode {args.bytecode}")
    with tempfile.TemporaryDirectory() as d:
        env = None
        if args.bytecode == "cached":
            env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
            env["PYTHONPYCACHEPREFIX"] = str(Path(d) / "pycache")
        subprocess.run(dynid + ["simulate", "--robot", "tx40", "--out", "run.csv", "--seed", str(args.seed),
                                "--quiet"], cwd=d, check=True, env=env)
        common = ["run.csv", "--robot", "tx40", "--holdout", "3", "--json", "out.json", "--quiet"]
        runs = {"identify": [], "diagnose": []}
        if args.bytecode == "cached":
            for name in runs:                  # compiles what each command imports (cvxpy: diagnose)
                timed(dynid + [name] + common, d, env)
        for _ in range(args.repeats):
            for name in runs:                  # alternate, so drifts in machine load hit both
                runs[name].append(timed(dynid + [name] + common, d, env))
                print(f"  {name:9s} cpu {runs[name][-1][0]:7.1f} s   wall {runs[name][-1][1]:7.1f} s")
    med = {name: (statistics.median(c for c, _ in r), statistics.median(w for _, w in r))
           for name, r in runs.items()}
    ratio_cpu = med["diagnose"][0] / med["identify"][0]
    ratio_wall = med["diagnose"][1] / med["identify"][1]
    print(f"median cpu: identify {med['identify'][0]:.1f} s, diagnose {med['diagnose'][0]:.1f} s, "
          f"ratio {ratio_cpu:.2f} (wall ratio {ratio_wall:.2f}); goal <= 2")
    print(json.dumps({"ratio_diagnose_to_identify": round(ratio_cpu, 3), "ratio_wall": round(ratio_wall, 3),
                      "identify_cpu_s": round(med["identify"][0], 2), "diagnose_cpu_s": round(med["diagnose"][0], 2),
                      "identify_wall_s": round(med["identify"][1], 2), "diagnose_wall_s": round(med["diagnose"][1], 2),
                      "cpu_runs": {k: [round(c, 2) for c, _ in v] for k, v in runs.items()},
                      "repeats": args.repeats, "bytecode": args.bytecode}))


if __name__ == "__main__":
    main()
