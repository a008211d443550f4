"""Depth under markers, observations of whole datasets, the detections cache and `hec detect`."""

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from hec.cli import main
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.depth import DepthFitError, DepthNoiseModel, fit_marker_depth
from hec.estimator.observe.frames import Frame
from hec.estimator.observe.observations import (
    ObservationCacheError,
    dataset_depth_noise,
    load_observations,
    observe_dataset,
    observe_frame,
    save_observations,
)
from hec.estimator.targets.qr import DetectorSettings, QRDetector

K = CameraIntrinsics(640, 480, 617.0, 617.0, 319.5, 239.5)
CORNERS = np.array([[280.0, 200.0], [360.0, 205.0], [356.0, 285.0], [276.0, 280.0]])


def _tilted_plane_depth(normal: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(480, 640) exact depth of the plane n . p = n . point seen by K."""
    u, v = np.meshgrid(np.arange(640.0), np.arange(480.0))
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1)
    return (normal @ point) / (rays @ normal)


def test_depth_plane_is_unbiased_and_its_covariance_honest() -> None:
    normal = np.array([0.0, np.sin(np.radians(35)), -np.cos(np.radians(35))])
    truth = _tilted_plane_depth(normal, np.array([0.0, 0.0, 0.45]))
    model = DepthNoiseModel()
    rng = np.random.default_rng(0)
    centre = CORNERS.mean(axis=0)
    true_z = truth[int(centre[1]), int(centre[0])]  # centre lies between pixels: compare via the plane
    errors, variances = [], []
    for _ in range(200):
        noisy = truth + model.sigma(truth) * rng.standard_normal(truth.shape)
        noisy = np.round(noisy / model.depth_step_m) * model.depth_step_m
        noisy[rng.random(truth.shape) < 0.05] = 0.0  # holes
        noisy[rng.random(truth.shape) < 0.01] = 2.0  # outliers
        plane = fit_marker_depth(noisy, CORNERS, model)
        z, cov = plane.depth_at(np.array([[int(centre[0]), int(centre[1])]]))
        errors.append(z[0] - true_z)
        variances.append(cov[0, 0])
    errors = np.array(errors)
    assert abs(errors.mean()) < 3 * errors.std() / np.sqrt(len(errors))
    assert 0.7 <= np.mean(errors**2) / np.mean(variances) <= 1.4


def test_depth_plane_is_the_least_squares_plane_of_its_pixels() -> None:
    # No outliers and small noise: every valid pixel is an inlier, so the plane must be the SVD
    # least-squares plane of all of them (the fit solves the normal equations).
    normal = np.array([0.3, np.sin(np.radians(35)), -np.cos(np.radians(35))])
    depth = _tilted_plane_depth(normal / np.linalg.norm(normal), np.array([0.0, 0.0, 0.6]))
    depth *= 1.0 + 1e-4 * np.random.default_rng(1).standard_normal(depth.shape)
    plane = fit_marker_depth(depth, CORNERS, DepthNoiseModel())
    rows, cols = np.nonzero(_marker_mask(CORNERS))
    assert plane.inliers == plane.valid == len(rows)
    A = np.column_stack([np.ones(len(rows)), cols - plane.origin_px[0], rows - plane.origin_px[1]])
    expected, *_ = np.linalg.lstsq(A, 1.0 / depth[rows, cols], rcond=None)
    np.testing.assert_allclose(plane.coeffs, expected, rtol=1e-12, atol=1e-12 * abs(expected[0]))


def _marker_mask(corners: np.ndarray) -> np.ndarray:
    """(480, 640) bool: the pixels fit_marker_depth takes as under the marker."""
    mask = np.zeros((480, 640), dtype=np.uint8)
    cv2.fillConvexPoly(mask, np.round(corners * 16).astype(np.int32), 1, cv2.LINE_8, 4)
    return mask.astype(bool)


def test_depth_fit_refuses_an_empty_patch() -> None:
    with pytest.raises(DepthFitError, match="too few valid depth pixels"):
        fit_marker_depth(np.zeros((480, 640)), CORNERS, DepthNoiseModel())


def test_correlated_depth_noise_widens_the_covariance() -> None:
    truth = np.full((480, 640), 0.5)
    independent = fit_marker_depth(truth, CORNERS, DepthNoiseModel())
    correlated = fit_marker_depth(truth, CORNERS, DepthNoiseModel(correlation_px=4.0))
    np.testing.assert_allclose(correlated.coeffs_cov, 16.0 * independent.coeffs_cov)


@pytest.fixture(scope="module")
def dataset(default_dataset: Path):
    return load_dataset(default_dataset)


def test_unusable_depth_keeps_the_markers_without_depth(dataset) -> None:
    frame = dataset.frame(0)
    detector = QRDetector(dataset.board)
    for depth, expected in (
        (np.zeros_like(frame.depth_m), "no valid pixel"),
        (frame.depth_m[::2, ::2], "aligned"),
    ):
        changed = Frame(frame.rgb, depth, frame.intrinsics, frame.T_base_flange, frame.joints, frame.time_s)
        obs = observe_frame(0, changed, detector, dataset_depth_noise(dataset))
        assert len(obs.markers) == 8 and obs.problem is None
        assert any(expected in note for note in obs.notes)
        assert all(m.points_cam is None and expected in m.depth_note for m in obs.markers)


def test_missing_image_skips_that_frame_only(dataset, tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(dataset.root, copy)
    (copy / "rgb" / "000002.png").unlink()
    observations = observe_dataset(load_dataset(copy))
    assert "000002.png: image file missing" in observations[2].problem
    assert all(o.problem is None and len(o.markers) >= 7 for i, o in enumerate(observations) if i != 2)


def test_cache_round_trip_and_staleness(dataset, tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(dataset.root, copy)
    settings = DetectorSettings()
    observations = observe_dataset(load_dataset(copy), settings)
    save_observations(copy, observations, settings, dataset_depth_noise(dataset))
    loaded, loaded_settings, _ = load_observations(copy, settings)
    assert loaded_settings == settings
    for a, b in zip(observations, loaded, strict=True):
        assert [m.marker_id for m in a.markers] == [m.marker_id for m in b.markers]
        for ma, mb in zip(a.markers, b.markers, strict=True):
            np.testing.assert_array_equal(ma.corners_cov, mb.corners_cov)
            np.testing.assert_array_equal(ma.points_cov, mb.points_cov)
    with pytest.raises(ObservationCacheError, match="other detector settings"):
        load_observations(copy, DetectorSettings(passes=("pyzbar@1",)))
    with open(copy / "frames.csv", "a") as f:
        f.write("\n")
    with pytest.raises(ObservationCacheError, match="stale"):
        load_observations(copy)


def test_hec_detect_writes_cache_overlays_and_a_table(
    dataset, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(dataset.root, copy)
    assert main(["detect", str(copy), "--overlay", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert (copy / "detections.json").is_file()
    assert len(list((copy / "overlay").glob("*.png"))) == len(dataset)
    assert "vs ground truth:" in out and f"{len(dataset)} frames (0 skipped)" in out
    assert main(["detect", str(copy), "--passes", "nope@1"]) == 2
    assert "bad decoding pass 'nope@1'" in capsys.readouterr().err
