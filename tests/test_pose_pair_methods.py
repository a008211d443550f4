"""Calibrating from pose pairs: the model's Jacobians, exact pairs, honest uncertainty on noisy pairs
with the noise learned, degenerate motions, and `hec calibrate` / `hec detect` on an imported set."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hec.cli import main
from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.lie import pose_nees, pose_plus
from hec.estimator.geometry.transforms import invert, make_transform, pose_error
from hec.estimator.io.layouts import write_easy_handeye_samples
from hec.estimator.observe.pose_pairs import PosePair
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.pose_pair_methods import PAIR_NOISE_FREE, PosePairModel, solve_pose_pairs
from hec.estimator.solve.problem import CalibrationInputError

X_TRUE = make_transform(Rotation.from_rotvec([0.02, -0.01, 0.3]).as_matrix(), np.array([0.01, 0.006, 0.04]))
B_TRUE = make_transform(Rotation.from_rotvec([-1.5, 0.0, 0.1]).as_matrix(), np.array([0.15, -0.7, 0.45]))
SIGMAS = np.array([1e-4, 1e-4, 4e-4, np.radians(0.05), np.radians(0.05), np.radians(0.01)])


def _pairs(
    rng: np.random.Generator,
    count: int = 15,
    sigmas: np.ndarray | None = None,
    distances_m: tuple[float, ...] = (0.45,),
    tracking_scale: float = 1.0,
) -> list[PosePair]:
    """Views of the board from around it (flange poses that look at B_TRUE from the distances in
    turn), board poses with noise and their translations read tracking_scale x true."""
    pairs = []
    for i in range(count):
        view = make_transform(
            Rotation.from_rotvec(rng.normal(0, 0.35, 3)).as_matrix(),
            np.array([0.0, 0.0, -distances_m[i % len(distances_m)]]),
        )
        T_cam_board_true = invert(view)
        A = B_TRUE @ invert(T_cam_board_true) @ invert(X_TRUE)
        Z = (
            T_cam_board_true
            if sigmas is None
            else pose_plus(T_cam_board_true, sigmas * rng.standard_normal(6))
        )
        Z[:3, 3] *= tracking_scale
        pairs.append(PosePair(i, A, Z))
    return pairs


def test_jacobians_match_finite_differences() -> None:
    rng = np.random.default_rng(0)
    pairs = _pairs(rng, 1, SIGMAS)
    model = PosePairModel(pairs, RobotPoseNoise())
    X, B = pose_plus(X_TRUE, rng.normal(0, 0.01, 6)), pose_plus(B_TRUE, rng.normal(0, 0.01, 6))
    _, J, J_A = model.residual(X, B, 0)
    step, numeric = 1e-6, np.zeros((6, 18))
    for k in range(18):
        d = np.zeros(18)
        d[k] = step
        plus = PosePairModel(
            [PosePair(0, pose_plus(pairs[0].T_base_flange, d[12:]), pairs[0].T_cam_board)], RobotPoseNoise()
        )
        minus = PosePairModel(
            [PosePair(0, pose_plus(pairs[0].T_base_flange, -d[12:]), pairs[0].T_cam_board)], RobotPoseNoise()
        )
        r_plus = plus.residual(pose_plus(X, d[:6]), pose_plus(B, d[6:12]), 0)[0]
        r_minus = minus.residual(pose_plus(X, -d[:6]), pose_plus(B, -d[6:12]), 0)[0]
        numeric[:, k] = (r_plus - r_minus) / (2 * step)
    np.testing.assert_allclose(np.hstack([J, J_A]), numeric, atol=1e-7)


@pytest.mark.parametrize(
    "method", ["batch", "ekf", "iekf", "opencv-park", "opencv-daniilidis", "opencv-shah"]
)
def test_exact_pairs_give_the_mount(method: str) -> None:
    pairs = _pairs(np.random.default_rng(1))
    result = solve_pose_pairs(method, pairs, MethodOptions(), RobotPoseNoise(0.0, 0.0))
    error_m, error_rad = pose_error(result.T_flange_cam, X_TRUE)
    assert error_m < 1e-9 and error_rad < 1e-9, (error_m, error_rad)
    # Views at one distance cannot measure a scale common to the tracking poses: every method says so.
    assert "these views leave it undetermined (views at one distance)" in result.warnings[-1]
    assert not any("noise was learned" in w or "0.000" in w for w in result.warnings), result.warnings


@pytest.mark.parametrize("method", ["batch", "opencv-park"])
def test_a_tracking_scale_is_measured_from_the_data_and_unbiased_pairs_get_no_warning(method: str) -> None:
    """Views at two distances measure a scale common to the tracking poses' translations: 1 % is
    named with its size from the data (within 3 sigma), exact and unbiased noisy pairs get no bias
    warning, and exact pairs are not said to have learned a noise."""
    two = (0.35, 0.6)
    exact = solve_pose_pairs(
        method, _pairs(np.random.default_rng(1), distances_m=two), MethodOptions(), PAIR_NOISE_FREE
    )
    assert not any("tracking poses" in w for w in exact.warnings), exact.warnings
    if method == "batch":
        assert any("fit each other exactly" in w for w in exact.warnings), exact.warnings
    for seed in range(5):
        for scale in (1.0, 1.01):
            pairs = _pairs(np.random.default_rng(200 + seed), 20, SIGMAS, two, scale)
            result = solve_pose_pairs(method, pairs, MethodOptions(), PAIR_NOISE_FREE)
            said = [w for w in result.warnings if "tracking poses' translations read" in w]
            if scale == 1.0:
                assert not said, (seed, said)
                continue
            assert len(said) == 1, (seed, result.warnings)
            found = re.search(r"read ([-+][\d.]+) % \(\+-([\d.]+) %\)", said[0])
            assert abs(float(found.group(1)) - 1.0) < 3 * float(found.group(2)), said


def test_noise_is_learned_and_the_uncertainty_is_honest() -> None:
    """Pairs without covariance, noise per axis as a PnP pose has: the learned sigmas come back near
    the true ones and the mount's NEES averages about 6 over Monte-Carlo trials."""
    nees, learned = [], []
    for seed in range(40):
        pairs = _pairs(np.random.default_rng(100 + seed), 20, SIGMAS)
        result = solve_pose_pairs("batch", pairs, MethodOptions(), PAIR_NOISE_FREE)
        nees.append(pose_nees(result.T_flange_cam, X_TRUE, result.covariance))
        learned.append(result.diagnostics["learned_pose_sigma"])
        assert "its noise was learned from the data" in result.warnings[0]
    assert 4.5 < np.mean(nees) < 8.0, np.mean(nees)
    np.testing.assert_allclose(np.median(learned, axis=0), SIGMAS, rtol=0.25)


