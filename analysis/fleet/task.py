"""One fleet task: one recording -> its identified parameters, or its error (pure, deterministic).

The task reads the recording, runs IDIM (OLS, per-joint WLS, essential set of
Gautier, Janot & Vandanjon 2010 section 2, exactly as `dynid identify`
does through `dynid.analysis.estimators.idim.identify_idim`) and returns a
plain dict. Nothing in the result depends on the worker, the clock or the
order of execution except `task_seconds` and `task_cpu_seconds`, which the comparisons leave out.

A recording longer than `max_samples` (default `MAX_SAMPLES`) is not
processed whole: `dynid.analysis.estimators.streamed.reduce_stream` filters,
builds the regressor and decimates it block by block, and reduces each decimated
chunk at once to its per-joint triangles (WᵀW, Wᵀτ and ‖τ‖² in factored form,
`dynid.analysis.estimators.least_squares.Reduction`), which add up; OLS, WLS
and the essential set are solved on the sum. Neither the full-rate nor the
decimated W is ever held, so the task's memory is a few blocks of q and tau
beyond the recording itself. The streamed filter differs from the whole-record
one by < 1e-5 at the block joins, so the two paths agree to well within σ; on
the same decimated system they agree to rounding.
"""
from __future__ import annotations

import functools
import hashlib
import time

import numpy as np

from dynid.analysis.data.experiment import Experiment, load_experiment
from dynid.analysis.diagnosis.selection import diagnose
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import essential_parameters
from dynid.analysis.estimators.idim import identify_idim
from dynid.analysis.estimators.streamed import reduce_stream
from dynid.analysis.identify import as_robot
from dynid.analysis.processing.observation import resolve_settings
from dynid.analysis.processing.signals import dead_zone_thresholds, derivatives
from dynid.dynamics.base_parameters import base_parameters
from dynid.errors import DynidError

#: samples above which a recording is streamed and reduced block by block (6 joints x 2e6
#: samples x 8 B of q and tau is 0.2 GB; its full-rate TX40 regressor would be 6 GB, built a
#: chunk at a time by the in-memory path, and the decimated one it keeps 6 GB / n_d)
MAX_SAMPLES = 2_000_000
#: the schema version of a task's result: part of the store key, so a change recomputes
RESULT_SCHEMA = 1


def file_hash(path, *, block: int = 1 << 20) -> str:
    """SHA-256 (hex) of a file's bytes: the store's "data hash" (cheap to recompute on rerun)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def task_key(robot_id: str, recording: str, data_hash: str, version: str, options: dict) -> str:
    """The store key of one task: (robot, recording, data hash, dynid version, options) hashed."""
    text = "\0".join([str(RESULT_SCHEMA), robot_id, recording, data_hash, version,
                      repr(sorted(options.items()))])
    return hashlib.sha256(text.encode()).hexdigest()[:24]


@functools.lru_cache(maxsize=32)
def _robot(spec: str):
    # one load per worker process and robot model, not per task
    robot = as_robot(spec)
    return robot, base_parameters(robot)


def _streamed_reduction(exp, robot, bp, settings, block):
    """The reduced system of a long recording, block by block (settings from its first block)."""
    head = slice(0, min(exp.q.shape[0], block))
    first = Experiment(t=exp.t[head], q=exp.q[head], tau=exp.tau[head], fs=exp.fs, source=exp.source)
    s = resolve_settings(first, settings)
    qd_threshold = s["qd_threshold"]
    if isinstance(qd_threshold, str):   # 'auto' from the first block's peak speed
        der = derivatives(first.q, exp.fs, s["fc_position"], s["order"])
        qd_threshold = dead_zone_thresholds(der.qd, qd_threshold)
    chunks = ((exp.q[i:i + block], exp.tau[i:i + block]) for i in range(0, exp.q.shape[0], block))
    return reduce_stream(chunks, exp.fs, robot, bp, fc_position=s["fc_position"], nd=int(s["nd"]),
                         f_decimation_cutoff=s["f_decimation_cutoff"], qd_threshold=qd_threshold,
                         order=s["order"], block=block)


#: the covariance of the stored sigma: a long recording is reduced block by block (a Reduction
#: keeps no samples to resample), and the health check rescales sigma by the fleet's own scatter
UNCERTAINTY = "classic"


def _identify(exp, robot, bp, settings, max_samples):
    """(wls result, essential result, samples of the recording) of one recording."""
    if exp.q is None or exp.q.shape[0] <= max_samples:
        r = identify_idim(exp, robot, settings=settings, bp=bp, uncertainty=UNCERTAINTY)
        return r.wls, r.essential, r.observation.n_raw
    streamed = _streamed_reduction(exp, robot, bp, settings, max(1000, max_samples // 4))
    cfg = dict(streamed.settings)
    wls = ls.wls_reduced(streamed.reduction, settings=cfg)
    ess = essential_parameters(streamed.reduction, None, None, ls.wls, settings=cfg)
    return wls, ess, streamed.n_raw


def retry_failure(spec: dict, why: str) -> dict:
    """The result fields of a failure that is not a property of the recording (an OSError, out
    of memory, its worker died): `retry` marks it, so the store keeps it only until the next run."""
    return {"status": "error", "retry": True,
            "error": f"{spec['path']}: not identified: {why}; a failure of the machine, not of the recording, "
                     f"so it is not kept as the recording's result: the next run tries it again"}


def identify_recording(spec: dict) -> dict:
    """Run one task. `spec`: robot_id, path, robot, timestamp, day, key, data_hash,
    temperatures, settings, max_samples, diagnose. Returns the result dict (`status`
    `"ok"` with the parameters, or `"error"` with the message, and `retry` when the
    failure is not a property of the recording)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = {k: spec[k] for k in ("key", "robot_id", "path", "robot", "timestamp", "day", "data_hash",
                                "version")}
    out["temperatures"] = list(spec.get("temperatures") or [])
    try:
        robot, bp = _robot(spec["robot"])
        exp = load_experiment(spec["path"], robot)
        wls, ess, n_raw = _identify(exp, robot, bp, spec.get("settings"), int(spec.get("max_samples") or MAX_SAMPLES))
        model = ess.result
        ess_values = dict(zip(model.names, zip(model.chi, model.bse.to_numpy())))
        out.update(status="ok", error="", n_samples=int(n_raw), rel_error=float(model.rel_error),
                   names=list(wls.names), value=[float(v) for v in wls.chi],
                   sigma=[float(s) for s in wls.bse.to_numpy()],
                   essential=[n in ess_values for n in wls.names],
                   essential_value=[float(ess_values[n][0]) if n in ess_values else float("nan")
                                    for n in wls.names],
                   essential_sigma=[float(ess_values[n][1]) if n in ess_values else float("nan")
                                    for n in wls.names],
                   experiment_hash=exp.data_hash(), effects=[])
        if spec.get("diagnose"):
            d = diagnose(exp, robot)
            out["effects"] = [e.name if e.joint is None else f"{e.name} (joint {e.joint})" for e in d.selected]
    except DynidError as exc:           # a bad log: its message, and the fleet goes on
        out.update(status="error", error=str(exc))
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
        out.update(status="error", error=f"{spec['path']}: {type(exc).__name__}: {exc}")
    except (OSError, MemoryError) as exc:   # the machine's, not the recording's: the next run retries
        out.update(retry_failure(spec, f"{type(exc).__name__}: {exc}"))
    out["task_seconds"] = time.perf_counter() - t0
    out["task_cpu_seconds"] = time.process_time() - c0
    return out
