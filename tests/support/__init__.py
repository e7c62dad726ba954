"""Test-only helpers shared by every test folder and by benchmarks/: independent plants,
oracles, simulated data (not part of the dynid package)."""
