"""Measurement-level synthetic observations: the truth projected, plus Gaussian noise.

No rendering and no detector: corners are the true projections (where the detector's
homography fit puts them under lens distortion, hec.estimator.geometry.marker_fit_bias) plus
N(0, sigma^2) per coordinate, corner depths the true depth plus N(0, sigma(z)^2) each, and the
reported flange poses the true ones perturbed as hec.estimator.geometry.lie describes. The
observations carry exactly the covariances the noise was drawn from, so an
estimator's errors can be compared with the Cramer-Rao bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.camera import CameraIntrinsics, project
from hec.estimator.geometry.lie import pose_plus
from hec.estimator.geometry.marker_fit_bias import marker_fit_bias
from hec.estimator.geometry.transforms import invert, transform_points
from hec.estimator.observe.depth import DepthNoiseModel
from hec.estimator.observe.observations import FrameObservations, MarkerObservation, back_projected_points
from hec.estimator.targets.qr_fit import center_from_corners, point_jacobian_wrt_corners
from hec.estimator.targets.target import Target


@dataclass(frozen=True)
class SyntheticNoise:
    """corner_sigma_px: per pixel coordinate. depth: sigma(z) of each corner's depth.
    robot: noise of the reported flange poses."""

    corner_sigma_px: float = 0.3
    depth: DepthNoiseModel = field(default_factory=DepthNoiseModel)
    robot: RobotPoseNoise = field(default_factory=RobotPoseNoise)


def synthetic_observations(
    board: Target,
    intrinsics: CameraIntrinsics,
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray,
    T_base_flange_true: list[np.ndarray],
    noise: SyntheticNoise,
    rng: np.random.Generator,
    exact: bool = False,
    margin_px: float = 2.0,
    setup: str = EYE_IN_HAND,
) -> list[FrameObservations]:
    """One FrameObservations per true flange pose, holding the markers fully in view.

    exact: add no noise, but still report the covariances of ``noise``. Noise is drawn frame by
    frame: the flange pose's, then each kept marker's corners' and its depths'. setup 'eye-to-hand':
    the camera is fixed at T_flange_cam = T_base_cam and the board rides on the flange at
    T_base_board = T_flange_board (the two unknowns' roles swapped); the reported flange poses are
    perturbed alike.
    """
    if board.points_per_marker != 4:
        raise ValueError(
            f"measurement-fidelity observations are synthesised for 4-corner markers; board "
            f"'{board.name}' is a {board.kind} board (use render fidelity)"
        )
    ids = list(board.marker_ids)
    corners_board = np.array([board.marker_corners(m) for m in ids])  # (M, 4, 3)
    corners_base = transform_points(T_base_board, corners_board.reshape(-1, 3))
    centers_base = transform_points(T_base_board, np.array([board.marker_center(m) for m in ids]))
    limits = np.array([intrinsics.width - 1 - margin_px, intrinsics.height - 1 - margin_px])
    # the camera's pose in the frame the board is fixed in (the base; eye-to-hand the flange)
    if setup == EYE_TO_HAND:
        T_cam_base = [invert(T_flange_cam) @ T_base_flange for T_base_flange in T_base_flange_true]
    else:
        T_cam_base = [invert(T_base_flange @ T_flange_cam) for T_base_flange in T_base_flange_true]
    # Every frame's markers at once: camera-frame corners (F, M, 4, 3), the ones wholly in front.
    corners_cam = np.array([transform_points(T, corners_base) for T in T_cam_base]).reshape(
        -1, len(ids), 4, 3
    )
    frame_of, marker_of = np.nonzero(np.all(corners_cam[..., 2] > 0, axis=-1))
    in_front = corners_cam[frame_of, marker_of]  # (K, 4, 3)
    corners = project(np.eye(4), in_front.reshape(-1, 3), intrinsics).reshape(-1, 4, 2)
    if any(intrinsics.dist) and len(in_front):
        corners = corners + marker_fit_bias(in_front, intrinsics).reshape(-1, 4, 2)
    inside = np.all((corners >= margin_px) & (corners <= limits), axis=(1, 2))
    frame_of, marker_of, corners = frame_of[inside], marker_of[inside], corners[inside]
    z_centers = np.array([transform_points(T, centers_base)[:, 2] for T in T_cam_base]).reshape(-1, len(ids))
    z_true = np.column_stack([z_centers[frame_of, marker_of], corners_cam[frame_of, marker_of, :, 2]])
    observations = [
        FrameObservations(i, float(i), T_base_flange) for i, T_base_flange in enumerate(T_base_flange_true)
    ]
    corner_noise, depth_noise = np.zeros((len(frame_of), 4, 2)), np.zeros((len(frame_of), 5))
    if not exact:
        first = np.searchsorted(frame_of, np.arange(len(observations) + 1))
        for i, obs in enumerate(observations):
            obs.T_base_flange = pose_plus(obs.T_base_flange, _robot_delta(noise.robot, rng))
            for k in range(first[i], first[i + 1]):
                corner_noise[k] = rng.standard_normal((4, 2))
                depth_noise[k] = rng.standard_normal(5)
    markers = _markers(
        [ids[m] for m in marker_of], corners, z_true, corner_noise, depth_noise, intrinsics, noise
    )
    for f, marker in zip(frame_of, markers, strict=True):
        observations[f].markers.append(marker)
    return observations


def _robot_delta(robot: RobotPoseNoise, rng: np.random.Generator) -> np.ndarray:
    return np.concatenate(
        [rng.normal(0.0, robot.translation_sigma_m, 3), rng.normal(0.0, robot.rotation_sigma_rad, 3)]
    )


def _markers(
    marker_ids: list[int],
    corners: np.ndarray,
    z_true: np.ndarray,
    corner_noise: np.ndarray,
    depth_noise: np.ndarray,
    intrinsics: CameraIntrinsics,
    noise: SyntheticNoise,
) -> list[MarkerObservation]:
    """The observations of K markers from their detected corners' truth (K, 4, 2), the true depths
    of their centres and corners (K, 5) and standard normal draws of each (K, 4, 2), (K, 5)."""
    z_sigma = noise.depth.sigma(z_true)
    corners = corners + noise.corner_sigma_px * corner_noise
    z = z_true + z_sigma * depth_noise
    corners_cov = noise.corner_sigma_px**2 * np.eye(8)
    J_center = point_jacobian_wrt_corners(corners, np.array([[0.5, 0.5]]))[:, 0]  # (K, 2, 8)
    centers_px = center_from_corners(corners)
    centers_cov = J_center @ corners_cov @ np.swapaxes(J_center, -1, -2)
    uv = np.concatenate([centers_px[:, None], corners], axis=1)
    uv_cov = np.zeros((len(marker_ids), 5, 2, 2))
    uv_cov[:, 0] = centers_cov
    uv_cov[:, 1:] = noise.corner_sigma_px**2 * np.eye(2)
    points, points_cov = back_projected_points(uv, uv_cov, z, z_sigma**2, np.zeros((*z.shape, 2)), intrinsics)
    depth_cov = z_sigma[:, :, None] * z_sigma[:, None, :] * np.eye(5)
    return [
        MarkerObservation(
            marker_id=marker_id,
            corners_px=corners[k],
            corners_cov=corners_cov.copy(),
            center_px=centers_px[k],
            center_cov=centers_cov[k],
            quality=1.0,
            module_agreement=1.0,
            noise_sigma=0.0,
            found_by="synthetic",
            raw_corners_px=corners[k],
            depth_m=z[k],
            depth_cov=depth_cov[k],
            points_cam=points[k],
            points_cov=points_cov[k],
        )
        for k, marker_id in enumerate(marker_ids)
    ]
