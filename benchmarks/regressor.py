"""Speed and memory of dynid's regressor on the TX40.

Run from the repository root::

    python benchmarks/regressor.py            # full benchmark, < 60 s on 2 cores
    python benchmarks/regressor.py --quick    # 10x fewer samples

1. IDM_st (all 86 columns) for 100,000 random samples: dynid (numba backend;
   one warm-up call, which compiles or loads the kernel, is excluded; median of
   3 runs) against Pinocchio's ``computeJointTorqueRegressor`` called in a
   per-sample Python loop on a Pinocchio model of the TX40 built from the same
   joint placements (median of 3 runs). Pinocchio's regressor has the 60
   inertial columns only; dynid's also has Ia, Fv, Fc, Off and the coupling.
2. Peak resident memory of the base regressor (60 columns) of 1,000,000 samples
   through ``regressor_chunks``, each chunk reduced to W^T W at once, so the
   2.9 GB regressor is never held. This part runs in a fresh subprocess so its
   peak RSS (VmHWM on Linux, else ``ru_maxrss``) is its own; the inputs q, qd,
   qdd (144 MB) are part of it.
3. Part 1 again with reused output buffers: dynid's regressor(..., out=W) and the
   Pinocchio loop writing into its own kept array, against a read + write pass
   between two touched arrays (no page faults on either side).

The last line printed is a JSON object with the headline figures.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from dynid.dynamics.base_parameters import base_parameters  # noqa: E402
from dynid.dynamics.regressor import regressor, regressor_chunks  # noqa: E402
from dynid.dynamics.robot_file import load_robot  # noqa: E402


def _samples(n_samples, n_joints, seed):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-np.pi, np.pi, (n_samples, n_joints)),
            rng.normal(0.0, 2.0, (n_samples, n_joints)),
            rng.normal(0.0, 5.0, (n_samples, n_joints)))


def _peak_rss_mb():
    """Peak resident set size of this process, MB.

    Linux: VmHWM of /proc/self/status, the high-water mark of this process's own
    address space (ru_maxrss survives exec and would report the parent's peak
    at the time of the fork). Elsewhere: ru_maxrss.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    # ru_maxrss is in kilobytes on Linux, bytes on macOS
    scale = 1.0 if sys.platform == "darwin" else 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale / 2 ** 20


#: CPU seconds (user + system, this process) of each timed call, by the function's name
_CPU: dict = {}


def _median_time(fn, repeats, name=None):
    """Median wall time of `repeats` calls and the list of them; with `name`, the median
    CPU time (user + system: what the call costs whatever else runs) is kept in _CPU."""
    times, cpu = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    if name:
        _CPU[name] = statistics.median(cpu)
    return statistics.median(times), times


