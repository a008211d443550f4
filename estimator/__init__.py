"""The library everything else uses: geometry, targets, observations, estimators and files.

This package imports neither MuJoCo nor any hardware library: it sees arrays,
poses and images, so the simulator and the real cell share all of it.
"""
