"""Peak memory of loading each input kind, as a multiple of the input's size (issue 31).

For each kind a recording of about SIZE bytes of samples (6 joints, t, q1..q6,
tau1..tau6 at 5 kHz) is written to a temporary folder and loaded by
dynid.load_experiment in a fresh child process, which reports its resident memory
before loading (after the imports) and its peak (VmHWM, reset after the imports
through /proc/self/clear_refs). The figure is the net peak over the input size;
the target is < 3 for every kind:

* ``npz``: numpy.savez (uncompressed);
* ``npz_compressed``: numpy.savez_compressed; the input size is the expanded
  arrays' size (what the loader must hold), also given over the file size;
* ``parquet``: pandas.DataFrame.to_parquet (snappy);
* ``resampling``: an experiment TOML over an npz with jittered time stamps and
  ``resample = true`` (the resampled copy is part of the peak);
* ``toml``: an experiment TOML just under the 1 MiB cap (long names), over a small
  npz; and ``toml_over_cap``: a 64 MiB TOML, refused before it is read (net peak
  near 0).

The last line is a JSON object: per kind the ratio, with ``max_ratio`` the headline.
Run from the repository root: python benchmarks/io_memory.py [--quick]
(--quick: 20 MB inputs instead of 100 MB).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

FS = 5000.0
N_JOINTS = 6


def _status_kb(field: str):
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith(field + ":"))
    except (OSError, StopIteration):
        return None


def child(path: str, warm: str) -> None:
    """Runs in a subprocess: load a tiny input of the same kind (the loader's own imports are
    part of the baseline, not of the input's cost), then the input; print the resident memory
    before it and the peak (kB)."""
    import gc

    import dynid
    from dynid.errors import DynidError

    try:
        dynid.load_experiment(warm, n_joints=N_JOINTS)
    except DynidError:
        pass
    gc.collect()
    base = _status_kb("VmRSS")
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass
    try:
        exp = dynid.load_experiment(path, n_joints=N_JOINTS)
        outcome = f"{exp.n_samples} samples"
    except DynidError as exc:
        outcome = f"refused: {str(exc)[:120]}"
    peak = _status_kb("VmHWM")
    print(json.dumps({"baseline_kb": base, "peak_kb": peak, "outcome": outcome}))


def signals(n: int, seed: int = 0, jitter: bool = False):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    if jitter:
        t = t + rng.uniform(-0.2, 0.2, n) / FS
    j = np.arange(1, N_JOINTS + 1)
    q = 0.8 * np.sin(2 * np.pi * 0.1 * j * t[:, None]) + rng.normal(0, 4e-5, (n, N_JOINTS))
    tau = 20 / j * np.cos(2 * np.pi * 0.1 * j * t[:, None]) + rng.normal(0, 0.5, (n, N_JOINTS))
    return t, q, tau


def _toml(folder: Path, npz: str, name: str, extra: str = "", pad: int = 0, time_key: str = "t") -> Path:
    p = folder / name
    text = (f'[experiment]\nfile = "{npz}"\nname = "{"x" * pad}"\n{extra}'
            f'[time]\nkey = "{time_key}"\n[positions]\nkey = "q"\n[torques]\nkey = "tau"\n')
    p.write_text(text)
    return p


def make_inputs(folder: Path, size: int, toml_pad: bool = True) -> dict:
    """kind -> (path, input size in bytes)."""
    n = size // (8 * (1 + 2 * N_JOINTS))
    t, q, tau = signals(n)
    data_bytes = t.nbytes + q.nbytes + tau.nbytes
    out = {}
    np.savez(folder / "rec.npz", t=t, q=q, tau=tau)
    out["npz"] = (folder / "rec.npz", data_bytes)
    np.savez_compressed(folder / "rec_c.npz", t=t, q=q, tau=tau)
    out["npz_compressed"] = (folder / "rec_c.npz", data_bytes)
    import pandas as pd
    cols = {"t": t, **{f"q{j + 1}": q[:, j] for j in range(N_JOINTS)},
            **{f"tau{j + 1}": tau[:, j] for j in range(N_JOINTS)}}
    pd.DataFrame(cols).to_parquet(folder / "rec.parquet")
    out["parquet"] = (folder / "rec.parquet", data_bytes)
    tj, qj, tauj = signals(n, seed=1, jitter=True)
    np.savez(folder / "jitter.npz", t=tj, q=qj, tau=tauj)
    out["resampling"] = (_toml(folder, "jitter.npz", "resample.toml", "resample = true\n"), data_bytes)
    small = max(1000, n // 1000)
    np.savez(folder / "small.npz", t=t[:small], q=q[:small], tau=tau[:small])
    toml = _toml(folder, "small.npz", "big.toml", pad=(1 << 20) - 400 if toml_pad else 10)
    out["toml"] = (toml, toml.stat().st_size)
    over = _toml(folder, "small.npz", "over.toml", pad=64 << 20 if toml_pad else 10)
    out["toml_over_cap"] = (over, over.stat().st_size)
    return out


def measure(path: Path, warm: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    res = subprocess.run([sys.executable, __file__, "--child", str(path), str(warm)], capture_output=True, text=True,
                         env=env, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(*args.child)
        return
    size = 20_000_000 if args.quick else 100_000_000
    results = {}
    with tempfile.TemporaryDirectory() as d, tempfile.TemporaryDirectory() as w:
        warm = make_inputs(Path(w), 200_000, toml_pad=False)
        for kind, (path, nbytes) in make_inputs(Path(d), size).items():
            m = measure(path, warm[kind][0])
            net = (m["peak_kb"] - m["baseline_kb"]) * 1024
            ratio = net / nbytes
            results[kind] = {"input_mb": round(nbytes / 1e6, 2), "file_mb": round(path.stat().st_size / 1e6, 2),
                             "net_peak_mb": round(net / 1e6, 1), "ratio": round(ratio, 2), "outcome": m["outcome"]}
            print(f"{kind:15s} input {nbytes / 1e6:8.2f} MB (file {path.stat().st_size / 1e6:8.2f} MB): "
                  f"net peak {net / 1e6:7.1f} MB = {ratio:5.2f} x the input  [{m['outcome']}]", flush=True)
    worst = max(r["ratio"] for r in results.values())
    print(f"largest ratio {worst:.2f} (target < 3)")
    print(json.dumps({"benchmark": "io_memory", "input_mb": size / 1e6, "max_ratio": round(worst, 2),
                      "target": 3.0, "ok": worst < 3.0,
                      "ratios": {k: r["ratio"] for k, r in results.items()}}))


if __name__ == "__main__":
    main()
