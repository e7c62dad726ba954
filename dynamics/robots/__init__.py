"""Robots bundled with dynid: one TOML file each, with the provenance of its numbers."""
