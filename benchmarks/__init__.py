"""Benchmarks and the composition suite (scripts; run from the repository root)."""
