"""Coverage of DIDIM's 95 % intervals on the independent closed-loop plant (issue 26, row DIDIM).

Data: the recordings of `benchmarks/didim_gains.py` (the coverage campaign's plant of
`benchmarks/coverage_independent.py`: Pinocchio TX40, Table 2 parameters, coupled wrist,
PID with velocity feed-forward at 5 kHz logged at 1 kHz, 4 s, 10-harmonic reference,
torque noise AR(1) phi = 0.9 of 0.3 N m, a position ripple on joint 1; encoder noise
2e-5 rad) with each joint's gains multiplied by a factor in [0.5, 2]. The true base
parameters are `coverage_independent.truth` (the plant's standard parameters through
dynid's base-parameter relations).

Per seed DIDIM runs as `--gains identify` does (the gains identified from the logged
loop, no gain update), from the robot file's a-priori values (`--gains true`: with the
plant's own gains, to separate the gains' share of the error), once, and each covariance
option of DIDIM (`didim_covariance`, what `identify_didim(uncertainty=..., gains=...)` reports:
classic eq. (14) on the last step, hac, bootstrap, and `bootstrap+gains`, the bootstrap with
the identified gains' covariance propagated through the loop) is computed on that run. Coverage: the fraction of
(parameter, seed) pairs whose estimate +- 1.96 sigma holds the truth, over all base
parameters and over the parameters with %sigma <= 10 (the ones a user would read),
with the median width relative to classic. Runs that did not converge are counted and
kept (their intervals are judged like the others: a user gets them with a warning).

    nice -n 10 python benchmarks/coverage_didim.py --start 6100 --seeds 40 --workers 2 \
        --out benchmarks/results/coverage_didim_seeds6100.jsonl

`--essential`: DIDIM with its essential set and the default covariance (`identify_didim(...,
essential=True, uncertainty="bootstrap", gains=<identified>)`: the CLI's `--gains identify`, which
does not propagate the gains' covariance, a share under 0.1 % of the width), and the coverage of
its reported parameters, the essential set (`essential_z`: the truth is the true base parameter
of the same name), beside the classic essential sigma of the same run (eq. (14) of the essential
model, `essential_classic_z`) and the median width relative to it.

Development used seeds below 1000; the last line is a JSON object with the headline figures.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from campaign_rows import append, resume

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "benchmarks", ROOT / "tests" / "support"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

OPTIONS = ("classic", "hac", "bootstrap", "bootstrap+gains")


def run_seed(seed, duration=4.0, gains="identify", options=OPTIONS, essential=False, block_rule=None):
    import coverage_independent as ci
    import didim_gains as dg
    if block_rule is not None:   # the bootstrap's block rule, for a paired comparison on the same seeds
        import functools

        from dynid.analysis.estimators import hac
        hac.bootstrap_covariance = functools.partial(hac.bootstrap_covariance, block=block_rule)

    from dynid.analysis.estimators.controller_gains import identify_gains
    from dynid.analysis.estimators.didim import didim_covariance, identify_didim
    from dynid.dynamics.base_parameters import base_parameters
    t0 = time.time()
    exp, rec, f = dg.recording(seed, duration)
    robot = dg.robot_pid()
    bp = base_parameters(robot)
    beta = ci.truth(robot, bp)
    try:
        g = identify_gains(exp, robot)
        g.controller(robot)    # refused when an identified gain is not positive
    except Exception as exc:   # the gains of a seed that cannot be identified: a row of the campaign
        return {"seed": seed, "gains": gains, "gain_factors": [float(x) for x in f],
                "error": f"gains: {str(exc).splitlines()[0]}", "seconds": time.time() - t0}
    if gains == "true":
        import dataclasses
        G = rec["gains"]
        c = robot.controller
        gdrive = np.array([jt.drive_gain for jt in robot.joints], dtype=float)
        J_ap, g_ap = np.asarray(c.J_ap, float), np.asarray(c.g_ap, float)
        kv = G["Kd"] * g_ap / (gdrive * J_ap)
        wn = np.sqrt(G["Kp"] / G["Kd"] * kv)
        ctrl = dataclasses.replace(c, wn=wn, zeta=kv / (2 * wn), ki=G["Ki"] * g_ap / (gdrive * J_ap))
        g = None
    else:
        ctrl = g.controller(robot)
    row = {"seed": seed, "gains": gains, "gain_factors": [float(x) for x in f]}
    t1 = time.time()
    try:
        if essential:    # what the user gets: the essential set with the default covariance
            d = identify_didim(exp, robot, bp=bp, controller=ctrl, chi0=dict(robot.apriori), update_gains=False,
                               essential=True, uncertainty="bootstrap", gains=g)
        else:
            d = identify_didim(exp, robot, bp=bp, controller=ctrl, chi0=dict(robot.apriori), update_gains=False,
                               essential=False)
    except Exception as exc:   # a failed run is a result of the campaign, with its message
        row["error"] = str(exc).splitlines()[0]
        row["seconds"] = time.time() - t0
        return row
    row.update(converged=bool(d.converged), steps=d.iterations, v_s=float(d.settings["v_s"]),
               stop_reason=d.stop_reason, didim_seconds=time.time() - t1)
    if essential:
        _essential_rows(row, d, bp, beta)
    idx = [list(bp.names).index(n) for n in d.result.names]
    for opt in options:
        if opt.endswith("+gains") and g is None:
            continue
        t2 = time.time()
        r = didim_covariance(d, opt.split("+")[0], gains=g if opt.endswith("+gains") else None)
        assert np.allclose(r.chi, d.chi, rtol=1e-9, atol=1e-12), "the option changed the estimate"
        sig = r.bse.to_numpy()
        row[f"{opt}_z"] = [float(v) for v in (r.chi - beta[idx]) / sig]
        row[f"{opt}_sigma"] = [float(v) for v in sig]
        row[f"{opt}_rel_std"] = [float(v) for v in r.rel_std.to_numpy()]
        row[f"{opt}_seconds"] = time.time() - t2
    row["seconds"] = time.time() - t0
    return row


def _essential_rows(row, d, bp, beta):
    """z and sigma of the essential set DIDIM reports, and of its classic sigma (eq. (14))."""
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.essential import essential_parameters
    L, last = d._state
    classic = essential_parameters(last["Wd"], last["taud"], list(bp.names), ls.wls, max_error_growth=0.02,
                                   row_mask=last["mask"], settings=L.info).result
    ess = d.essential.result
    assert list(classic.names) == list(ess.names) and np.allclose(classic.chi, ess.chi), "not the same set"
    idx = [list(bp.names).index(n) for n in ess.names]
    row["essential_names"] = list(ess.names)
    for part, r in (("essential", ess), ("essential_classic", classic)):
        sig = r.bse.to_numpy()
        row[f"{part}_z"] = [float(v) for v in (r.chi - beta[idx]) / sig]
        row[f"{part}_sigma"] = [float(v) for v in sig]


def headline(rows):
    out = {"seeds": len(rows), "errors": sum("error" in r for r in rows),
           "converged": sum(bool(r.get("converged")) for r in rows)}
    ok = [r for r in rows if "classic_z" in r]
    for opt in OPTIONS:
        have = [r for r in ok if f"{opt}_z" in r]
        if not have:
            continue
        z = np.concatenate([r[f"{opt}_z"] for r in have])
        out[f"{opt}_coverage95"] = float(np.mean(np.abs(z) <= 1.96))
        good = np.concatenate([np.asarray(r["classic_rel_std"]) <= 10.0 for r in have])
        out[f"{opt}_coverage95_identified"] = float(np.mean(np.abs(z[good]) <= 1.96))
        out["identified_pairs"] = int(good.sum())
        conv = [r for r in have if r.get("converged")]
        if conv:
            zc = np.concatenate([r[f"{opt}_z"] for r in conv])
            out[f"{opt}_coverage95_converged"] = float(np.mean(np.abs(zc) <= 1.96))
        if opt != "classic":
            ratio = np.concatenate([np.asarray(r[f"{opt}_sigma"]) / np.asarray(r["classic_sigma"]) for r in have])
            out[f"{opt}_median_width_vs_classic"] = float(np.median(ratio))
    ess = [r for r in ok if "essential_z" in r]
    if ess:
        for part in ("essential", "essential_classic"):
            z = np.concatenate([r[f"{part}_z"] for r in ess])
            out[f"{part}_coverage95"] = float(np.mean(np.abs(z) <= 1.96))
        out["essential_pairs"] = int(sum(len(r["essential_z"]) for r in ess))
        out["essential_median_width_vs_classic"] = float(np.median(np.concatenate(
            [np.asarray(r["essential_sigma"]) / np.asarray(r["essential_classic_sigma"]) for r in ess])))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--gains", default="identify", choices=("identify", "true"))
    ap.add_argument("--options", default=",".join(OPTIONS))
    ap.add_argument("--essential", action="store_true",
                    help="DIDIM with its essential set and the default covariance (and the gains' share)")
    ap.add_argument("--block-rule", default=None, choices=("politis-white", "politis-white-scores"),
                    help="the bootstrap's block rule (default dynid's); politis-white-scores: one block for "
                         "every parameter, the rule before 47dcc42")
    ap.add_argument("--out", default=None, help="JSON lines, one per seed (appended; seeds done are skipped)")
    ap.add_argument("--summarize", nargs="+", default=None, metavar="JSONL",
                    help="only print the headline of the rows in these files (no new runs)")
    a = ap.parse_args(argv)
    if a.summarize:
        rows = [json.loads(x) for f in a.summarize for x in Path(f).read_text().splitlines() if x.strip()]
        out = headline(rows)
        out["seed_list"] = sorted(r["seed"] for r in rows)
        print(json.dumps(out))
        return
    options = tuple(o for o in a.options.split(",") if o)
    seeds = list(range(a.start, a.start + a.seeds))
    rows, seeds = resume(a.out, seeds)
    t0 = time.time()

    def record(row):
        rows.append(row)
        print(f"seed {row['seed']}: converged {row.get('converged')} "
              + ", ".join(f"{o} {np.mean(np.abs(row[f'{o}_z']) <= 1.96):.2f}" for o in OPTIONS if f"{o}_z" in row)
              + (f", essential {np.mean(np.abs(row['essential_z']) <= 1.96):.2f}" if "essential_z" in row else "")
              + (f" error {row['error']}" if "error" in row else "") + f" ({row['seconds']:.0f} s)", flush=True)
        append(a.out, row)

    if a.workers > 1:
        from concurrent.futures import ProcessPoolExecutor
        n = len(seeds)
        with ProcessPoolExecutor(a.workers) as ex:
            for row in ex.map(run_seed, seeds, [a.duration] * n, [a.gains] * n, [options] * n,
                              [a.essential] * n, [a.block_rule] * n):
                record(row)
    else:
        for s in seeds:
            record(run_seed(s, a.duration, a.gains, options, a.essential, a.block_rule))
    out = headline(rows)
    out.update({"first_seed": a.start, "duration_s": a.duration, "gains": a.gains, "essential": a.essential,
                "block_rule": a.block_rule or "politis-white",
                "campaign_seconds": time.time() - t0})
    print(json.dumps(out))


if __name__ == "__main__":
    main()
