"""Warnings when the arm's self-calibration would absorb what is not a calibration residual: joints
that fit the robot poses better in another order (the ROS driver's), or a joint's zero corrected by
more than a real arm's ever is (a joint read with an offset, in other units or another order)."""

from __future__ import annotations

import numpy as np

from hec.estimator.io.joint_check import check_joint_order
from hec.estimator.solve.noise_learning import LearnedNoise
from hec.estimator.solve.problem import CalibrationProblem

# A joint zero corrected by more than this (degrees, 5x the self-calibration's prior sigma) is not a
# calibration residual: UR calibration files show zero offsets of 0.006-0.07 degrees.
WHOLE_JOINT_ZERO_DEG = 0.5
MISTAKES = ("the joints look like", "the joints do not match")


def joint_order_warning(problem: CalibrationProblem) -> str | None:
    """A warning when the frames' joints fit their reported flange poses better in the other order,
    or in neither (a joint read with an offset or in other units), by
    hec.estimator.io.joint_check.check_joint_order; else None, and None without an arm."""
    if problem.kinematics is None or any(f.joints is None for f in problem.frames):
        return None
    T_base_flange = np.array([f.T_base_flange for f in problem.frames])
    joints = np.array([f.joints for f in problem.frames])
    words = check_joint_order(T_base_flange, joints, problem.kinematics, "arm")
    if not words.startswith(MISTAKES):
        return None
    return (
        f"{words}; the arm's self-calibration would otherwise absorb the mistake into its kinematics and "
        "move the mount: re-import the joints as they fit"
    )


def joint_zero_warning(learned: LearnedNoise | None) -> str | None:
    """A warning when the self-calibrated kinematics move a joint's zero by WHOLE_JOINT_ZERO_DEG or
    more, else None."""
    if learned is None or learned.theta is None:
        return None
    zeros = {
        name.removesuffix("_zero_rad"): np.degrees(value)
        for name, value in zip(learned.theta_names, learned.theta, strict=True)
        if name.endswith("_zero_rad") and abs(np.degrees(value)) >= WHOLE_JOINT_ZERO_DEG
    }
    if not zeros:
        return None
    moved = ", ".join(f"{joint} by {deg:+.2f} deg" for joint, deg in zeros.items())
    return (
        f"the arm's self-calibration moves the zero of {moved}; a real arm's are within 0.1 deg of its "
        "nominal table, so this is likely a joint read with an offset, in other units or in another "
        "order: check the joint readings before trusting this mount"
    )
