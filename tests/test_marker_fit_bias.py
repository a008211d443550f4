"""hec.estimator.geometry.marker_fit_bias: the corners one homography over a distorted marker reports."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.marker_fit_bias import (
    QUADRATURE_AB,
    QUADRATURE_WEIGHTS,
    marker_fit_bias,
    marker_fit_bias_jacobians,
)
from hec.estimator.geometry.transforms import invert, transform_points
from hec.estimator.targets.qr import QRDetector
from hec.sim.cell import SimCell
from hec.sim.scenario import scenario_from_dict
from hec.sim.simulate import scenario_waypoints

# The realistic cell's lens (models/scenarios/realistic.toml).
LENS = CameraIntrinsics(640, 480, 617.0, 617.0, 319.5, 239.5, (0.13, -0.30, 0.0, 0.0, 0.0))
SIDE_M = 0.06


def _markers(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 4, 3) corners of 60 mm squares turned up to ~40 deg, 0.3-0.6 m in front of the
    camera, each wholly inside the image."""
    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]) * SIDE_M
    markers = []
    while len(markers) < count:
        R = cv2.Rodrigues(rng.normal(0.0, 0.4, 3))[0]
        z = rng.uniform(0.3, 0.6)
        t = [rng.uniform(-0.4, 0.4) * z, rng.uniform(-0.3, 0.3) * z, z]
        corners = (square - SIDE_M / 2) @ R.T + t
        uv = corners[:, :2] / corners[:, 2:] * LENS.fx + [LENS.cx, LENS.cy]
        if np.all((uv > 10) & (uv < [LENS.width - 10, LENS.height - 10])):
            markers.append(corners)
    return np.array(markers)


def _project(points_cam: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    uv, _ = cv2.projectPoints(points_cam, np.zeros(3), np.zeros(3), intrinsics.K, np.array(intrinsics.dist))
    return uv.reshape(-1, 2)


def test_bias_is_the_least_squares_homography_fit_in_symbol_coordinates() -> None:
    """Against the exact weighted least-squares homography from the distorted quadrature points to
    the symbol (its error measured in symbol coordinates, as the module's fit), solved to
    convergence by scipy: the module's one linear step is within 1 % of its corner shifts."""
    rng = np.random.default_rng(0)
    markers = _markers(rng, 20)
    bias = marker_fit_bias(markers, LENS).reshape(-1, 4, 2)
    ab, weight = QUADRATURE_AB, np.sqrt(QUADRATURE_WEIGHTS)[:, None]
    corners_ab = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    for corners, b in zip(markers, bias, strict=True):
        points = corners[0] + ab[:, :1] * (corners[1] - corners[0]) + ab[:, 1:] * (corners[3] - corners[0])
        points_px = _project(points, LENS)
        start, _ = cv2.findHomography(points_px, ab, 0)

        def residual(h: np.ndarray, points_px: np.ndarray = points_px) -> np.ndarray:
            mapped = cv2.perspectiveTransform(points_px[None], np.append(h, 1.0).reshape(3, 3))[0]
            return (weight * (mapped - ab)).ravel()

        h = least_squares(residual, (start / start[2, 2]).ravel()[:8], xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        fitted = cv2.perspectiveTransform(corners_ab[None], np.linalg.inv(np.append(h, 1.0).reshape(3, 3)))[0]
        exact = fitted - _project(corners, LENS)
        assert np.linalg.norm(b - exact) < 0.01 * np.linalg.norm(exact)
    # Of the size that matters: several times the detector's 0.013 px floor, up to ~0.1 px.
    assert 0.02 < np.sqrt(np.mean(np.sum(bias**2, axis=2))) < 0.1


def test_no_bias_without_distortion_but_its_derivatives_are_there() -> None:
    markers = _markers(np.random.default_rng(1), 5)
    pinhole = CameraIntrinsics(640, 480, 617.0, 617.0, 319.5, 239.5)
    assert np.abs(marker_fit_bias(markers, pinhole)).max() < 1e-12
    jac = marker_fit_bias_jacobians(markers, pinhole)
    assert np.abs(jac.d_corners_cam).max() < 1e-4  # a pinhole image of a square is a homography
    assert np.abs(jac.d_camera[:, :, 2:]).max() > 0.1  # k1, k2 make a bias, px per unit


@pytest.mark.parametrize("column", range(4))
def test_camera_derivatives_match_central_differences(column: int) -> None:
    markers = _markers(np.random.default_rng(2), 6)
    jac = marker_fit_bias_jacobians(markers, LENS)
    step = (1e-2, 1e-2, 1e-4, 1e-4)[column]

    def moved(sign: float) -> CameraIntrinsics:
        fx, fy, k1, k2 = np.array([LENS.fx, LENS.fy, *LENS.dist[:2]]) + sign * step * np.eye(4)[column]
        return CameraIntrinsics(640, 480, fx, fy, 319.5, 239.5, (k1, k2, 0.0, 0.0, 0.0))

    numeric = (marker_fit_bias(markers, moved(1.0)) - marker_fit_bias(markers, moved(-1.0))) / (2 * step)
    assert np.abs(numeric - jac.d_camera[:, :, column]).max() < 1e-3 * np.abs(numeric).max()


def test_the_detector_reports_the_fitted_corners_on_a_rendered_lens() -> None:
    """The QR detector on frames rendered through the realistic cell's lens: its corners sit nearer the
    distorted corners plus the bias than the distorted corners alone (the bias explains most of
    its error)."""
    lens = {"enabled": True, "true_coefficients": list(LENS.dist)}
    scenario = scenario_from_dict({"errors": {"lens": lens}})
    cell = SimCell(scenario, np.random.default_rng(0))
    true_k = cell.true.intrinsics
    detector = QRDetector(cell.board)
    plain, fitted = [], []
    try:
        for waypoint in scenario_waypoints(scenario)[:3]:
            cell.move_to(waypoint)
            frame, _ = cell.capture()
            T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
            for marker in detector.detect(frame.rgb).markers:
                index = cell.true.board.printed.marker_ids.index(marker.marker_id)
                corners = transform_points(T_cam_board, cell.true.board.true_corners()[index])
                truth = _project(corners, true_k)
                bias = marker_fit_bias(corners[None], true_k).reshape(4, 2)
                plain.append(marker.corners_px - truth)
                fitted.append(marker.corners_px - truth - bias)
    finally:
        cell.close()
    rms_plain, rms_fitted = (float(np.sqrt(np.mean(np.sum(np.square(e), axis=2)))) for e in (plain, fitted))
    print(
        f"{len(plain)} markers: corner RMS {rms_plain:.4f} px to the distorted corners, "
        f"{rms_fitted:.4f} px with the bias"
    )
    assert len(plain) >= 16
    assert rms_fitted < 0.6 * rms_plain
