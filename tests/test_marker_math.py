"""Jacobians of the measurement layer against finite differences, and the camera model."""

import numpy as np
import pytest

from hec.estimator.geometry.camera import CameraIntrinsics, back_project, distort_normalized, pixel_rays
from hec.estimator.targets.qr_fit import (
    apply_homography,
    center_from_corners,
    homography_from_corners,
    point_jacobian_wrt_corners,
)

CORNERS = np.array([[101.3, 97.2], [188.9, 105.6], [181.4, 190.1], [96.7, 182.8]])
DISTORTED = CameraIntrinsics(640, 480, 610.0, 615.0, 322.4, 236.9, (0.11, -0.23, 0.0012, -0.0009, 0.07))


def _numeric_jacobian(f, x: np.ndarray, h: float) -> np.ndarray:
    columns = []
    for k in range(len(x)):
        step = np.zeros_like(x)
        step[k] = h
        columns.append((f(x + step) - f(x - step)) / (2 * h))
    return np.stack(columns, axis=-1)


def test_homography_maps_unit_square_to_corners() -> None:
    H = homography_from_corners(CORNERS)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(apply_homography(H, square), CORNERS, atol=1e-9)


def test_center_is_where_the_diagonals_cross() -> None:
    c = center_from_corners(CORNERS)
    p0, p2, p1, p3 = CORNERS[0], CORNERS[2], CORNERS[1], CORNERS[3]
    # c lies on both diagonals: cross products vanish.
    for a, b in ((p0, p2), (p1, p3)):
        d, e = b - a, c - a
        assert abs(d[0] * e[1] - d[1] * e[0]) < 1e-9 * np.linalg.norm(d) ** 2


def test_point_jacobian_wrt_corners_matches_finite_differences() -> None:
    ab = np.array([[0.5, 0.5], [0.1, 0.8], [1.2, -0.1]])

    def points(flat: np.ndarray) -> np.ndarray:
        return apply_homography(homography_from_corners(flat.reshape(4, 2)), ab)

    numeric = _numeric_jacobian(points, CORNERS.ravel(), 1e-4)
    np.testing.assert_allclose(point_jacobian_wrt_corners(CORNERS, ab), numeric, atol=1e-6)


def test_a_batch_of_markers_gives_each_marker_its_own_answer() -> None:
    corners = CORNERS + np.random.default_rng(0).normal(0.0, 5.0, (6, 4, 2))
    ab = np.array([[0.5, 0.5], [0.1, 0.8]])
    for batch, single in (
        (homography_from_corners(corners), [homography_from_corners(c) for c in corners]),
        (point_jacobian_wrt_corners(corners, ab), [point_jacobian_wrt_corners(c, ab) for c in corners]),
        (center_from_corners(corners), [center_from_corners(c) for c in corners]),
    ):
        np.testing.assert_allclose(batch, np.array(single), rtol=1e-12, atol=1e-12)


def test_distortion_jacobian_matches_finite_differences() -> None:
    xy = np.array([[0.31, -0.22], [-0.4, 0.35], [0.0, 0.0]])
    _, analytic = distort_normalized(xy, DISTORTED.dist)
    for i in range(len(xy)):
        numeric = _numeric_jacobian(lambda p: distort_normalized(p[None], DISTORTED.dist)[0][0], xy[i], 1e-6)
        np.testing.assert_allclose(analytic[i], numeric, atol=1e-7)


@pytest.mark.parametrize("intrinsics", [DISTORTED, CameraIntrinsics(640, 480, 600.0, 612.0, 331.3, 228.6)])
def test_pixel_rays_invert_projection_and_their_jacobian(intrinsics: CameraIntrinsics) -> None:
    import cv2

    points = np.array([[0.12, -0.08, 0.45], [-0.2, 0.15, 0.6], [0.0, 0.0, 0.3]])
    uv, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), intrinsics.K, np.array(intrinsics.dist))
    uv = uv.reshape(-1, 2)
    np.testing.assert_allclose(back_project(uv, points[:, 2], intrinsics), points, atol=1e-9)
    rays, analytic = pixel_rays(uv, intrinsics)
    for i in range(len(uv)):
        numeric = _numeric_jacobian(lambda p: pixel_rays(p[None], intrinsics)[0][0], uv[i], 1e-3)
        np.testing.assert_allclose(analytic[i], numeric, atol=1e-8)


def test_back_projection_is_the_papers_formula_without_distortion() -> None:
    k = CameraIntrinsics(640, 480, 600.0, 612.0, 331.3, 228.6)
    uv, z = np.array([[100.0, 400.0]]), np.array([0.5])
    expected = [0.5 * (100.0 - k.cx) / k.fx, 0.5 * (400.0 - k.cy) / k.fy, 0.5]
    np.testing.assert_allclose(back_project(uv, z, k)[0], expected, atol=1e-12)
