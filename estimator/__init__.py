"""Geometry, target definition, datasets and (later) detection and estimation.

This package imports neither MuJoCo nor any hardware library: it sees arrays,
poses and images, so the simulator and the real cell share all of it.
"""
