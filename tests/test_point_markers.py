"""Markers of one point (chessboard and ChArUco corners) through the estimators: the QR board's
corners split into one-point markers are the same measurements, so every estimator must give the
same mount as on the 4-corner markers (a wrong points-per-marker layout anywhere breaks this)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from hec.estimator.geometry.transforms import pose_error
from hec.estimator.observe.observations import FrameObservations, MarkerObservation
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import solve
from hec.estimator.solve.problem import build_problem
from hec.estimator.targets.board import BoardDefinition
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene


@dataclass(frozen=True)
class CornerBoard:
    """BOARD's corners, each its own one-point marker: ID 4 i + c is corner c of QR marker i."""

    qr: BoardDefinition
    kind = "corners"
    points_per_marker = 1
    markers_placed_one_by_one = False
    corners_homography_fitted = False

    @property
    def name(self) -> str:
        return f"{self.qr.name} corners"

    @property
    def size_m(self) -> tuple[float, float]:
        return self.qr.size_m

    @property
    def marker_ids(self) -> list[int]:
        return [4 * i + c for i in self.qr.marker_ids for c in range(4)]

    def marker_corners(self, marker_id: int) -> np.ndarray:
        return self.qr.marker_corners(marker_id // 4)[marker_id % 4 : marker_id % 4 + 1]

    def marker_center(self, marker_id: int) -> np.ndarray:
        return self.marker_corners(marker_id)[0]

    def all_corners(self) -> np.ndarray:
        return np.stack([self.marker_corners(i) for i in self.marker_ids])


def _split(m: MarkerObservation) -> list[MarkerObservation]:
    """A 4-corner observation as four one-point ones (centre: the point itself)."""
    out = []
    for c in range(4):
        rows = slice(2 * c, 2 * c + 2)
        depth = None if m.depth_m is None else m.depth_m[[1 + c, 1 + c]]
        depth_cov = None if m.depth_cov is None else m.depth_cov[np.ix_([1 + c, 1 + c], [1 + c, 1 + c])]
        out.append(
            replace(
                m,
                marker_id=4 * m.marker_id + c,
                corners_px=m.corners_px[c : c + 1],
                corners_cov=m.corners_cov[rows, rows],
                center_px=m.corners_px[c],
                center_cov=m.corners_cov[rows, rows],
                raw_corners_px=m.raw_corners_px[c : c + 1],
                depth_m=depth,
                depth_cov=depth_cov,
                points_cam=None if m.points_cam is None else m.points_cam[[1 + c, 1 + c]],
                points_cov=None if m.points_cov is None else m.points_cov[[1 + c, 1 + c]],
            )
        )
    return out


@pytest.mark.parametrize("method", ["ekf", "iekf", "ukf", "batch", "opencv-park"])
@pytest.mark.parametrize("map_model", ["board", "landmarks"])
def test_one_point_markers_give_the_four_corner_markers_mount(method: str, map_model: str) -> None:
    if method == "opencv-park" and map_model == "landmarks":
        pytest.skip("OpenCV has no map model")
    rng = np.random.default_rng(5)
    X = random_mount(rng)
    observations = scene(X, rng)
    split = [
        FrameObservations(o.frame, o.time_s, o.T_base_flange, [p for m in o.markers for p in _split(m)])
        for o in observations
    ]
    options = MethodOptions(map_model=map_model, learn_noise=False, robust=False)
    quads = solve(method, build_problem(observations, BOARD, INTRINSICS), options, observations)
    points = solve(method, build_problem(split, CornerBoard(BOARD), INTRINSICS), options, split)
    dt, dr = pose_error(points.T_flange_cam, quads.T_flange_cam)
    assert dt < 1e-6 and dr < 1e-7, (dt, dr)
    assert pose_error(points.T_flange_cam, X)[0] < 2e-3
    if quads.covariance is not None:
        np.testing.assert_allclose(points.covariance, quads.covariance, rtol=1e-5, atol=1e-14)
