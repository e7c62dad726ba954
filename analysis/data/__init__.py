"""Experiment data: reading logs (CSV, Parquet, npz, MAT, TOML descriptions), transmission, synthetic recordings."""
