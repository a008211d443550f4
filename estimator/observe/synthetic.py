"""Measurement-level synthetic observations: the truth projected, plus Gaussian noise.

No rendering and no detector: corners are the true projections (where the detector's
homography fit puts them under lens distortion, estimator.geometry.marker_fit_bias) plus
N(0, sigma^2) per coordinate, corner depths the true depth plus N(0, sigma(z)^2) each, and the
reported flange poses the true ones perturbed as estimator.geometry.lie describes. The
observations carry exactly the covariances the noise was drawn from, so an
estimator's errors can be compared with the Cramer-Rao bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimator.geometry.camera import CameraIntrinsics, distort
from estimator.geometry.lie import pose_plus
from estimator.geometry.marker_fit_bias import marker_fit_bias
from estimator.geometry.transforms import invert, transform_points
from estimator.observe.depth import DepthNoiseModel
from estimator.observe.observations import FrameObservations, MarkerObservation, camera_points
from estimator.solve.problem import RobotPoseNoise
from estimator.targets.board import BoardDefinition
from estimator.targets.qr_fit import center_from_corners, point_jacobian_wrt_corners


@dataclass(frozen=True)
class SyntheticNoise:
    """corner_sigma_px: per pixel coordinate. depth: sigma(z) of each corner's depth.
    robot: noise of the reported flange poses."""

    corner_sigma_px: float = 0.3
    depth: DepthNoiseModel = field(default_factory=DepthNoiseModel)
    robot: RobotPoseNoise = field(default_factory=RobotPoseNoise)


def project(T_cam_base: np.ndarray, p_base: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """(N, 3) base-frame points -> (N, 2) pixels with the intrinsics' distortion."""
    p_cam = transform_points(T_cam_base, p_base)
    xy = distort(p_cam[:, :2] / p_cam[:, 2:3], intrinsics.dist)
    return xy * [intrinsics.fx, intrinsics.fy] + [intrinsics.cx, intrinsics.cy]


def synthetic_observations(
    board: BoardDefinition,
    intrinsics: CameraIntrinsics,
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray,
    T_base_flange_true: list[np.ndarray],
    noise: SyntheticNoise,
    rng: np.random.Generator,
    exact: bool = False,
    margin_px: float = 2.0,
) -> list[FrameObservations]:
    """One FrameObservations per true flange pose, holding the markers fully in view.

    exact: add no noise, but still report the covariances of ``noise``.
    """
    sigma_uv = noise.corner_sigma_px
    observations = []
    for i, T_base_flange in enumerate(T_base_flange_true):
        T_cam_base = invert(T_base_flange @ T_flange_cam)
        reported = T_base_flange if exact else pose_plus(T_base_flange, _robot_delta(noise.robot, rng))
        obs = FrameObservations(i, float(i), reported)
        for marker_id in board.marker_ids:
            corners_base = transform_points(T_base_board, board.marker_corners(marker_id))
            corners_cam = transform_points(T_cam_base, corners_base)
            z_true = corners_cam[:, 2]
            if np.any(z_true <= 0):
                continue
            corners = project(T_cam_base, corners_base, intrinsics)
            if any(intrinsics.dist):
                corners = corners + marker_fit_bias(corners_cam[None], intrinsics)[0][0]
            inside = (corners >= margin_px) & (
                corners <= [intrinsics.width - 1 - margin_px, intrinsics.height - 1 - margin_px]
            )
            if not inside.all():
                continue
            if not exact:
                corners = corners + sigma_uv * rng.standard_normal((4, 2))
            obs.markers.append(
                _marker(
                    marker_id, corners, z_true, T_cam_base, T_base_board, board, intrinsics, noise, rng, exact
                )
            )
        observations.append(obs)
    return observations


def _robot_delta(robot: RobotPoseNoise, rng: np.random.Generator) -> np.ndarray:
    return np.concatenate(
        [rng.normal(0.0, robot.translation_sigma_m, 3), rng.normal(0.0, robot.rotation_sigma_rad, 3)]
    )


def _marker(
    marker_id: int,
    corners: np.ndarray,
    z_corners: np.ndarray,
    T_cam_base: np.ndarray,
    T_base_board: np.ndarray,
    board: BoardDefinition,
    intrinsics: CameraIntrinsics,
    noise: SyntheticNoise,
    rng: np.random.Generator,
    exact: bool,
) -> MarkerObservation:
    center_true = transform_points(T_cam_base @ T_base_board, board.marker_center(marker_id)[None])[0, 2]
    z_true = np.concatenate([[center_true], z_corners])
    z_sigma = noise.depth.sigma(z_true)
    z = z_true if exact else z_true + z_sigma * rng.standard_normal(5)
    corners_cov = noise.corner_sigma_px**2 * np.eye(8)
    J_center = point_jacobian_wrt_corners(corners, np.array([[0.5, 0.5]]))[0]
    detection = dict(
        marker_id=marker_id,
        corners_px=corners,
        corners_cov=corners_cov,
        center_px=center_from_corners(corners),
        center_cov=J_center @ corners_cov @ J_center.T,
        quality=1.0,
        module_agreement=1.0,
        noise_sigma=0.0,
        found_by="synthetic",
        raw_corners_px=corners,
    )
    marker = MarkerObservation(**detection)
    depth_cov = np.diag(z_sigma**2)
    points, points_cov = camera_points(marker, z, depth_cov, np.zeros((5, 2)), intrinsics)
    return MarkerObservation(
        **detection, depth_m=z, depth_cov=depth_cov, points_cam=points, points_cov=points_cov
    )