def speed(n_samples, repeats=3, pairs=7):
    robot = load_robot("tx40")
    q, qd, qdd = _samples(n_samples, robot.n_joints, seed=1)

    regressor(robot, q[:100], qd[:100], qdd[:100])                   # warm-up (numba compile/load)
    dynid_s, dynid_runs = _median_time(lambda: regressor(robot, q, qd, qdd), repeats, "dynid")

    import pinocchio as pin

    from tests.support.oracles import pin_model_from_robot, random_standard_parameters
    chi = random_standard_parameters(robot, np.random.default_rng(2))
    model = pin_model_from_robot(robot, chi)
    data = model.createData()

    def pin_loop():
        out = np.empty((n_samples, robot.n_joints, 10 * robot.n_joints))
        for i in range(n_samples):
            out[i] = pin.computeJointTorqueRegressor(model, data, q[i], qd[i], qdd[i])
        return out

    # same numbers? (inertial columns; Pinocchio orders m, mc, I(xx xy yy xz yz zz) per body)
    Wd = regressor(robot, q[:50], qd[:50], qdd[:50])
    Wp = np.array([pin.computeJointTorqueRegressor(model, data, q[i], qd[i], qdd[i]) for i in range(50)])
    perm = [9, 6, 7, 8, 0, 1, 3, 2, 4, 5]          # dynid column of each Pinocchio column
    cols = [14 * j + k for j in range(robot.n_joints) for k in perm]
    agree = float(np.abs(Wd[:, :, cols] - Wp).max() / np.abs(Wp).max())

    pin_s, pin_runs = _median_time(pin_loop, repeats, "pinocchio")

    # The memory floor: one read and one write pass over an array of W's size, the
    # write into fresh memory as dynid's own output is (its first touch included).
    W_ref = regressor(robot, q, qd, qdd)
    floor_s, _ = _median_time(lambda: np.copyto(np.empty_like(W_ref), W_ref), repeats)

    # A caller that rebuilds the regressor of as many samples reuses its buffer (out=); the
    # Pinocchio loop then reuses its own too. Without fresh memory to fault in, the floor is
    # a read + write pass over W between two touched arrays.
    W_buf = np.empty_like(W_ref)
    out_s, out_runs = _median_time(lambda: regressor(robot, q, qd, qdd, out=W_buf), repeats)
    assert W_buf.tobytes() == W_ref.tobytes()
    P_buf = np.empty((n_samples, robot.n_joints, 10 * robot.n_joints))

    def pin_loop_reuse():
        for i in range(n_samples):
            P_buf[i] = pin.computeJointTorqueRegressor(model, data, q[i], qd[i], qdd[i])

    pin_out_s, _ = _median_time(pin_loop_reuse, repeats)
    floor_out_s, _ = _median_time(lambda: np.copyto(W_buf, W_ref), repeats)

    # Paired: each dynid call timed beside a Pinocchio loop (CPU time), alternating which goes
    # first; the median of the pairs' ratios follows the machine's load less than the ratio
    # of two medians taken one block after the other.
    paired = []
    for r in range(pairs):
        cpu = {}
        for name, fn in (("dynid", lambda: regressor(robot, q, qd, qdd)), ("pinocchio", pin_loop))[::1 - 2 * (r % 2)]:
            c0 = time.process_time()
            fn()
            cpu[name] = time.process_time() - c0
        paired.append(cpu["dynid"] / cpu["pinocchio"])
    return {"ratio_paired": statistics.median(paired), "paired_ratios": paired,"dynid_s": dynid_s, "dynid_runs": dynid_runs, "pinocchio_s": pin_s, "floor_s": floor_s,
            "pinocchio_runs": pin_runs, "max_rel_diff": agree, "pin_version": pin.__version__,
            "out_s": out_s, "out_runs": out_runs, "pinocchio_out_s": pin_out_s,
            "floor_out_s": floor_out_s}


def memory_child(n_samples, chunk):
    """Runs in a fresh interpreter: base regressor of n_samples, reduced chunk by chunk."""
    robot = load_robot("tx40")
    bp = base_parameters(robot)
    regressor(robot, *_samples(10, robot.n_joints, 0))                # load the kernel
    rss_start = _peak_rss_mb()
    q, qd, qdd = _samples(n_samples, robot.n_joints, seed=3)
    rss_inputs = _peak_rss_mb()
    t0 = time.perf_counter()
    WtW = np.zeros((bp.n_base, bp.n_base))
    rows = 0
    for _sl, W in regressor_chunks(robot, q, qd, qdd, columns=bp.independent, chunk=chunk):
        W2 = W.reshape(-1, bp.n_base)
        WtW += W2.T @ W2
        rows += W2.shape[0]
    elapsed = time.perf_counter() - t0
    cond = float(np.linalg.cond(WtW))
    print(json.dumps({"peak_rss_mb": _peak_rss_mb(), "rss_after_imports_mb": rss_start,
                      "rss_after_inputs_mb": rss_inputs, "seconds": elapsed, "rows": rows,
                      "n_base": bp.n_base, "cond_WtW": cond,
                      "full_regressor_mb": n_samples * robot.n_joints * bp.n_base * 8 / 2 ** 20}))


