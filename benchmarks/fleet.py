"""Benchmark of the fleet: 200 robots x 30 days identified on Dask, friction wear detected.

1. A simulated fleet (simulate_fleet of tests/support/simulated_fleet.py: planar2 at 200 Hz, one 9 s
   pick-and-place recording per robot and day, friction spread, daily temperature
   cycles, wear on one joint of 30 % of the robots from a random day on, a few
   corrupted logs) is written to a temporary folder, simulated on the cluster.
2. Scaling: the same subset of recordings is identified on a LocalCluster of 1
   worker (the reference, run first in this process) and of 2 workers, each
   warmed up first, into fresh stores; throughput = recordings / wall time. Dask's
   per-task overhead = (workers x wall - sum of the task times) / tasks, as a
   fraction of the mean task time (it includes the client writing each result).
3. The whole fleet is identified on the 2-worker cluster (dynid.fleet.run's
   engine) and monitored (Page's CUSUM on the temperature-compensated Fv, Fc);
   the alarms are scored against the simulated truth:
   - a worn joint (friction +20 % or more) is detected if an alarm on it (Fv or Fc,
     increase) fires at most 3 days after its onset and not before;
   - every other alarm is false; the rate is per 100 robot-months (30 days);
   - every corrupted log must be reported as an error of its recording.
4. The fleet report (HTML + JSON) is written, its size and time measured.
5. Held-out fleets: the detector's false-alarm rate (the factor below the nominal
   budget) was chosen on the fleet of seed 2026; fleets of other seeds
   (--eval-seeds, default 7,8, --eval-robots each) are simulated, identified and
   scored with the same settings; the rates per seed and pooled over the held-out
   seeds are in the JSON ("per_seed", "held_out_false_alarms_per_100_robot_months").

Targets: detection >= 90 %, false alarms <= 1 per 100 robot-months, corrupted
logs all reported, 2-worker / 1-worker throughput >= 1.6.
The last line is a JSON object with the figures.
Run from the repository root: python benchmarks/fleet.py [--robots 200 --days 30] [--quick]
"""
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "support"))      # simulated_fleet.py: the test fleet (Dask workers inherit the path)

import numpy as np
import pandas as pd


def score(health, truth, n_days, start):
    """(detected fraction, delays, false alarms, details) of the alarms against the truth."""
    worn = {(r.robot_id, r.worn_joint): r for r in truth.itertuples() if r.worn_joint}
    first = {}
    false = []
    for a in health.alarms:
        day = (pd.Timestamp(a.alarm_day, tz="UTC") - start.normalize()).days
        w = worn.get((a.robot_id, a.joint))
        if w is not None and a.direction == "increase" and day >= w.onset_day:
            first[(a.robot_id, a.joint)] = min(first.get((a.robot_id, a.joint), day), day)
        else:
            false.append(a)
    delays = {k: first[k] - w.onset_day for k, w in worn.items() if k in first}
    detected = sum(1 for d in delays.values() if d <= 3)
    return detected / max(1, len(worn)), delays, false, len(worn)


