"""Fleet scale: re-identify many robots' recordings on Dask and watch their friction for wear.

One concept per module: :mod:`.catalogue` (the table of recordings),
:mod:`.task` (one recording -> one result, pure), :mod:`.store` (the Parquet
results store), :mod:`.engine` (Dask distributed: plan, submit, collect),
:mod:`.health` (parameter histories, temperature compensation, CUSUM alarms)
and :mod:`.simulated` (a simulated production fleet for tests and benchmarks).
Dask and pyarrow are optional (``pip install "dynid[fleet]"``) and imported
only when a fleet is run.
"""
