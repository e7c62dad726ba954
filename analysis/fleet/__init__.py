"""Fleet scale: re-identify many robots' recordings on Dask and watch their friction for wear.

One concept per module: `.catalogue` (the table of recordings),
`.task` (one recording -> one result, pure), `.store` (the Parquet
results store), `.engine` (Dask distributed: plan, submit, collect),
`.health` (parameter histories, temperature compensation, CUSUM alarms)
and `.simulated` (a simulated production fleet for tests and benchmarks).
Dask and pyarrow are optional (the `fleet` extra) and imported
only when a fleet is run.
"""
