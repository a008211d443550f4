"""Where one homography fitted over a marker's whole image puts its corners under lens distortion.

The QR detector (hec.estimator.targets.qr_fit) aligns each marker's code to the image with one
homography, so the corners it reports are that homography's corners. Under lens distortion the
image of a flat square is not the image of a homography, and the homography that fits it best
misses the distorted corners: with the realistic cell's lens (k1 = 0.13, k2 = -0.30 at 640 x 480)
by about 0.05 px RMS, four times the detector's noise floor, and always in the same direction for
a given place in the image, so that a self-calibrated k2 came out 0.03 off. The measurement model
therefore predicts the detector's corners: the distorted corners plus this bias.

The fit is least squares over the marker's area with uniform weight (standing in for the
alignment's: a code has edges all over it), compared in symbol coordinates as the template
alignment compares in the template's frame. The integral is a QUADRATURE_SIDE x QUADRATURE_SIDE
Gauss-Legendre quadrature (within 2 % of a 61 x 61 grid's fit; a uniform 9 x 9 grid was 12 % off).
The distorted points are mapped back through the homography through the distorted corners; what
is left is ~1e-3 of the symbol, so one linear step from that homography gives the fit (within
0.5 % of the exact least-squares fit's corner shifts).

Symbol coordinates (a, b) as in hec.estimator.targets.qr_fit: corners (0, 0), (1, 0), (1, 1), (0, 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hec.estimator.geometry.camera import CameraIntrinsics, distort

QUADRATURE_SIDE = 4
# Forward-difference steps of the derivatives: normalised image coordinates of a corner; pixels of
# focal length and units of distortion coefficient.
NORMALISED_STEP = 1e-7
CAMERA_STEPS = (1e-3, 1e-3, 1e-6, 1e-6)  # fx, fy, k1, k2

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(QUADRATURE_SIDE)
# The quadrature's points (G, 2) in symbol coordinates and their weights (G,), summing to 1.
QUADRATURE_AB = 0.5 + 0.5 * np.column_stack(
    [np.tile(_NODES, QUADRATURE_SIDE), np.repeat(_NODES, QUADRATURE_SIDE)]
)
QUADRATURE_WEIGHTS = 0.25 * np.outer(_WEIGHTS, _WEIGHTS).ravel()
_CORNERS_AB = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _homographies_through(corners: np.ndarray) -> np.ndarray:
    """(M, 4, 2) points -> (M, 3, 3) homographies (H[2, 2] = 1) mapping the symbol's corners onto
    them, in closed form (Heckbert's square-to-quadrilateral mapping)."""
    x, y = corners[..., 0], corners[..., 1]
    sx, sy = x[:, 0] - x[:, 1] + x[:, 2] - x[:, 3], y[:, 0] - y[:, 1] + y[:, 2] - y[:, 3]
    dx1, dx2, dy1, dy2 = x[:, 1] - x[:, 2], x[:, 3] - x[:, 2], y[:, 1] - y[:, 2], y[:, 3] - y[:, 2]
    det = dx1 * dy2 - dx2 * dy1
    g, h = (sx * dy2 - dx2 * sy) / det, (dx1 * sy - sx * dy1) / det
    H = np.empty((len(corners), 3, 3))
    H[:, 0] = np.stack([x[:, 1] - x[:, 0] + g * x[:, 1], x[:, 3] - x[:, 0] + h * x[:, 3], x[:, 0]], axis=1)
    H[:, 1] = np.stack([y[:, 1] - y[:, 0] + g * y[:, 1], y[:, 3] - y[:, 0] + h * y[:, 3], y[:, 0]], axis=1)
    H[:, 2, 0], H[:, 2, 1], H[:, 2, 2] = g, h, 1.0
    return H


def _apply(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Homographies H (M, 3, 3) applied to points (M, N, 2), or to the same (N, 2) for all: (M, N, 2)."""
    a, b = points[..., 0], points[..., 1]
    row = [[H[:, i, j : j + 1] for j in range(3)] for i in range(3)]  # (M, 1) each
    w = row[2][0] * a + row[2][1] * b + row[2][2]
    return np.stack([row[i][0] * a + row[i][1] * b + row[i][2] for i in (0, 1)], axis=-1) / w[..., None]


def _adjugate(H: np.ndarray) -> np.ndarray:
    """(M, 3, 3) -> the adjugates (M, 3, 3): the inverses times the determinants, which map points
    as the inverses do (a homography's scale does not matter) without a solve."""
    a, b, c, d, e, f, g, h, i = (H[:, k // 3, k % 3] for k in range(9))
    adjugate = np.empty_like(H)
    adjugate[:, 0, 0], adjugate[:, 0, 1], adjugate[:, 0, 2] = e * i - f * h, c * h - b * i, b * f - c * e
    adjugate[:, 1, 0], adjugate[:, 1, 1], adjugate[:, 1, 2] = f * g - d * i, a * i - c * g, c * d - a * f
    adjugate[:, 2, 0], adjugate[:, 2, 1], adjugate[:, 2, 2] = d * h - e * g, b * g - a * h, a * e - b * d
    return adjugate


def _fit_to_corners() -> np.ndarray:
    """(8, 2G): corner shifts (symbol units) of the weighted least-squares homography through
    displacements of the quadrature's points (symbol units) near the identity, rows (a0, b0, ..., b3)."""

    def tangent(ab: np.ndarray) -> np.ndarray:  # d(point)/d(h) at the identity, (2N, 8)
        a, b = ab[:, 0], ab[:, 1]
        zero, one = np.zeros_like(a), np.ones_like(a)
        du = np.stack([a, b, one, zero, zero, zero, -a * a, -b * a], axis=1)
        dv = np.stack([zero, zero, zero, a, b, one, -a * b, -b * b], axis=1)
        return np.stack([du, dv], axis=1).reshape(-1, 8)

    J = tangent(QUADRATURE_AB)
    W = np.repeat(QUADRATURE_WEIGHTS, 2)[:, None]
    return tangent(_CORNERS_AB) @ np.linalg.solve(J.T @ (W * J), (W * J).T)


_FIT_TO_CORNERS = _fit_to_corners()


def _camera(intrinsics: CameraIntrinsics, M: int) -> np.ndarray:
    """(M, 7): fx, fy, k1, k2, p1, p2, k3 for each of M markers."""
    k1, k2, p1, p2, k3 = (tuple(intrinsics.dist) + (0.0,) * 5)[:5]
    return np.tile([intrinsics.fx, intrinsics.fy, k1, k2, p1, p2, k3], (M, 1))


def _distorted_pixels(xy: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """(M, N, 2) pinhole normalised coordinates -> distorted pixels (M, N, 2) relative to the
    principal point, for each marker's camera (M, 7)."""
    distorted = distort(xy, tuple(camera[:, j : j + 1] for j in range(2, 7)))
    return distorted * camera[:, None, :2]


def marker_fit_bias(corners_cam: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Where a homography fit over each marker's distorted image puts its corners, minus the
    distorted corners: (M, 8) pixels, rows (u0, v0, ..., v3); zero without distortion.

    corners_cam: (M, 4, 3) each marker's corners in the camera frame (metres), in symbol order.
    The marker's pinhole image is the homography through its corners' pinhole images (a flat
    marker, whatever the four points are). The principal point does not matter: a homography
    follows the image's shift exactly.
    """
    return _bias(corners_cam[:, :, :2] / corners_cam[:, :, 2:3], _camera(intrinsics, len(corners_cam)))


def _bias(corners_xy: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """marker_fit_bias from the corners' pinhole normalised coordinates (M, 4, 2) and each
    marker's camera (M, 7) (see _camera)."""
    M = len(corners_xy)
    points_px = _distorted_pixels(_apply(_homographies_through(corners_xy), QUADRATURE_AB), camera)
    H = _homographies_through(_distorted_pixels(corners_xy, camera))
    displacement = _apply(_adjugate(H), points_px) - QUADRATURE_AB  # symbol units, (M, G, 2)
    shift = (displacement.reshape(M, -1) @ _FIT_TO_CORNERS.T).reshape(M, 4, 2)
    # symbol units -> pixels through H's derivative at each corner
    w = H[:, 2:3, 0] * _CORNERS_AB[:, 0] + H[:, 2:3, 1] * _CORNERS_AB[:, 1] + 1.0  # (M, 4)
    corners_px = _apply(H, _CORNERS_AB)
    d_px_d_ab = (H[:, None, :2, :2] - corners_px[:, :, :, None] * H[:, None, 2:3, :2]) / w[:, :, None, None]
    return np.einsum("mkij,mkj->mki", d_px_d_ab, shift).reshape(M, 8)


@dataclass(frozen=True)
class MarkerFitBiasJacobians:
    """Derivatives of M markers' corner bias, rows (u0, v0, ..., u3, v3) per marker: d_camera
    (M, 8, 4) with respect to fx, fy (pixels) and the distortion's k1, k2 (the principal point
    only moves the whole image, which a homography follows exactly); d_corners_cam (M, 8, 12) with
    respect to the marker's corners in the camera frame (x0, y0, z0, ..., z3), pixels per metre."""

    d_camera: np.ndarray
    d_corners_cam: np.ndarray


def marker_fit_bias_jacobians(
    corners_cam: np.ndarray, intrinsics: CameraIntrinsics, bias: np.ndarray | None = None
) -> MarkerFitBiasJacobians:
    """The bias's derivatives (see marker_fit_bias) by forward differences, all twelve moves (the
    corners' eight normalised coordinates, fx, fy, k1, k2) in one batch; bias (M, 8):
    marker_fit_bias at corners_cam, if already computed. (A first-order analytic form was 30 % off
    for the corners' motion: the fit's own change with the marker's shape is as large as its
    residuals' change. The bias is ~1e-3 of a corner's own derivative, so the differences' ~1e-5
    relative error is nothing.)"""
    M = len(corners_cam)
    z = corners_cam[:, :, 2:3]
    corners_xy = corners_cam[:, :, :2] / z
    camera = _camera(intrinsics, M)
    base = _bias(corners_xy, camera) if bias is None else bias
    steps = np.array([NORMALISED_STEP] * 8 + list(CAMERA_STEPS))
    moves = np.eye(12) * steps
    moved_xy = corners_xy[None] + moves[:, :8].reshape(12, 1, 4, 2)
    moved_camera = camera[None] + np.pad(moves[:, 8:], ((0, 0), (0, 3)))[:, None, :]
    moved = _bias(moved_xy.reshape(-1, 4, 2), moved_camera.reshape(-1, 7)).reshape(12, M, 8)
    derivatives = np.moveaxis((moved - base) / steps[:, None, None], 0, -1)  # (M, 8, 12)
    # d(x/z, y/z)/d(x, y, z) per corner
    d_xy_d_cam = np.zeros((M, 4, 2, 3))
    d_xy_d_cam[:, :, 0, 0] = d_xy_d_cam[:, :, 1, 1] = 1.0 / z[:, :, 0]
    d_xy_d_cam[:, :, :, 2] = -corners_xy / z
    d_xy = derivatives[:, :, :8].reshape(M, 8, 4, 2)
    d_cam = np.einsum("mrki,mkic->mrkc", d_xy, d_xy_d_cam).reshape(M, 8, 12)
    return MarkerFitBiasJacobians(derivatives[:, :, 8:], d_cam)
