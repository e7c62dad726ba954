"""Residual diagnosis: which effect the identified model lacks; fits of named effects (asymmetric friction)."""