def timed_run(client, specs, store_dir):
    from dynid.analysis.fleet.engine import execute
    from dynid.analysis.fleet.store import ResultStore
    t0 = time.perf_counter()
    results, _ = execute(specs, ResultStore(store_dir), client)
    wall = time.perf_counter() - t0
    return (wall, float(np.nansum([r["task_seconds"] for r in results])),
            float(np.nansum([r["task_cpu_seconds"] for r in results])))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--robots", type=int, default=200)
    ap.add_argument("--days", type=int, default=30)
    ap.add_argument("--scaling-tasks", type=int, default=300)
    ap.add_argument("--quick", action="store_true", help="20 robots x 30 days, 100 scaling tasks")
    ap.add_argument("--keep", help="folder to keep the fleet, store and report in (default: temporary)")
    ap.add_argument("--reuse", action="store_true",
                    help="with --keep: reuse the simulated fleet already there (its stores are recomputed)")
    ap.add_argument("--reuse-store", action="store_true",
                    help="with --keep --reuse: keep the fleet's main store too (step 3 then computes nothing)")
    ap.add_argument("--scaling-only", action="store_true",
                    help="with --keep --reuse: only the scaling measurement (step 2), e.g. again on a quieter machine")
    ap.add_argument("--eval-seeds", type=lambda v: [int(x) for x in v.split(",") if x], default=[7, 8],
                    help="seeds of held-out fleets the detector is evaluated on (its rate was chosen on 2026)")
    ap.add_argument("--eval-robots", type=int, default=50, help="robots of each held-out fleet")
    args = ap.parse_args()
    if args.quick:
        args.robots, args.scaling_tasks = 20, 100
    from distributed import Client, LocalCluster
    from simulated_fleet import START, simulate_fleet

    from dynid.analysis.fleet.engine import identify_fleet, plan
    from dynid.analysis.fleet.health import monitor
    from dynid.analysis.fleet.store import ResultStore
    from dynid.analysis.fleet.task import identify_recording
    from dynid.reports.fleet_report import write_fleet_outputs

    t_all = time.perf_counter()
    tmp = tempfile.TemporaryDirectory() if not args.keep else None
    root = Path(args.keep or tmp.name)
    kw = {"n_workers": 2, "threads_per_worker": 1, "processes": True, "dashboard_address": ":0",
          "silence_logs": 40}
    with LocalCluster(**kw) as cluster2, Client(cluster2) as client2:
        t0 = time.perf_counter()
        if args.reuse:      # the same fleet again (same seed), without writing its recordings
            import shutil
            for old in ("store-1", "store-2") + (() if args.scaling_only or args.reuse_store else ("store",)):
                shutil.rmtree(root / old, ignore_errors=True)
            fleet = simulate_fleet(root / "fleet", args.robots, args.days, seed=2026,
                                   n_corrupted=max(3, args.robots // 20), client=client2, write=False)
        else:
            fleet = simulate_fleet(root / "fleet", args.robots, args.days, seed=2026,
                                   n_corrupted=max(3, args.robots // 20), client=client2)
        t_sim = None if args.reuse else time.perf_counter() - t0
        print(f"simulated {args.robots} x {args.days} recordings in "
              f"{'(reused)' if t_sim is None else f'{t_sim:.1f}'} s "
              f"({(fleet.robots.worn_joint > 0).sum()} worn robots, {len(fleet.corrupted)} corrupted logs)",
              flush=True)
        specs, _ = plan(fleet.catalogue, ResultStore(root / "none"))
        good = [s for s in specs if s["path"] not in set(fleet.corrupted)]
        subset = good[:args.scaling_tasks]
        missing = [s["path"] for s in subset if not Path(s["path"]).exists()]
        if missing:         # timing tasks that only report "file not found" would measure nothing
            raise SystemExit(f"{len(missing)} of the {len(subset)} scaling recordings are missing (e.g. "
                             f"{missing[0]}); run without --reuse to simulate the fleet again")
        warm = good[-4:]
        # reference: 1 worker, run first
        with LocalCluster(**{**kw, "n_workers": 1}) as cluster1, Client(cluster1) as client1:
            client1.gather(client1.map(identify_recording, warm, pure=False))
            wall1, busy1, cpu1 = timed_run(client1, subset, root / "store-1")
        client2.gather(client2.map(identify_recording, warm * 2, pure=False))
        wall2, busy2, cpu2 = timed_run(client2, subset, root / "store-2")
        thr1, thr2 = len(subset) / wall1, len(subset) / wall2
        mean_task = busy2 / len(subset)
        overhead2 = (2 * wall2 - busy2) / len(subset) / mean_task
        overhead1 = (wall1 - busy1) / len(subset) / (busy1 / len(subset))
        print(f"load average {os.getloadavg()}, task CPU {1e3 * cpu1 / len(subset):.1f} ms (1 worker) "
              f"{1e3 * cpu2 / len(subset):.1f} ms (2 workers)", flush=True)
        print(f"scaling on {len(subset)} recordings: 1 worker {thr1:.2f}/s, 2 workers {thr2:.2f}/s, "
              f"ratio {thr2 / thr1:.2f}; mean task {1e3 * mean_task:.1f} ms, Dask overhead per task "
              f"{100 * overhead1:.1f} % (1 worker), {100 * overhead2:.1f} % (2 workers)", flush=True)
        if args.scaling_only:
            print(json.dumps({"scaling_ratio_2_vs_1": round(thr2 / thr1, 3), "throughput_1_worker_per_s": round(thr1, 3),
                              "throughput_2_workers_per_s": round(thr2, 3), "scaling_tasks": len(subset),
                              "dask_overhead_fraction_1_worker": round(overhead1, 4),
                              "dask_overhead_fraction_2_workers": round(overhead2, 4),
                              "mean_task_cpu_ms": round(1e3 * cpu2 / len(subset), 2),
                              "load_average_1min": round(os.getloadavg()[0], 2),
                              "wall_seconds": round(time.perf_counter() - t_all, 1)}))
            return
        # the whole fleet
        t0 = time.perf_counter()
        run = identify_fleet(fleet.catalogue, root / "store", client=client2)
        t_ident = time.perf_counter() - t0
        print(f"identified {run.n_computed} recordings in {t_ident:.1f} s ({run.n_computed / t_ident:.1f}/s), "
              f"{len(run.errors)} errors", flush=True)
        t0 = time.perf_counter()
        rerun = identify_fleet(fleet.catalogue, root / "store", client=client2)
        t_rerun = time.perf_counter() - t0
        # held-out fleets: other seeds than the one the false-alarm rate below was chosen on
        held_out = []
        for seed in args.eval_seeds:
            t0 = time.perf_counter()
            folder = root / f"fleet-seed{seed}"
            other = simulate_fleet(folder, args.eval_robots, args.days, seed=seed,
                                   n_corrupted=max(3, args.eval_robots // 20), client=client2,
                                   write=not (args.reuse and (folder / "catalogue.csv").exists()))
            if not args.reuse_store:
                import shutil
                shutil.rmtree(root / f"store-seed{seed}", ignore_errors=True)
            identify_fleet(other.catalogue, root / f"store-seed{seed}", client=client2)
            held_out.append((seed, other, time.perf_counter() - t0))
            print(f"held-out fleet seed {seed}: {args.eval_robots} x {args.days} simulated and identified in "
                  f"{held_out[-1][2]:.0f} s", flush=True)
    frame = ResultStore(root / "store").read()
    t0 = time.perf_counter()
    n_series = 2 * 2      # planar2: Fv, Fc of 2 joints
    # the false-alarm budget, 1 per 100 robot-months spread over the series and days, asked for
    # 10 times lower: the CUSUM's threshold assumes Gaussian standardised values, and identified
    # friction has heavier tails (a recording whose cycle separates Fv from Fc badly); at the
    # nominal budget the measured rate was about 2.5 per 100 robot-months. This factor was chosen
    # on the fleet of seed 2026 (200 x 30): the held-out seeds (--eval-seeds) test it.
    rate = 0.1 / 100 / (n_series * 30)
    health = monitor(frame, false_alarm_rate=rate)
    t_health = time.perf_counter() - t0
    run.health = health
    t0 = time.perf_counter()
    write_fleet_outputs(run, frame, html=root / "fleet.html", json_path=root / "fleet.json")
    t_report = time.perf_counter() - t0
    html_kb = os.path.getsize(root / "fleet.html") / 1e3
    detected, delays, false, n_worn = score(health, fleet.robots, args.days, START)
    robot_months = args.robots * args.days / 30
    # reported = stored as an error of its recording (by this run or, with --reuse-store, an earlier one)
    failed = frame[frame["status"] != "ok"].drop_duplicates("key")
    err_paths = set(failed["recording"])
    reported = sum(1 for p in fleet.corrupted if p in err_paths)
    print(f"health: {len(health.alarms)} alarms, threshold h = {health.threshold:.2f}; worn joints detected "
          f"within 3 days {100 * detected:.1f} % of {n_worn}; delays (days) "
          f"{dict(pd.Series(list(delays.values())).value_counts().sort_index())}; "
          f"false alarms {len(false)} ({100 * len(false) / robot_months:.2f} per 100 robot-months); "
          f"corrupted logs reported {reported}/{len(fleet.corrupted)}; temperature coefficients "
          f"{ {k: round(v, 4) for k, v in health.temperature_coefficients.items()} } (simulated -0.008)",
          flush=True)
    for a in false:
        print(f"  false alarm: {a.robot_id} joint {a.joint} {a.parameter} {a.direction} onset {a.onset_day} "
              f"alarm {a.alarm_day} size {100 * a.rel_size:.1f} %")
    per_seed = [{"seed": 2026, "tuned_on": True, "robots": args.robots, "worn_joints": n_worn,
                 "detected_within_3_days": round(detected, 4), "false_alarms": len(false),
                 "false_alarms_per_100_robot_months": round(100 * len(false) / robot_months, 3)}]
    for seed, other, _ in held_out:
        h_o = monitor(ResultStore(root / f"store-seed{seed}").read(), false_alarm_rate=rate)
        det_o, delays_o, false_o, worn_o = score(h_o, other.robots, args.days, START)
        months_o = args.eval_robots * args.days / 30
        per_seed.append({"seed": seed, "tuned_on": False, "robots": args.eval_robots, "worn_joints": worn_o,
                         "detected_within_3_days": round(det_o, 4), "false_alarms": len(false_o),
                         "false_alarms_per_100_robot_months": round(100 * len(false_o) / months_o, 3)})
        print(f"held-out seed {seed}: worn joints detected within 3 days {100 * det_o:.1f} % of {worn_o}; "
              f"false alarms {len(false_o)} ({100 * len(false_o) / months_o:.2f} per 100 robot-months)", flush=True)
        late = sorted((f"{r} joint {j}: " + (f"{delays_o[(r, j)]} days" if (r, j) in delays_o else "not detected"))
                      for r, j in ((w.robot_id, w.worn_joint) for w in other.robots.itertuples() if w.worn_joint)
                      if delays_o.get((r, j), 99) > 3)
        if late:
            print("  worn joints not detected within 3 days: " + "; ".join(late))
        for a in false_o:
            print(f"  false alarm: {a.robot_id} joint {a.joint} {a.parameter} {a.direction} onset {a.onset_day} "
                  f"alarm {a.alarm_day} size {100 * a.rel_size:.1f} %")
    held = [p for p in per_seed if not p["tuned_on"]]
    held_months = sum(p["robots"] * args.days / 30 for p in held)
    held_false = sum(p["false_alarms"] for p in held)
    out = {
        "robots": args.robots, "days": args.days, "recordings": run.n_recordings,
        "worn_joints": n_worn, "detected_within_3_days": round(detected, 4),
        "false_alarms": len(false), "false_alarms_per_100_robot_months": round(100 * len(false) / robot_months, 3),
        "corrupted_logs": len(fleet.corrupted), "corrupted_reported": reported, "errors": len(err_paths),
        "errors_not_corrupted": len(err_paths - set(fleet.corrupted)),
        "crashed": False,
        "throughput_1_worker_per_s": round(thr1, 3), "throughput_2_workers_per_s": round(thr2, 3),
        "scaling_ratio_2_vs_1": round(thr2 / thr1, 3), "scaling_tasks": len(subset),
        "mean_task_ms": round(1e3 * mean_task, 2), "mean_task_cpu_ms": round(1e3 * cpu2 / len(subset), 2),
        "load_average_1min": round(os.getloadavg()[0], 2), "cpu_cores": os.cpu_count(), "dask_overhead_fraction_1_worker": round(overhead1, 4),
        "dask_overhead_fraction_2_workers": round(overhead2, 4),
        "rerun_computed": rerun.n_computed, "rerun_seconds": round(t_rerun, 2),
        "simulate_seconds": None if t_sim is None else round(t_sim, 1), "identify_seconds": round(t_ident, 1),
        "health_seconds": round(t_health, 2), "report_seconds": round(t_report, 2), "report_kb": round(html_kb, 1),
        "per_seed": per_seed,
        "held_out_robot_months": held_months,
        "held_out_false_alarms_per_100_robot_months": (round(100 * held_false / held_months, 3)
                                                        if held_months else None),
        "held_out_detected_within_3_days": (round(sum(p["detected_within_3_days"] * p["worn_joints"] for p in held)
                                                  / max(1, sum(p["worn_joints"] for p in held)), 4)
                                            if held else None),
        "wall_seconds": round(time.perf_counter() - t_all, 1),
        "targets": {"detected_within_3_days": ">= 0.9", "false_alarms_per_100_robot_months": "<= 1",
                    "scaling_ratio_2_vs_1": ">= 1.6"},
    }
    if tmp is not None:
        tmp.cleanup()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
