"""How long `dynid demo` takes: CPU (user + system) and wall time of the README's command.

Each run is a fresh child process writing the HTML report into a temporary folder:

    dynid demo --seed 1 --report dynid-demo.html --quiet

With ``--reference PYTHON`` (an interpreter whose environment has another version of
dynid installed, e.g. a worktree of an earlier commit), the two are run alternately, so
both see the same machine load, and the figures are the ratio of the medians (this / the
reference) and the median of each run's ratio to the reference run right after it (the
machine's speed drifts over minutes): the back-to-back before/after of issue 30. The README's stated demo time
comes from this script.

With ``--cold``, one more run first with an empty numba cache (``NUMBA_CACHE_DIR`` a new
folder): the first demo after installing dynid, which compiles the numba kernels once
(`demo_cold_cpu_s`, `demo_cold_wall_s`).

The last line is a JSON object with `demo_cpu_s`, `demo_wall_s` (medians) and, with a
reference, `reference_cpu_s`, `reference_wall_s`, `ratio_cpu` and `ratio_cpu_paired` (the
median of each run's ratio to the reference run right after it).

Run from the repository root:

    python benchmarks/demo_time.py [--repeats N] [--cold] [--reference /path/to/other/.venv/bin/python]
"""
import argparse
import json
import os
import statistics
import sys
import tempfile

from diagnosis_speed import dynid_command, timed  # one child process, timed the same way


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=1, help="runs of each interpreter (default 1)")
    ap.add_argument("--reference", help="another interpreter with dynid installed, run alternately")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cold", action="store_true", help="first one run with an empty numba cache (a fresh install)")
    args = ap.parse_args(argv)
    runs = {"this": dynid_command(sys.executable)}
    if args.reference:
        runs["reference"] = dynid_command(args.reference)
    times = {name: [] for name in runs}
    load = os.getloadavg()[0]
    cold = None
    with tempfile.TemporaryDirectory() as d:
        if args.cold:
            env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(d, "numba-cache"))
            cold = timed(runs["this"] + ["demo", "--seed", str(args.seed), "--report", "dynid-demo.html",
                                         "--quiet"], d, env=env)
            print(f"  cold      CPU {cold[0]:6.1f} s  wall {cold[1]:6.1f} s  (empty numba cache)", flush=True)
        for _ in range(args.repeats):
            for name, cmd in runs.items():
                cpu, wall = timed(cmd + ["demo", "--seed", str(args.seed), "--report", "dynid-demo.html",
                                         "--quiet"], d)
                times[name].append((cpu, wall))
                print(f"  {name:9s} CPU {cpu:6.1f} s  wall {wall:6.1f} s", flush=True)
    med = {name: (statistics.median(c for c, _ in ts), statistics.median(w for _, w in ts))
           for name, ts in times.items()}
    out = {"demo_cpu_s": round(med["this"][0], 1), "demo_wall_s": round(med["this"][1], 1),
           "repeats": args.repeats, "cpus": os.cpu_count(),
           "load_before": round(load, 1), "load_after": round(os.getloadavg()[0], 1)}
    if cold is not None:
        out.update(demo_cold_cpu_s=round(cold[0], 1), demo_cold_wall_s=round(cold[1], 1))
    print(f"dynid demo --seed {args.seed}: CPU {out['demo_cpu_s']} s, wall {out['demo_wall_s']} s "
          f"(median of {args.repeats}; load {out['load_before']} -> {out['load_after']} on {out['cpus']} CPUs)")
    if args.reference:
        # each run beside the reference run right after it: the machine's speed drifts over minutes
        paired = [a[0] / b[0] for a, b in zip(times["this"], times["reference"])]
        out.update(reference_cpu_s=round(med["reference"][0], 1), reference_wall_s=round(med["reference"][1], 1),
                   ratio_cpu=round(med["this"][0] / med["reference"][0], 3),
                   ratio_cpu_paired=round(statistics.median(paired), 3))
        print(f"reference ({args.reference}): CPU {out['reference_cpu_s']} s, wall {out['reference_wall_s']} s; "
              f"ratio CPU this / reference {out['ratio_cpu']} (median of the run-by-run ratios "
              f"{out['ratio_cpu_paired']}: {', '.join(f'{r:.3f}' for r in paired)})")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
