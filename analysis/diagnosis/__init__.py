"""Residual diagnosis: which effect the identified model lacks."""
