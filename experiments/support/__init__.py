"""What the commands, sweeps and sessions share: detecting a dataset, plots, signals and the
synthetic scenes of the benchmarks."""
