"""Coverage of the Projection Method's 95 % intervals on simulated planar arms.

Each seed simulates 10 s of `planar2` in closed loop (`dynid.simulate`: its own random Fourier
reference, white noise on q and tau) and identifies it with `method="projection"`; every base
parameter's z = (estimate - truth) / sigma is pooled over the seeds. Calibrated intervals give a
coverage near 95 % and a z standard deviation near 1. Development used seeds 1-4 (the test);
seeds 300 and up were first run for the seventeenth stop's fix of the position filter.

The last line is a JSON object with `coverage_95`, `z_std`, `pairs` and `median_rel_error`.

Run from the repository root: python benchmarks/coverage_projection.py [--start 300] [--seeds 20]
"""
import argparse
import json

import numpy as np

import dynid


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start", type=int, default=300)
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    dynid.progress.silence()
    zs, rel = [], []
    for seed in range(args.start, args.start + args.seeds):
        sim = dynid.simulate("planar2", 10.0, seed=seed)
        truth = sim.to_dict()["true_parameters"]["base"]
        r = dynid.identify(sim.experiment, "planar2", method="projection")
        z = [(r.params[n] - truth[n]) / r.bse[n] for n in r.names if n in truth and r.bse[n] > 0]
        zs += z
        rel.append(r.rel_error)
        print(f"seed {seed}: {np.mean(np.abs(z) < 1.96):.2f} of {len(z)} within 1.96 sigma, "
              f"rel_error {r.rel_error:.4f}")
    zs = np.array(zs)
    out = {"seeds": [args.start, args.start + args.seeds - 1], "pairs": int(zs.size),
           "coverage_95": float(np.mean(np.abs(zs) < 1.96)), "z_std": float(zs.std()),
           "median_rel_error": float(np.median(rel))}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
