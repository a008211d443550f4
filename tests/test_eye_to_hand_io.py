"""An eye-to-hand calibration (the camera fixed in the cell) through its file, hec export and hec
verify: every export format gives back T_base_cam, parented to the robot base, and the verification
tells a fixed camera moved by 1 mm / 0.2 degrees from one left alone. Measurement-level frames of the
eye-to-hand cell (hec.estimator.observe.synthetic), calibrated as hec calibrate does."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from hec.bench.verify import learned_levels
from hec.calibration.report import calibration_to_dict
from hec.calibration.run import check_poses_fit
from hec.cli import main
from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.lie import pose_plus
from hec.estimator.geometry.waypoints import eye_to_hand_waypoints
from hec.estimator.io.calibration_file import CALIBRATION_FORMAT, CALIBRATION_VERSION, read_calibration
from hec.estimator.io.export import realsense_link_optical
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import run_method
from hec.estimator.solve.noise_learning import learn_noise
from hec.estimator.solve.problem import CalibrationInputError, build_problem
from hec.estimator.solve.verify import VERIFY_VIEWS, spread_views, verification_problem, verify_mount
from hec.sim.scenario import load_scenario
from tests.test_export import _from_xyzw, _publisher_transform, _urdf_origin

SCENARIO = load_scenario("eye_to_hand")
BOARD, INTRINSICS = SCENARIO.board_definition(), SCENARIO.camera.intrinsics()
T_BASE_CAM, T_FLANGE_BOARD = SCENARIO.stand.transform(), SCENARIO.board_mount.transform()
NOISE = SyntheticNoise()


def _problem(T_base_cam: np.ndarray, flange: list[np.ndarray], rng: np.random.Generator):
    observations = synthetic_observations(
        BOARD, INTRINSICS, T_base_cam, T_FLANGE_BOARD, flange, NOISE, rng, setup=EYE_TO_HAND
    )
    return build_problem(observations, BOARD, INTRINSICS, NOISE.robot, setup=EYE_TO_HAND), observations


@pytest.fixture(scope="module")
def calibrated():
    """(the calibration, its learned noise levels, the trajectory's flange poses)."""
    flange = [w.T_base_flange for w in eye_to_hand_waypoints(T_BASE_CAM, T_FLANGE_BOARD, 0.45)]
    problem, observations = _problem(T_BASE_CAM, flange, np.random.default_rng(11))
    options = MethodOptions()
    learned = learn_noise(problem, options)
    return run_method("ekf", problem, options, observations, learned), learned_levels(learned), flange


@pytest.fixture(scope="module")
def calibration_file(calibrated, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cal") / "cal.json"
    data = {"format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION} | calibration_to_dict(calibrated[0])
    path.write_text(json.dumps(data))
    return path


OPTICAL = "camera_color_optical_frame"  # the optical frame: T_base_cam itself


def _export(calibration_file: Path, fmt: str, capsys, *more: str) -> str:
    """The export's text; camera_link (the default child) taken at RealSense's zero offset."""
    more = more or ("--child", OPTICAL)
    assert main(["export", str(calibration_file), "--to", fmt, "--assume-zero-offset", *more]) == 0
    return capsys.readouterr().out


def test_the_file_names_the_fixed_camera_and_reads_back(calibrated, calibration_file: Path) -> None:
    data = json.loads(calibration_file.read_text())
    assert data["setup"] == EYE_TO_HAND and "T_flange_cam" not in data and "T_flange_board" in data
    cal = read_calibration(calibration_file)
    assert cal.setup == EYE_TO_HAND and cal.hand_eye_name == "T_base_cam"
    np.testing.assert_allclose(cal.T_flange_cam, calibrated[0].T_flange_cam, atol=1e-12)
    assert np.abs(cal.T_flange_cam - T_BASE_CAM).max() < 2e-3  # the calibration found the camera


def test_every_export_gives_back_T_base_cam_from_the_robot_base(calibration_file: Path, capsys) -> None:
    T_base_cam = read_calibration(calibration_file).T_flange_cam
    tree = ast.parse(_export(calibration_file, "ros2-launch", capsys))
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node")
    arguments = ast.literal_eval(next(k.value for k in call.keywords if k.arg == "arguments"))
    T, parent, _ = _publisher_transform(arguments)
    assert parent == "base_link" and np.abs(T - T_base_cam).max() < 1e-9
    words = _export(calibration_file, "ros2-args", capsys).splitlines()[-1].split()
    assert np.abs(_publisher_transform(words[4:])[0] - T_base_cam).max() < 1e-9
    T_link, parent, child = _urdf_origin(_export(calibration_file, "urdf", capsys, "--child", "camera_link"))
    assert (parent, child) == ("base_link", "camera_link")
    assert np.abs(T_link @ realsense_link_optical() - T_base_cam).max() < 1e-9
    calib = yaml.safe_load(_export(calibration_file, "easy_handeye2", capsys))
    assert calib["parameters"]["calibration_type"] == "eye_on_base"
    assert calib["parameters"]["robot_base_frame"] == "base_link"
    t, r = calib["transform"]["translation"], calib["transform"]["rotation"]
    assert np.abs(_from_xyzw([t[k] for k in "xyz"], [r[k] for k in "xyzw"]) - T_base_cam).max() < 1e-9
    for fmt, load in (("yaml", yaml.safe_load), ("json", json.loads)):
        record = load(_export(calibration_file, fmt, capsys))
        assert record["parent_frame"] == "base_link" and "cam2base" in record["use"]
        assert np.abs(np.array(record["matrix"]) - T_base_cam).max() < 1e-9


def test_verification_tells_a_moved_fixed_camera_from_one_left_alone(calibrated) -> None:
    cal, levels, flange = calibrated
    views = spread_views(flange, VERIFY_VIEWS)
    rng = np.random.default_rng(12)
    along = np.array([0.6, -0.6, 0.53]) / np.linalg.norm([0.6, -0.6, 0.53])
    cases = {
        "unmoved": T_BASE_CAM,
        "1 mm": pose_plus(T_BASE_CAM, np.concatenate([1e-3 * along, np.zeros(3)])),
        "0.2 deg": pose_plus(T_BASE_CAM, np.concatenate([np.zeros(3), np.radians(0.2) * along])),
    }
    verdicts = {}
    for case, T_base_cam in cases.items():
        problem, _ = _problem(T_base_cam, views, rng)
        v = verify_mount(verification_problem(problem, levels), cal.T_flange_cam, cal.covariance)
        verdicts[case] = v.moved
    assert verdicts == {"unmoved": False, "1 mm": True, "0.2 deg": True}


def test_eye_to_hand_frames_read_as_eye_in_hand_are_refused_naming_the_set_up(tmp_path: Path) -> None:
    flange = [w.T_base_flange for w in eye_to_hand_waypoints(T_BASE_CAM, T_FLANGE_BOARD, 0.45)]
    _, observations = _problem(T_BASE_CAM, flange, np.random.default_rng(3))
    dataset = Dataset(tmp_path, {}, INTRINSICS, BOARD, 0.001, [], None)
    for setup, named in ((EYE_IN_HAND, EYE_TO_HAND), (EYE_TO_HAND, None)):
        problem = build_problem(observations, BOARD, INTRINSICS, NOISE.robot, setup=setup)
        if named is None:
            check_poses_fit(dataset, problem)  # the right set-up fits
            continue
        with pytest.raises(CalibrationInputError, match=f'record "setup": "{named}"'):
            check_poses_fit(dataset, problem)
