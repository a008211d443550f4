"""The eye-to-hand set-up solved by the eye-in-hand model with the roles of the unknowns swapped.

Eye-in-hand, a board point c is seen at p_cam = inv(X) @ inv(F) @ B @ c with F = T_base_flange
(reported), X = T_flange_cam and B = T_base_board. Eye-to-hand (camera fixed, board on the flange)
it is seen at p_cam = inv(T_base_cam) @ F @ T_flange_board @ c, which is the same model with

    F' = inv(F) = T_flange_base,   X' = T_base_cam,   B' = T_flange_board.

So an eye-to-hand CalibrationProblem holds F' in each frame's T_base_flange slot (its "model
pose"), every estimator solves it unchanged, and the result's T_flange_cam is T_base_cam and its
T_base_board is T_flange_board.

What is not the same is the robot's noise and the arm's kinematics: they belong to the reported
pose F, not to F'. The true F is pose_plus(F, delta) with delta = (dt per base axis, dtheta per
flange axis) ~ N(0, RobotPoseNoise.covariance()), and inverting moves that noise into other frames
and couples it (F' = inv(pose_plus(F, delta)) has dtheta' = -R dtheta and dt' = -R^T dt + [t']x
dtheta: the rotation noise moves the inverted translation by the lever arm |t'|, 0.1-0.2 mm per
0.01 degree at a UR5's reach). Rather than an approximate diagonal noise on F', the perturbation
every estimator carries for a frame stays delta of the reported F: the model pose of a perturbed
frame is flange_plus (exactly inv(pose_plus(F, delta))) and the measurement model's flange
Jacobian is chained through model_pose_jacobian (d(model pose perturbation)/d(delta)). The declared
and learned robot noise, the Cramer-Rao bound and the arm's self-calibration (kinematic corrections
of F through the joints, flange_minus) then mean what they mean eye-in-hand.
"""

from __future__ import annotations

import numpy as np

from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND, SETUPS
from hec.estimator.geometry.lie import pose_minus, pose_plus, skew_rows, so3_exp_rows
from hec.estimator.geometry.transforms import invert


def check_setup(setup: str) -> str:
    """setup itself when it is one of SETUPS, else ValueError."""
    if setup not in SETUPS:
        raise ValueError(f"unknown set-up {setup!r}; choose one of {', '.join(SETUPS)}")
    return setup


def model_pose(setup: str, T: np.ndarray) -> np.ndarray:
    """(4, 4) the model pose of a reported T_base_flange (4, 4): itself eye-in-hand, its inverse
    T_flange_base eye-to-hand; and back (the inverse is its own inverse)."""
    return invert(T) if setup == EYE_TO_HAND else T


def flange_plus(setup: str, T_model: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(4, 4) the model pose when the reported flange pose behind T_model (4, 4) is perturbed by
    delta (6,) (hec.estimator.geometry.lie): pose_plus(T_model, delta) eye-in-hand, exactly
    inv(pose_plus(inv(T_model), delta)) eye-to-hand."""
    if setup == EYE_IN_HAND:
        return pose_plus(T_model, delta)
    return invert(pose_plus(invert(T_model), delta))


def flange_minus(setup: str, T_model: np.ndarray, T_model_ref: np.ndarray) -> np.ndarray:
    """(6,) the perturbation delta of the reported flange pose behind T_model_ref with
    flange_plus(setup, T_model_ref, delta) == T_model (both (4, 4) model poses)."""
    return pose_minus(model_pose(setup, T_model), model_pose(setup, T_model_ref))


def flange_plus_rows(
    setup: str, R_model: np.ndarray, t_model: np.ndarray, deltas: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """flange_plus of N model poses (R_model (N, 3, 3), t_model (N, 3)) and deltas (N, 6): the
    perturbed rotations (N, 3, 3) and translations (N, 3)."""
    E = so3_exp_rows(deltas[:, 3:])
    if setup == EYE_IN_HAND:
        return R_model @ E, t_model + deltas[:, :3]
    # F = (R'^T, -R'^T t'); perturbed (R'^T E, -R'^T t' + dt); inverted (E^T R', E^T (t' - R' dt))
    Et = np.swapaxes(E, 1, 2)
    return Et @ R_model, np.einsum(
        "nij,nj->ni", Et, t_model - np.einsum("nij,nj->ni", R_model, deltas[:, :3])
    )


def model_pose_jacobian(R_model: np.ndarray, t_model: np.ndarray) -> np.ndarray:
    """(..., 6, 6) d(perturbation of the eye-to-hand model pose F' = inv(F)) / d(perturbation delta
    of the reported F), at F' = (R_model (..., 3, 3), t_model (..., 3)): dt' = -R' dt + [t']x
    dtheta, dtheta' = -R'^T dtheta."""
    shape = R_model.shape[:-2]
    R = R_model.reshape(-1, 3, 3)
    A = np.zeros((len(R), 6, 6))
    A[:, :3, :3] = -R
    A[:, :3, 3:] = skew_rows(np.broadcast_to(t_model, (*shape, 3)).reshape(-1, 3))
    A[:, 3:, 3:] = -np.swapaxes(R, 1, 2)
    return A.reshape(*shape, 6, 6)


def model_pose_covariance(setup: str, T_model: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(6, 6) the covariance of the model pose T_model's (4, 4) perturbation when the reported
    pose's is covariance (6, 6): itself eye-in-hand, A covariance A^T eye-to-hand with A =
    model_pose_jacobian (first order; for a method that carries the model pose's own perturbation)."""
    if setup == EYE_IN_HAND:
        return covariance
    A = model_pose_jacobian(T_model[:3, :3], T_model[:3, 3])
    return A @ covariance @ A.T
