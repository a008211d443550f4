"""The calibration methods by name: what the command line offers without loading the estimators
(hec.estimator.solve.methods maps each name to its estimator)."""

from __future__ import annotations

OPENCV_METHOD_NAMES = (
    "opencv-tsai",
    "opencv-park",
    "opencv-horaud",
    "opencv-andreff",
    "opencv-daniilidis",
    "opencv-shah",
    "opencv-li",
)
METHOD_NAMES = ("seed-ekf", "ekf", "iekf", "ukf", "batch", *OPENCV_METHOD_NAMES)
DEFAULT_METHOD = "ekf"
