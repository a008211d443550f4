"""The corner noise floor learned from how well a dataset's markers agree
(hec.estimator.observe.corner_noise)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.camera import CameraIntrinsics, project
from hec.estimator.geometry.lie import so3_exp
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.io.board_file import find_board
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.corner_noise import fit_board_views, learn_corner_floor, measured_noise
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.grading import grade_observations
from hec.estimator.observe.observations import (
    FrameObservations,
    MarkerObservation,
    ObservationCacheError,
    load_observations,
    observe_dataset,
    with_pixel_floor,
)
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.qr_fit import center_from_corners
from tests.conftest import TEST_SEED
from tests.hec_cli import run_hec, scenario_file

BOARD = find_board("hec_8qr")
DECLARED = CameraIntrinsics(640, 480, 617.0, 617.0, 319.5, 239.5)


@pytest.fixture(scope="module")
def realistic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three views of the realistic cell (lens and intrinsics undeclared, blur, lighting, a bent
    and shifted print), rendered."""
    from hec.sim.scenario import load_scenario
    from hec.sim.simulate import simulate

    folder = tmp_path_factory.mktemp("realistic")
    toml = (models_dir() / "scenarios" / "realistic.toml").read_text()
    scenario = load_scenario(scenario_file(folder / "scenario", 3, toml))
    return simulate(scenario, folder / "d", TEST_SEED, progress=False).out_dir


@pytest.fixture(scope="module")
def dataset(realistic: Path) -> Dataset:
    return load_dataset(realistic)


@pytest.fixture(scope="module")
def detected(dataset: Dataset) -> tuple[list[FrameObservations], list[FrameObservations]]:
    """The realistic frames' observations on the constant floor and on the learned one."""
    settings = DetectorSettings()
    constant = observe_dataset(dataset, settings)
    return constant, learn_corner_floor(constant, dataset.board, dataset.intrinsics, settings)[0]


def test_the_learned_floor_makes_the_realistic_cells_corner_errors_honest(dataset: Dataset, detected) -> None:
    """With the constant floor the normalised corner errors exceed 3 (25 here); with
    the learned one they are near 1 (1.1 here, corners and centres; 1.4-1.5 on the 17 views of
    hec.bench.corner_noise: biases all markers of a frame share do not show in their
    agreement). Graded against the corners as printed, through the true lens."""
    constant, learned = (
        grade_observations(o, dataset.ground_truth, dataset.board, dataset.intrinsics).summary()
        for o in detected
    )
    assert constant["wrong_id"] == 0 and constant["corner_rms_px"] < 0.2, constant
    assert constant["corner_nees"] > 3.0 and constant["center_px_nees"] > 3.0, constant
    assert 0.7 <= learned["corner_nees"] <= 2.0, learned
    assert 0.5 <= learned["center_px_nees"] <= 2.5, learned


def test_hec_detect_prints_and_caches_the_learned_floor(realistic: Path, tmp_path: Path) -> None:
    copy = tmp_path / "d"
    shutil.copytree(realistic, copy)
    code, out, _ = run_hec(["detect", str(copy), "--quiet"])
    assert code == 0
    line = next(s for s in out.splitlines() if s.startswith("corner noise floor: measured "))
    assert "degrees of freedom; constant 0.013 px); covariances use the measured (floor" in line
    cached = json.loads((copy / "detections.json").read_text())
    assert cached["detector"]["learn_corner_floor"] is True
    floor = cached["corner_noise"]["floor_px"]
    assert f"floor {floor:.3f} px" in line and 0.03 < floor < 0.1
    observations, _, _ = load_observations(copy, DetectorSettings())
    marker = next(m for o in observations for m in o.markers)
    assert np.all(np.diag(marker.corners_cov) > floor**2)
    with pytest.raises(ObservationCacheError, match="other detector settings"):
        load_observations(copy, DetectorSettings(learn_corner_floor=False))


def test_a_cache_from_before_the_learned_floor_says_it_used_the_constant() -> None:
    settings = DetectorSettings().to_dict()
    del settings["learn_corner_floor"]
    assert DetectorSettings.from_dict(settings) == DetectorSettings(learn_corner_floor=False)


