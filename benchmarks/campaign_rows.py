"""The rows a seed campaign already wrote: resume an interrupted run where it stopped.

Shared (`resume`, `append` for each new row, `map_seeds` to run them) by the coverage and convergence campaigns (`coverage_independent.py`,
`coverage_didim.py`, `coverage_posterior.py`, `didim_gains.py`), whose results file holds
one JSON object per seed and line.
"""
from __future__ import annotations

import json
from pathlib import Path


def resume(out, seeds):
    """The rows of `out` for `seeds`, and the seeds still to run.

    Parameters
    ----------
    out : str or Path or None
        The campaign's .jsonl results file (one JSON object with a "seed" key per line); None or
        a missing file: nothing done yet.
    seeds : list of int
        The seeds the campaign asks for.

    Returns
    -------
    rows : list of dict
        The rows already written for those seeds.
    todo : list of int
        The seeds without a row, in order.
    """
    if not out or not Path(out).exists():
        return [], list(seeds)
    rows = [json.loads(x) for x in Path(out).read_text().splitlines() if x.strip()]
    done = {r["seed"] for r in rows}
    return [r for r in rows if r["seed"] in seeds], [s for s in seeds if s not in done]


def append(out, row):
    """Write `row` as one line of `out` (nothing when `out` is None): what `resume` reads back.

    Parameters
    ----------
    out : str or Path or None
        The campaign's .jsonl results file.
    row : dict
        One seed's results, with its "seed" key.
    """
    if out:
        with open(out, "a") as fh:
            fh.write(json.dumps(row) + "\n")


def map_seeds(run_seed, seeds, workers=1, *args):
    """`run_seed(seed, *args)` for each seed, in order, in `workers` processes (1: this one).

    Yields
    ------
    dict
        Each seed's row as it is done, for the caller to print and `append`.
    """
    if workers > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(workers) as ex:
            yield from ex.map(run_seed, seeds, *([a] * len(seeds) for a in args))
    else:
        for s in seeds:
            yield run_seed(s, *args)
