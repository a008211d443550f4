"""Benchmarks: rendering, detection and estimator speed and accuracy (`python -m hec.bench.NAME`)."""
