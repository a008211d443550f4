"""Benchmarks: rendering, detection and estimator speed and accuracy (`python -m experiments.bench.NAME`)."""
