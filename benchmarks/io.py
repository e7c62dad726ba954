"""Benchmark of experiment loading (CSV).

1. A 200,000-row x 13-column CSV in dynid's column format (t, q1..q6, tau1..tau6; a
   40 s, 5 kHz, 6-joint log) is generated in a temporary folder and loaded with
   dynid.load_experiment(path, n_joints=6) and with pandas.read_csv, alternately, in
   the same process (median of 11 each; beside it, the median of each dynid load's ratio to
   the pandas load right after it), with the CPU time of each beside. Target: dynid / pandas
   <= 1.3. dynid reads with pandas' C reader on pandas >= 3 (exact there); on pandas 2
   with Arrow's CSV reader first when pyarrow is installed, and its time through pandas'
   reader (what it does without pyarrow) is given beside (the same route on pandas >= 3).
   Beside them, the time of dynid's scan of the file for cells pandas would read
   differently (`_scan_csv`), alone: it runs before the parse on pandas 2 and for a file
   with text columns; pandas 3 refuses those cells in a float column by itself, so a
   numeric file is not scanned there (a block of rows that pandas read as 0 and 1 alone
   sends the file to the scan, for boolean words).
2. A CSV of about 200 MB in the same format is loaded by dynid in a fresh subprocess
   whose peak resident memory (ru_maxrss of the child) is its own; it is given as a
   multiple of the file size, also net of the memory the child had before loading
   (interpreter, numpy, pandas, dynid). Target: <= 3 x the file size.

The last line is a JSON object with the headline figures.
Run from the repository root: python benchmarks/io.py [--quick]
(--quick: 20,000 rows and a 20 MB file.)
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
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

FS = 5000.0
N_JOINTS = 6


def write_csv(path: Path, n_rows: int, seed: int = 0) -> None:
    """A dynid-format CSV (full float precision), written in blocks of rows."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    names = ["t"] + [f"q{j}" for j in range(1, N_JOINTS + 1)] + [f"tau{j}" for j in range(1, N_JOINTS + 1)]
    block = 100_000
    with open(path, "w", newline="") as f:
        for start in range(0, n_rows, block):
            k = np.arange(start, min(n_rows, start + block))
            t = k / FS
            cols = {"t": t}
            for j in range(1, N_JOINTS + 1):
                cols[f"q{j}"] = 0.8 * np.sin(2 * np.pi * 0.1 * j * t) + rng.normal(0, 4e-5, t.size)
            for j in range(1, N_JOINTS + 1):
                cols[f"tau{j}"] = 20 / j * np.cos(2 * np.pi * 0.1 * j * t) + rng.normal(0, 0.5, t.size)
            pd.DataFrame(cols, columns=names).to_csv(f, index=False, header=start == 0,
                                                     float_format="%.17g")


def rows_for_bytes(target: int) -> int:
    """Rows of write_csv's format that make about ``target`` bytes."""
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "probe.csv"
        write_csv(p, 2000, seed=1)
        per_row = p.stat().st_size / 2000
    return int(target / per_row)


#: Loads of each kind timed (the median is given). Ratios from medians of 5 ranged over 1.10-1.36
#: in ten runs on an idle machine (results/io.txt); most of that is the machine, not the count.
REPEATS = 11


def time_loading(path: Path, repeats: int = 3):
    """Medians of dynid.load_experiment (its default route: Arrow's reader when pyarrow is
    installed), of the same with pandas' reader instead, and of pandas.read_csv, in turn."""
    import pandas as pd

    import dynid
    from dynid.analysis.data import readers

    dynid_s, pandas_route_s, pandas_s, scan_s, dynid_cpu, pandas_cpu = [], [], [], [], [], []
    exp = exp_pd = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        readers._scan_csv(path)      # cells pandas would misread (pandas 2, text columns)
        scan_s.append(time.perf_counter() - t0)
        t0, c0 = time.perf_counter(), time.process_time()
        exp = dynid.load_experiment(path, n_joints=N_JOINTS)
        dynid_s.append(time.perf_counter() - t0)
        dynid_cpu.append(time.process_time() - c0)
        t0, c0 = time.perf_counter(), time.process_time()
        df = pd.read_csv(path)
        pandas_s.append(time.perf_counter() - t0)
        pandas_cpu.append(time.process_time() - c0)
        readers._USE_ARROW = False
        try:
            t0 = time.perf_counter()
            exp_pd = dynid.load_experiment(path, n_joints=N_JOINTS)
            pandas_route_s.append(time.perf_counter() - t0)
        finally:
            readers._USE_ARROW = True
    assert exp.n_samples == len(df)
    # the values dynid loaded are those pandas parsed (and Python's float() would), by either route
    np.testing.assert_array_equal(exp.tau, df[[f"tau{j}" for j in range(1, N_JOINTS + 1)]].to_numpy())
    assert exp.tau.tobytes() == exp_pd.tau.tobytes() and exp.q.tobytes() == exp_pd.q.tobytes()
    paired = statistics.median(d / p for d, p in zip(dynid_s, pandas_s))
    return (statistics.median(dynid_s), statistics.median(pandas_s), exp, paired,
            statistics.median(pandas_route_s), statistics.median(scan_s),
            statistics.median(dynid_cpu), statistics.median(pandas_cpu))


