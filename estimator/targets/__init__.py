"""Calibration targets: the board definition and one detector module per target kind."""
