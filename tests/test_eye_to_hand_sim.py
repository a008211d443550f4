"""The simulated eye-to-hand cell: the camera on a stand, the board on the flange
(models/scenarios/eye_to_hand.toml). Its trajectory shows the fixed camera the default views, the
real renderer and detector work on it unchanged, and its dataset records the set-up and the truth
(T_base_cam, T_flange_board)."""

from __future__ import annotations

import numpy as np
import pytest

from hec.api import detect
from hec.estimator.common.setups import EYE_TO_HAND
from hec.estimator.geometry.camera import project
from hec.estimator.geometry.transforms import invert, pose_error
from hec.estimator.geometry.waypoints import rotation_rich_views, write_waypoint_file
from hec.estimator.io.dataset import load_dataset
from hec.sim.cell import SimCell
from hec.sim.scenario import Scenario, load_scenario
from hec.sim.simulate import scenario_waypoints, simulate

VIEWS = (0, 5, 9)  # head-on, tilted 32 degrees, rolled 20 degrees


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return load_scenario("eye_to_hand")


def test_the_shipped_scenario_is_eye_to_hand_and_eye_in_hand_ones_do_not_record_its_keys(
    scenario: Scenario,
) -> None:
    assert scenario.setup == EYE_TO_HAND and scenario.eye_to_hand
    assert {"setup", "stand", "board_mount"} <= set(scenario.to_dict())
    assert not {"setup", "stand", "board_mount"} & set(Scenario().to_dict())


def test_every_waypoint_shows_the_fixed_camera_the_board_as_the_default_views_do(scenario: Scenario) -> None:
    T_base_cam, T_flange_board = scenario.stand.transform(), scenario.board_mount.transform()
    views = rotation_rich_views(scenario.trajectory.distance_m)
    waypoints = scenario_waypoints(scenario)
    assert len(waypoints) == len(views)
    for waypoint, (_, T_board_cam) in zip(waypoints, views, strict=True):
        T_cam_board = invert(T_base_cam) @ waypoint.T_base_flange @ T_flange_board
        dt, dr = pose_error(T_cam_board, invert(T_board_cam))
        assert dt < 1e-12 and dr < 1e-12


def test_the_rendered_board_rides_on_the_flange_where_the_truth_says(scenario: Scenario) -> None:
    cell = SimCell(scenario.model_copy(update={"noise": scenario.noise.all_off()}), np.random.default_rng(0))
    try:
        waypoints = scenario_waypoints(scenario)
        for index in VIEWS:
            cell.move_to(waypoints[index])
            truth = cell.ground_truth()
            T_cam_board = invert(truth.T_base_cam) @ cell.true_flange_pose() @ truth.T_flange_board
            np.testing.assert_allclose(T_cam_board, cell.T_cam_board(), atol=1e-12)
            rgb, depth = cell.render_true()
            # the board's centre is where the truth projects it, at the depth the truth puts it
            u, v = np.round(project(T_cam_board, np.zeros((1, 3)), cell.intrinsics)[0]).astype(int)
            assert depth[v, u] == pytest.approx(T_cam_board[2, 3], abs=2e-3)
            assert 0.3 < T_cam_board[2, 3] < 0.7
    finally:
        cell.close()


def test_a_simulated_eye_to_hand_dataset_records_its_set_up_and_its_markers_are_all_detected(
    scenario: Scenario, tmp_path
) -> None:
    waypoints = [scenario_waypoints(scenario)[i] for i in VIEWS]
    write_waypoint_file(tmp_path / "views.csv", waypoints)
    short = scenario.model_copy(
        update={
            "trajectory": scenario.trajectory.model_copy(update={"kind": "file", "file": "views.csv"}),
            "base_dir": str(tmp_path),
        }
    )
    result = simulate(short, tmp_path / "data", seed=3, progress=False)
    assert result.frames == len(VIEWS) and not result.skipped
    dataset = load_dataset(result.out_dir)
    assert dataset.metadata["setup"] == EYE_TO_HAND
    truth = dataset.ground_truth
    assert truth.setup == EYE_TO_HAND and truth.T_flange_cam is None
    np.testing.assert_allclose(truth.hand_eye, scenario.stand.transform())
    np.testing.assert_allclose(truth.board_pose, scenario.board_mount.transform())
    observations = detect(dataset)
    assert [len(o.markers) for o in observations] == [len(dataset.board.marker_ids)] * len(VIEWS)
    for i, obs in enumerate(observations):
        T_cam_board = truth.T_cam_board(i)
        for marker in obs.markers:
            corners = dataset.board.marker_corners(marker.marker_id)
            expected = project(T_cam_board, corners, dataset.intrinsics)
            assert np.abs(np.asarray(marker.corners_px) - expected).max() < 0.5


def test_an_eye_to_hand_image_folder_imports_with_its_set_up_and_calibrates_to_the_fixed_camera(
    scenario: Scenario, tmp_path, capsys
) -> None:
    from hec.api import calibrate
    from hec.cli import main
    from hec.estimator.io.intrinsics_file import write_opencv_intrinsics
    from hec.estimator.io.layouts import write_folder
    from hec.estimator.io.pose_file import PoseConvention

    source = load_dataset(simulate(scenario, tmp_path / "rendered", seed=5, progress=False).out_dir)
    pngs = [(source.root / row["rgb"]).read_bytes() for row in source.rows]
    poses = np.array([row["T_base_flange"] for row in source.rows])
    convention = PoseConvention()
    folder = write_folder(tmp_path / "folder", pngs, poses, convention, None)
    camera = write_opencv_intrinsics(tmp_path / "camera.yaml", source.intrinsics)
    argv = [
        "import",
        "folder",
        str(folder / "images"),
        "--out",
        str(tmp_path / "imported"),
        "--board",
        "hec_8qr",
    ]
    argv += ["--intrinsics", str(camera), "--poses", str(folder / "poses.csv"), "--quiet"]
    assert main([*argv, "--setup", EYE_TO_HAND]) == 0
    assert "the robot poses fit the stated convention" in capsys.readouterr().out
    imported = load_dataset(tmp_path / "imported")
    assert imported.metadata["setup"] == EYE_TO_HAND
    result = calibrate(imported, "ekf", cross_validate=False)
    dt, dr = pose_error(result.T_flange_cam, scenario.stand.transform())
    assert result.setup == EYE_TO_HAND and dt < 1e-3 and np.degrees(dr) < 0.1


def test_planned_views_of_a_fixed_camera_are_reachable_and_show_it_the_board(
    scenario: Scenario, tmp_path
) -> None:
    from hec.cli import main

    plan = tmp_path / "planned.csv"
    argv = ["plan", "--scenario", "eye_to_hand", "--out", str(plan), "--views", "5", "--candidates", "200"]
    assert main(argv) == 0
    planned = scenario.model_copy(
        update={
            "trajectory": scenario.trajectory.model_copy(update={"kind": "file", "file": str(plan)}),
            "base_dir": str(tmp_path),
        }
    )
    result = simulate(planned, tmp_path / "data", seed=1, progress=False)
    assert result.frames == 5 and not result.skipped
    dataset = load_dataset(result.out_dir)
    # the board is found in every view (a far, steep view may lose a marker, eye-in-hand as well)
    assert all(len(o.markers) >= len(dataset.board.marker_ids) - 2 for o in detect(dataset))
