"""Signals, estimators, statistics, essential parameters and diagnostics."""