def memory(n_samples, chunk):
    # One BLAS thread for the small W^T W products: on a loaded 2-core machine
    # OpenBLAS's threads thrash and make them up to 8x slower.
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--memory-child",
                          str(n_samples), "--chunk", str(chunk)],
                         capture_output=True, text=True, check=True, cwd=str(ROOT), env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="10x fewer samples")
    ap.add_argument("--memory-child", type=int, metavar="N", help=argparse.SUPPRESS)
    ap.add_argument("--chunk", type=int, default=10_000)
    args = ap.parse_args(argv)
    if args.memory_child:
        memory_child(args.memory_child, args.chunk)
        return

    n_speed = 10_000 if args.quick else 100_000
    n_mem = 100_000 if args.quick else 1_000_000
    t_all = time.perf_counter()
    print(f"dynid regressor benchmark: TX40 (6 joints, 86 standard / 60 base parameters), "
          f"{os.cpu_count()} CPUs, Python {platform.python_version()}, NumPy {np.__version__}")
    m = memory(n_mem, args.chunk)          # first, while this process is still small
    s = speed(n_speed)
    print(f"\n1) IDM_st of {n_speed:,} samples (median of 3 runs, warm-up excluded)")
    print(f"   dynid (numba, 86 columns)                      {s['dynid_s']:8.3f} s   "
          f"runs {', '.join(f'{t:.3f}' for t in s['dynid_runs'])}")
    print(f"   Pinocchio {s['pin_version']} computeJointTorqueRegressor loop  {s['pinocchio_s']:8.3f} s   "
          f"runs {', '.join(f'{t:.3f}' for t in s['pinocchio_runs'])}")
    ratio = s["dynid_s"] / s["pinocchio_s"]
    print(f"   paired CPU ratios (dynid beside Pinocchio, {len(s['paired_ratios'])} pairs)  "
          f"median {s['ratio_paired']:.3f}  ({', '.join(f'{x:.3f}' for x in s['paired_ratios'])})")
    ratio_cpu = _CPU["dynid"] / _CPU["pinocchio"]
    print(f"   ratio dynid / pinocchio                        {ratio:8.3f}  "
          f"({1 / ratio:.1f}x faster)" if ratio < 1 else f"   ratio dynid / pinocchio {ratio:8.3f}")
    print(f"   ratio of the fastest runs                      {min(s['dynid_runs']) / min(s['pinocchio_runs']):8.3f}"
          f"  (dynid writes a {n_speed * 6 * 86 * 8 / 2 ** 20:.0f} MB array per run: the first touch"
          f" of fresh memory makes its runs noisy on a loaded machine)")
    print(f"   ratio of the CPU times (user + system)         {ratio_cpu:8.3f}  (dynid {_CPU['dynid']:.3f} s, "
          f"Pinocchio {_CPU['pinocchio']:.3f} s: less sensitive to other work on the machine)")
    floor = s["dynid_s"] / s["floor_s"]
    print(f"   one read + write pass over W (fresh output)    {s['floor_s']:8.3f} s   "
          f"dynid / that floor {floor:.2f}")
    print(f"   inertial columns agree with Pinocchio to {s['max_rel_diff']:.1e} (relative)")
    ratio_out = s["out_s"] / s["pinocchio_out_s"]
    floor_out = s["out_s"] / s["floor_out_s"]
    print("   reused output buffers (regressor(..., out=W); the Pinocchio loop into its own)")
    print(f"   dynid                                          {s['out_s']:8.3f} s   "
          f"runs {', '.join(f'{t:.3f}' for t in s['out_runs'])}")
    print(f"   Pinocchio loop                                 {s['pinocchio_out_s']:8.3f} s   "
          f"ratio dynid / pinocchio {ratio_out:.3f}")
    print(f"   one read + write pass over W (touched output)  {s['floor_out_s']:8.3f} s   "
          f"dynid / that floor {floor_out:.2f}")

    print(f"\n2) base regressor of {n_mem:,} samples via regressor_chunks (chunk {args.chunk:,}), "
          f"reduced to W^T W per chunk, fresh process, 1 BLAS thread")
    print(f"   time                          {m['seconds']:8.2f} s")
    print(f"   peak RSS                      {m['peak_rss_mb']:8.1f} MB")
    print(f"     after imports               {m['rss_after_imports_mb']:8.1f} MB")
    print(f"     after the q, qd, qdd inputs {m['rss_after_inputs_mb']:8.1f} MB")
    print(f"   the full {m['rows']:,} x {m['n_base']} regressor would take {m['full_regressor_mb']:,.0f} MB")
    print(f"\ntotal wall time {time.perf_counter() - t_all:.1f} s")
    print(json.dumps({"dynid_s": round(s["dynid_s"], 4), "pinocchio_s": round(s["pinocchio_s"], 4),
                      "ratio": round(ratio, 4), "ratio_cpu": round(ratio_cpu, 4),
                      "ratio_paired": round(s["ratio_paired"], 4), "floor_s": round(s["floor_s"], 4),
                      "ratio_to_memory_floor": round(floor, 3), "peak_rss_mb_1M": round(m["peak_rss_mb"], 1),
                      "ratio_out_reused": round(ratio_out, 4), "ratio_out_to_memory_floor": round(floor_out, 3),
                      "n_samples": n_speed, "n_samples_memory": n_mem}))


if __name__ == "__main__":
    main()
