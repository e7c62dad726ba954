"""How often the segment-agreement line rejects on `dynid simulate`'s own recordings (issue 26).

The guide's example: `dynid simulate --robot tx40 --duration 6 --seed S`, then `dynid identify
run.csv --robot tx40 --holdout 2` (4 s identified, three segments of 1.33 s each, the default
bootstrap covariance). Per seed: whether the verdict's agreement line says the segments agree,
the χ² test's p-value, the pairwise fraction within ±1.96 σ, and the parameters the test
rejects most strongly (Cochran's Q per parameter). With `--qd-threshold X` the velocity dead
zone is X rad/s on every joint instead of the automatic 1 % of each joint's peak speed.

What it found: seeds 100-139 (results/agreement_simulated_100.txt, _100_qd0.05.txt) rejected at
1 % on 13 of 40 with the automatic dead zone and on 7 of 40 with 0.05 rad/s, mostly on
friction and offset parameters of joints 3-6. The cause was not the simulator's smooth Coulomb
sign (the first explanation, which the 0.05 rad/s run did not bear out): a joint (or motor)
that does not reverse within a 1.3 s segment makes its Coulomb column there a combination of
offsets, and every segment was fitted without that column, so its torque went into other
parameters differently in each. Since each segment is fitted with every column it identifies
and the parameters that absorb one it cannot are left out (``idim.recording_agreement``):
0 of 40 on seeds 100-139 with either dead zone (results/agreement_simulated_100_own_columns.txt),
0 of 39 on held-out seeds 16500-16539 (results/agreement_simulated_16500.txt; seed 16504's 4 s
do not identify the model).

    python benchmarks/agreement_simulated.py [--start 100] [--seeds 40] [--qd-threshold X]

A seed whose recording does not identify the model, or whose segments identify too little
alone for an agreement line, is listed in ``not_identified_or_no_line``.

The last line is a JSON object with the headline figures.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--qd-threshold", type=float, default=None, help="rad/s, every joint (default: automatic)")
    a = ap.parse_args(argv)

    import dynid
    dynid.progress.silence()
    options = {} if a.qd_threshold is None else {"qd_threshold": a.qd_threshold}
    rows, failed, t0 = [], [], time.time()
    for seed in range(a.start, a.start + a.seeds):
        rec = dynid.simulate("tx40", 6.0, seed=seed)
        try:
            agreement = dynid.run(rec.experiment, rec.robot, holdout=2.0, **options).result.agreement
        except dynid.IdentificationError as exc:   # the 4 s do not identify the model: no line to judge
            failed.append(seed)
            print(f"seed {seed}: not identified ({str(exc).splitlines()[0][:120]})", flush=True)
            continue
        if agreement is None:                      # the segments do not identify enough alone
            failed.append(seed)
            print(f"seed {seed}: no agreement line (the segments identify too little alone)", flush=True)
            continue
        d = agreement.to_dict()
        pp = np.asarray(d["per_parameter_p_value"], dtype=float)
        top = [(agreement.names[i], float(pp[i])) for i in np.argsort(pp)[:3]]
        row = {"seed": seed, "agrees": bool(agreement.agrees), "p_value": d["p_value"], "pairs": d["pairs"],
               "within_95": d["within_95"], "most_rejected": top}
        rows.append(row)
        within = "no pairs" if row["within_95"] is None else f"{100 * row['within_95']:.0f} % within"
        print(f"seed {seed}: {'agree' if row['agrees'] else 'do NOT agree'}, p = {row['p_value']:.2g}, "
              f"{row['pairs']} pairs, {within}; most rejected "
              + ", ".join(f"{n} (p {p:.1g})" for n, p in top), flush=True)
    p = np.array([r["p_value"] for r in rows], dtype=float)
    print(json.dumps({
        "seeds": len(rows), "not_identified_or_no_line": failed, "first_seed": a.start, "qd_threshold": a.qd_threshold or "auto",
        "not_agree": int(sum(not r["agrees"] for r in rows)), "chi2_p_below_0.01": int(np.sum(p < 0.01)),
        "chi2_p_below_0.05": int(np.sum(p < 0.05)),
        "median_within_95": float(np.median([r["within_95"] for r in rows if r["within_95"] is not None])),
        "seconds": round(time.time() - t0, 1)}))


if __name__ == "__main__":
    main()