def test_too_few_pairs_or_one_rotation_axis_are_input_errors() -> None:
    pairs = _pairs(np.random.default_rng(2))
    with pytest.raises(CalibrationInputError, match="too few pose pairs: 2"):
        solve_pose_pairs("batch", pairs[:2], MethodOptions())
    flat = [
        PosePair(p.frame, make_transform(np.eye(3), p.T_base_flange[:3, 3]), p.T_cam_board) for p in pairs
    ]
    with pytest.raises(CalibrationInputError, match="do not span two axes"):
        solve_pose_pairs("batch", flat, MethodOptions())
    with pytest.raises(ValueError, match="method 'ukf' cannot use pose pairs"):
        solve_pose_pairs("ukf", pairs, MethodOptions())


def test_calibrate_and_detect_on_an_imported_pose_pair_set(tmp_path: Path, capsys) -> None:
    pairs = _pairs(np.random.default_rng(3), 12, SIGMAS)
    samples = write_easy_handeye_samples(tmp_path / "cell.samples", pairs)
    assert main(["import", "easy_handeye2", str(samples), "--out", str(tmp_path / "pairs")]) == 0
    capsys.readouterr()
    assert (
        main(["calibrate", str(tmp_path / "pairs"), "--method", "all", "--json", str(tmp_path / "c.json")])
        == 0
    )
    out = capsys.readouterr().out
    assert "observations: pose_pairs.json, imported from easy_handeye2; no images" in out
    assert "method: batch" in out and "method: opencv-tsai" in out and "residuals of the board poses" in out
    assert main(["detect", str(tmp_path / "pairs")]) == 2
    assert "holds imported pose pairs (pose_pairs.json) and no images" in capsys.readouterr().err
    assert (tmp_path / "pairs" / "pose_pairs.json").is_file()


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ([], None),
        (["--tracking-direction", "target-to-camera"], "pass --tracking-direction camera-to-target"),
        (["--pose-direction", "flange-to-base"], "pass --pose-direction base-to-flange"),
        (
            ["--pose-direction", "flange-to-base", "--tracking-direction", "target-to-camera"],
            "both inverted: they fit as well either way",
        ),
    ],
)
def test_import_names_a_wrong_pose_pair_direction(tmp_path: Path, capsys, options, named) -> None:
    samples = write_easy_handeye_samples(
        tmp_path / "cell.samples", _pairs(np.random.default_rng(4), 12, SIGMAS)
    )
    code = main(["import", "easy_handeye2", str(samples), "--out", str(tmp_path / "pairs"), *options])
    out, err = capsys.readouterr()
    if named is None:
        assert code == 0 and "convention check: the pose pairs fit the stated directions" in out
    else:  # refused: nothing written
        assert code == 2 and "the pose pairs look like" in err and named in err, err
        assert not (tmp_path / "pairs").exists()
