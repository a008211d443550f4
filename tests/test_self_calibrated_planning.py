"""View planning for a self-calibrating cell (measurement-level information, no renders): the
Jacobian of the full state against finite differences, the mount's information after the
self-calibration corrections are marginalised, and a planner that chooses by it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.kinematics import IK_RESTARTS, UR5, solve_ik_nearest
from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import Waypoint, look_at_board
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.problem import ReportedArm, build_problem
from hec.estimator.solve.self_calibrated_planning import (
    frame_jacobian,
    planning_groups,
    self_calibrated_informations,
)
from hec.estimator.solve.self_calibration import adjusted_problem, group_names, kinematic_jacobian
from hec.estimator.solve.view_planning import eliminate_board, plan_views, predicted_sigmas, view_informations
from hec.support.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount

NOISE = SyntheticNoise()
DISTANCE = SCENARIO.trajectory.distance_m
X = random_mount(np.random.default_rng(3))


def _views(distances: list[float]) -> list[Waypoint]:
    """Views turned about both in-plane axes and the optical axis, at each of the distances."""
    poses = [
        (0.0, 0.0, 0.0),
        (25.0, 0.0, 40.0),
        (25.0, 90.0, -40.0),
        (25.0, 180.0, 20.0),
        (25.0, 270.0, -20.0),
    ]
    poses += [(15.0, 45.0, 50.0), (15.0, 225.0, -50.0)]
    T_cam_flange = invert(X)
    return [
        Waypoint(i, f"view {i}", T_base_flange=T_BASE_BOARD @ look_at_board(t, a, r, d) @ T_cam_flange)
        for i, (d, (t, a, r)) in enumerate((d, p) for d in distances for p in poses)
    ]


def test_the_full_state_jacobian_matches_finite_differences() -> None:
    waypoints = _views([DISTANCE])[:3]
    flanges = [w.T_base_flange for w in waypoints]
    joints = {i: solve_ik_nearest(UR5, T, IK_RESTARTS[0]) for i, T in enumerate(flanges)}
    observations = synthetic_observations(
        BOARD, INTRINSICS, X, T_BASE_BOARD, flanges, NOISE, None, exact=True
    )
    problem = build_problem(observations, BOARD, INTRINSICS, NOISE.robot, arm=ReportedArm(UR5, joints))
    names = group_names(problem, planning_groups(BOARD, arm_known=True))
    state = HandEyeState(X, T_base_board=T_BASE_BOARD)
    frame = 1
    J, _ = frame_jacobian(problem, state, frame, names, kinematic_jacobian(UR5, joints[frame]))
    theta_columns = J[:, 12:]
    steps = np.where(np.char.startswith(np.array(names), "f"), 1e-3, 1e-7)  # focal lengths in pixels
    for j, name in enumerate(names):
        theta = np.zeros(len(names))
        theta[j] = steps[j]
        forward_problem, backward_problem = (adjusted_problem(problem, s * theta, names) for s in (1, -1))
        ahead = predict_frame(forward_problem, state, forward_problem.frames[frame], jacobians=False)
        behind = predict_frame(backward_problem, state, backward_problem.frames[frame], jacobians=False)
        # the residual is measured - predicted: its derivative is minus the prediction's
        numeric = -(ahead.residual - behind.residual) / (2 * steps[j])
        scale = max(np.abs(numeric).max(), 1e-6)
        assert np.abs(theta_columns[:, j] - numeric).max() <= 1e-4 * scale, name


def test_the_state_block_is_the_mount_only_information() -> None:
    waypoints = _views([DISTANCE])
    usable, mount_only = view_informations(waypoints, BOARD, INTRINSICS, X, T_BASE_BOARD, NOISE)
    full_usable, full, prior = self_calibrated_informations(
        waypoints, BOARD, INTRINSICS, X, T_BASE_BOARD, NOISE, ("board_scale",)
    )
    assert full_usable == usable and full.shape == (len(usable), 14, 14)
    np.testing.assert_allclose(full[:, :12, :12], mount_only, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(np.diag(prior)[12:], 1.0 / 0.03**2)


def test_a_print_scale_and_a_depth_scale_free_together_cost_the_mount_from_one_distance() -> None:
    """From one distance a print scale and a depth bias look alike: marginalising either alone costs
    the mount little (the other pins the distance), both together much of its information."""

    def loss(groups: tuple[str, ...]) -> float:
        _, full, prior = self_calibrated_informations(
            _views([DISTANCE]), BOARD, INTRINSICS, X, T_BASE_BOARD, NOISE, groups
        )
        marginal = eliminate_board(full.sum(axis=0) + prior)
        fixed = eliminate_board(full.sum(axis=0)[:12, :12])
        assert np.all(np.linalg.eigvalsh(fixed - marginal) > -1e-6 * np.abs(fixed).max())
        return float(np.linalg.slogdet(fixed)[1] - np.linalg.slogdet(marginal)[1])

    alone = max(loss(("board_scale",)), loss(("depth_bias",)))
    together = loss(("board_scale", "depth_bias"))
    assert alone < 0.5  # the bound's volume grows by under a factor 1.65
    assert together > 10 * alone


def test_the_planner_takes_several_distances_when_the_print_scale_is_free() -> None:
    """Offered the same views at three distances with the print scale and the depth bias free, the
    planner spreads its views over distances, and its mount beats the best plan from one distance."""
    distances = [0.7 * DISTANCE, DISTANCE, 1.3 * DISTANCE]
    waypoints = _views(distances)
    per_distance = len(waypoints) // len(distances)
    _, full, prior = self_calibrated_informations(
        waypoints, BOARD, INTRINSICS, X, T_BASE_BOARD, NOISE, ("board_scale", "depth_bias")
    )
    steps = plan_views(full, 6, "d-optimal", prior=prior)
    chosen_distances = {s.candidate // per_distance for s in steps}
    assert len(chosen_distances) >= 2
    # the plan's predicted mount sigma beats six views planned at the middle distance
    mount_only = plan_views(full[per_distance : 2 * per_distance, :12, :12], 6, "d-optimal")
    one_distance = [per_distance + s.candidate for s in mount_only]
    planned_mm, _ = predicted_sigmas(full[[s.candidate for s in steps]].sum(axis=0) + prior)
    one_distance_mm, _ = predicted_sigmas(full[one_distance].sum(axis=0) + prior)
    assert planned_mm < 0.8 * one_distance_mm


def test_the_kinematics_group_needs_reachable_views_and_the_arm() -> None:
    waypoints = _views([DISTANCE])
    groups = planning_groups(BOARD, arm_known=True)
    assert "kinematics" in groups and "marker_shifts" in groups
    assert "kinematics" not in planning_groups(BOARD, arm_known=False)
    usable, full, prior = self_calibrated_informations(
        waypoints, BOARD, INTRINSICS, X, T_BASE_BOARD, NOISE, groups, UR5
    )
    p = full.shape[-1] - 12
    assert p == 14 + 24 + 2 * len(BOARD.marker_ids) and len(usable) > 0
    # joint 6's corrections move the flange as the mount does: the mount's information with them
    # free is bounded by their priors however many views there are
    mount = eliminate_board(full.sum(axis=0) + prior)
    sigma_deg = np.degrees(np.sqrt(np.diag(np.linalg.inv(mount))[3:]))
    assert np.linalg.norm(sigma_deg) > 0.05


def test_a_real_cells_plan_marginalises_the_groups_its_calibration_kept() -> None:
    from hec.session.view_plan import kept_groups

    kept = ["marker_shifts", "kinematics", "intrinsics", "not_a_group"]
    result = {"noise": {"self_calibration": {"groups_kept": kept, "groups_tried": [*kept, "distortion"]}}}
    assert kept_groups(result) == ("intrinsics", "kinematics", "marker_shifts")
    assert kept_groups({"noise": {"self_calibration": None}}) == () == kept_groups({})


@pytest.mark.needs("sim")
def test_a_scenario_with_model_errors_plans_for_the_self_calibrated_state() -> None:
    """The realistic scenario plans over every group, the arm's kinematics too; the ideal one on the
    mount and board pose alone, as before."""
    from hec.session.view_plan import _plan, simulated_cell

    realistic = simulated_cell("realistic", 0.02)
    assert realistic.groups == planning_groups(realistic.board, arm_known=True)
    ideal = simulated_cell(None, 0.02)
    assert ideal.groups == () and ideal.kinematics is None
    plan = _plan(realistic, 6, None, "d-optimal", 150, 0.02, 0)
    assert plan.groups == realistic.groups and len(plan.views) == 6
    # the corrections' priors leave the mount a floor: the prediction stays above the ideal cell's
    ideal_plan = _plan(ideal, 6, None, "d-optimal", 150, 0.02, 0)
    assert plan.steps[-1].sigma_translation_mm > 2 * ideal_plan.steps[-1].sigma_translation_mm


@pytest.mark.needs("sim")
def test_an_adaptive_session_on_the_realistic_cell_marginalises_its_self_calibration(tmp_path: Path) -> None:
    """The adaptive session on a cell with model errors chooses by the self-calibrated state's
    information and records which groups it marginalised."""
    import json

    from tests.hec_cli import run_hec

    out = tmp_path / "rec"
    argv = ["record", "--sim", "--scenario", "realistic", "--target-sigma-mm", "0.001"]
    code, stdout, stderr = run_hec(
        [*argv, "--target-sigma-deg", "0.0001", "--max-views", "4", "--out", str(out)]
    )
    assert code == 0, stderr
    block = json.loads((out / "dataset.json").read_text())["session"]["adaptive"]
    assert block["views"] == 4 and "kinematics" in block["self_calibration_groups"]
    assert "board_scale" in block["self_calibration_groups"]