def _status_kb(field: str) -> int | None:
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith(field + ":"))
    except (OSError, StopIteration):
        return None


def rss_child(path: str) -> None:
    """Runs in a subprocess: load one CSV; print the resident memory before loading and
    the peak (kB). The peak is reset after the imports where Linux allows it
    (/proc/self/clear_refs), so that import-time peaks do not hide the loader's."""
    import dynid  # noqa: F401 - the imports are part of the baseline

    base = _status_kb("VmRSS") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass
    t0 = time.perf_counter()
    exp = dynid.load_experiment(path, n_joints=N_JOINTS)
    elapsed = time.perf_counter() - t0
    peak = _status_kb("VmHWM") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"baseline_kb": base, "peak_kb": peak, "seconds": elapsed,
                      "n_samples": exp.n_samples}))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes (20,000 rows, 20 MB)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        rss_child(args.child)
        return
    n_rows = 20_000 if args.quick else 200_000
    rss_bytes = 20_000_000 if args.quick else 200_000_000
    with tempfile.TemporaryDirectory(prefix="dynid-io-") as d:
        csv_path = Path(d) / "log.csv"
        write_csv(csv_path, n_rows)
        size = csv_path.stat().st_size
        time_loading(csv_path, repeats=1)          # warm-up: imports, page cache
        dynid_s, pandas_s, exp, paired, pandas_route_s, scan_s, dynid_cpu, pandas_cpu = time_loading(
            csv_path, repeats=REPEATS)
        ratio = dynid_s / pandas_s
        # pandas' parse and the scan one after the other (a load on pandas 2, or with text columns)
        ratio_parse_scan = (pandas_s + scan_s) / pandas_s
        ratio_pandas_route = pandas_route_s / pandas_s
        try:
            import pyarrow
            arrow = f"pyarrow {pyarrow.__version__}"
        except ImportError:
            arrow = "no pyarrow: pandas' reader"
        print(f"CSV {n_rows:,} rows x {1 + 2 * N_JOINTS} columns ({size / 1e6:.1f} MB): "
              f"dynid.load_experiment {dynid_s:.3f} s ({arrow}), pandas.read_csv {pandas_s:.3f} s, "
              f"ratio {ratio:.2f} (target 1.3; median of {REPEATS}; load by load {paired:.2f})")
        print(f"  dynid through pandas' reader (as without pyarrow) {pandas_route_s:.3f} s, "
              f"ratio {ratio_pandas_route:.2f}")
        print(f"  dynid's time beyond pandas' {dynid_s - pandas_s:.3f} s: the checks and the arrays (the "
              f"scan for cells pandas would misread, {scan_s:.3f} s alone, {ratio_parse_scan:.2f} x pandas "
              "after the parse, runs only on pandas 2 and for files with text columns)")
        # pandas >= 3 parses on every core; dynid's checks run on one (tau's spikes on a second)
        print(f"  CPU time: dynid {dynid_cpu:.3f} s, pandas {pandas_cpu:.3f} s (ratio "
              f"{dynid_cpu / pandas_cpu:.2f}); pandas kept {pandas_cpu / pandas_s:.1f} cores busy "
              "(when a core is taken by other work, pandas' parse slows and the ratio falls)")

        big = Path(d) / "big.csv"
        write_csv(big, rows_for_bytes(rss_bytes), seed=2)
        big_size = big.stat().st_size
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
        out = subprocess.run([sys.executable, __file__, "--child", str(big)],
                             capture_output=True, text=True, env=env, check=True)
        child = json.loads(out.stdout.strip().splitlines()[-1])
        # the children's ru_maxrss (kB on Linux; it includes import-time peaks)
        children_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        peak = child["peak_kb"] * 1024
        rss_over_file = peak / big_size
        net_over_file = (child["peak_kb"] - child["baseline_kb"]) * 1024 / big_size
        print(f"CSV {big_size / 1e6:.0f} MB ({child['n_samples']:,} rows) in a child process: "
              f"loaded in {child['seconds']:.1f} s, peak RSS {peak / 1e6:.0f} MB = "
              f"{rss_over_file:.2f} x the file size (target 3; {net_over_file:.2f} x net of the "
              f"{child['baseline_kb'] / 1024:.0f} MB the child held after importing dynid; "
              f"RUSAGE_CHILDREN ru_maxrss {children_kb / 1024:.0f} MB)")
    print(json.dumps({"csv_rows": n_rows, "csv_mb": round(size / 1e6, 1), "dynid_s": round(dynid_s, 3),
                      "pandas_s": round(pandas_s, 3), "ratio": round(ratio, 2), "ratio_paired": round(paired, 2),
                      "ratio_pandas_route": round(ratio_pandas_route, 2), "scan_s": round(scan_s, 4),
                      "ratio_parse_and_scan": round(ratio_parse_scan, 3),
                      "ratio_cpu": round(dynid_cpu / pandas_cpu, 2),
                      "pandas_cores_busy": round(pandas_cpu / pandas_s, 2),
                      "rss_file_mb": round(big_size / 1e6), "rss_peak_mb": round(peak / 1e6),
                      "rss_over_file": round(rss_over_file, 2),
                      "rss_net_over_file": round(net_over_file, 2)}))


if __name__ == "__main__":
    main()
