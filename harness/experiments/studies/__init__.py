"""Experiments and benchmarks of the paper, each behind an ``rt2`` command."""
