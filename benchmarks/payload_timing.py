"""The torque timing's effect on the payload (issue 28): logged, centred, or centred on one side only.

For each seed, the recordings of benchmarks/payload.py (20 s unloaded, `L` s loaded, 2 kHz; the
plant holds each command over the next period) identified by both routes with the torque
  base  : as logged (the command held over [t_k, t_k + T), paired with q_k);
  zoh   : centred on the position samples on every recording (identify_payload(zoh=True), the
          fixed route's model identified from the centred unloaded recording);
  zohL  : centred on the loaded recording only (model from the logged torque): the mistake
          docs/payload.md warns about.
Prints one JSON line per seed and variant: I = inertia error over the largest principal moment,
cov = parameters (of 10) whose 95 % interval holds the truth, z, the joints' residual sigma.
Run from the repository root (niced): python benchmarks/payload_timing.py 3,6,8 [L] [variants]
(benchmarks/results/payload_dev_zoh.jsonl).
"""
import dataclasses
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main():
    import numpy as np

    import dynid
    from benchmarks.payload import recordings
    from dynid.analysis.estimators.payload import centre_held_torque, identify_payload
    robot = dataclasses.replace(dynid.load_robot("tx40"), couplings=[])
    seeds = [int(s) for s in sys.argv[1].split(",")]
    loaded_s = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0
    variants = sys.argv[3].split(",") if len(sys.argv) > 3 else ["base", "zoh", "zohL"]
    for seed in seeds:
        params, parts, eu0, el0, _ = recordings(seed, loaded_s=loaded_s)
        Imax = np.linalg.eigvalsh(parts["inertia_com"]).max()
        for v in variants:
            eu = centre_held_torque(eu0) if v == "zoh" else eu0
            el = centre_held_torque(el0) if v in ("zoh", "zohL") else el0
            r0 = dynid.identify(eu, robot)
            res = {}
            for key, r in (("fixed", identify_payload(el, robot, model=r0, max_rel_halfwidth=np.inf)),
                           ("global", identify_payload(el, robot, unloaded=eu, max_rel_halfwidth=np.inf))):
                z = (r.chi - params) / r.bse.to_numpy()
                res[key] = dict(I=round(float(np.abs(r.inertia_com - parts["inertia_com"]).max() / Imax), 4),
                                cov=int(np.sum(np.abs(z) <= 1.96)), z=[round(x, 1) for x in z],
                                sig=[round(x, 3) for x in r.joint_sigma])
            print(json.dumps({"seed": seed, "L": loaded_s, "v": v, **res}), flush=True)


if __name__ == "__main__":
    main()
