"""The calibration problem, its measurement model and every estimator, the OpenCV baselines, observability."""