def test_the_3d_covariances_follow_the_pixel_floor(dataset: Dataset, detected) -> None:
    """with_pixel_floor adds to every corner and centre variance and grows the points' covariances
    by what that variance maps to; with nothing added they stay as the detector made them."""
    marker = next(m for o in detected[0] for m in o.markers if m.points_cov is not None)
    same = with_pixel_floor(marker, 0.0, 0.0, dataset.intrinsics)
    np.testing.assert_allclose(same.points_cov, marker.points_cov, rtol=1e-9, atol=1e-18)
    grown = with_pixel_floor(marker, 0.05**2, 0.01**2, dataset.intrinsics)
    np.testing.assert_allclose(grown.corners_cov - marker.corners_cov, 0.05**2 * np.eye(8), atol=1e-15)
    np.testing.assert_allclose(grown.center_cov - marker.center_cov, 0.01**2 * np.eye(2), atol=1e-15)
    assert np.all(np.linalg.eigvalsh(grown.points_cov - marker.points_cov) > -1e-18)
    assert np.all(np.trace(grown.points_cov - marker.points_cov, axis1=1, axis2=2) > 0.0)


def _synthetic_views(rng: np.random.Generator, sigma_px: float, frames: int = 8) -> list[FrameObservations]:
    """Frames of the board seen through a lens the intrinsics do not declare (k1 0.12, k2 -0.25,
    fx 0.3 % and cx 3 px off), printed 0.7 mm bent with markers 50 um off, corners with white
    noise sigma_px; covariances the constant floor."""
    true_camera = CameraIntrinsics(640, 480, 618.9, 617.0, 322.5, 239.5, (0.12, -0.25, 0.0, 0.0, 0.0))
    shifts = rng.normal(0.0, 50e-6, (8, 2))
    settings = DetectorSettings()
    cov, center_cov = settings.corner_floor_px**2 * np.eye(8), settings.center_floor_px**2 * np.eye(2)
    observations = []
    for i in range(frames):
        R = so3_exp(np.array([np.pi, 0.0, 0.0]) + rng.normal(0.0, 0.35, 3))
        T_cam_board = make_transform(R, np.array([0.0, 0.0, 0.45]) + rng.normal(0.0, 0.03, 3))
        markers = []
        for j, marker_id in enumerate(BOARD.marker_ids):
            p = BOARD.marker_corners(marker_id)
            p[:, :2] += shifts[j]
            p[:, 2] = 0.0007 * (1.0 - (2.0 * p[:, 0] / BOARD.size_m[0]) ** 2)
            corners = project(T_cam_board, p, true_camera) + rng.normal(0.0, sigma_px, (4, 2))
            center = center_from_corners(corners)
            markers.append(
                MarkerObservation(marker_id, corners, cov, center, center_cov, 1.0, 1.0, 1.0, "test", corners)
            )
        observations.append(FrameObservations(i, float(i), np.eye(4), markers))
    return observations


def test_the_markers_agreement_measures_the_corner_noise_not_the_lens_or_the_print() -> None:
    """On corners with 0.04 px of noise behind an undeclared lens and a bent, shifted print the
    measured noise is 0.04 px; one homography per frame through the declared lens sees the
    lens as noise."""
    observations = _synthetic_views(np.random.default_rng(3), 0.04)
    settings = DetectorSettings()
    _, noise = learn_corner_floor(observations, BOARD, DECLARED, settings)
    assert noise.measured_px == pytest.approx(0.04, rel=0.1)
    assert noise.floor_px == pytest.approx(0.04, rel=0.1)
    assert noise.center_floor_px == pytest.approx(noise.floor_px * 0.0036 / 0.013)
    plain = fit_board_views(observations, BOARD, DECLARED, settings, lens=False, printed=False)
    assert measured_noise(plain.residuals, plain.dof_factor) > 3 * noise.measured_px


def test_noise_below_the_constant_keeps_the_constant() -> None:
    observations = _synthetic_views(np.random.default_rng(4), 0.005)
    learned, noise = learn_corner_floor(observations, BOARD, DECLARED, DetectorSettings())
    assert noise.measured_px < noise.constant_px == noise.floor_px
    assert "covariances use the constant" in noise.describe()
    np.testing.assert_array_equal(learned[0].markers[0].corners_cov, observations[0].markers[0].corners_cov)


def test_too_few_markers_keep_the_constant_and_say_why() -> None:
    observations = _synthetic_views(np.random.default_rng(5), 0.04, frames=1)
    observations[0].markers = observations[0].markers[:2]
    _, noise = learn_corner_floor(observations, BOARD, DECLARED, DetectorSettings())
    assert noise.measured_px is None and noise.floor_px == noise.constant_px
    assert "not measured (fewer than 16 degrees of freedom" in noise.describe()
    assert (
        learn_corner_floor(observations, BOARD, DECLARED, DetectorSettings(learn_corner_floor=False))[1]
        is None
    )
