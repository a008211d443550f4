"""View planning on the default simulated cell's geometry (measurement-level information, no
renders): candidates, the information each adds, and the greedy choice against the default list."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.kinematics import UR5, forward
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.geometry.waypoints import Waypoint, read_waypoint_file, rotation_rich_waypoints
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.observability import frame_information, state_information
from hec.estimator.solve.problem import build_problem
from hec.estimator.solve.view_planning import (
    CRITERIA,
    candidate_views,
    eliminate_board,
    plan_views,
    predicted_sigmas,
    reachable,
    view_informations,
)
from hec.support.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount
from tests.hec_cli import run_hec

NOISE = SyntheticNoise()
DISTANCE = SCENARIO.trajectory.distance_m


def _candidates(seed: int, count: int = 300) -> tuple[np.ndarray, list[Waypoint], list[int], np.ndarray]:
    rng = np.random.default_rng(seed)
    X = random_mount(rng)
    candidates = candidate_views(T_BASE_BOARD, X, DISTANCE, count, rng)
    usable, informations = view_informations(candidates, BOARD, INTRINSICS, X, T_BASE_BOARD, NOISE)
    return X, candidates, usable, informations


def test_frame_informations_sum_to_the_state_information() -> None:
    X = random_mount(np.random.default_rng(5))
    flanges = [w.T_base_flange for w in rotation_rich_waypoints(T_BASE_BOARD, X, DISTANCE)]
    observations = synthetic_observations(
        BOARD, INTRINSICS, X, T_BASE_BOARD, flanges, NOISE, None, exact=True
    )
    problem = build_problem(observations, BOARD, INTRINSICS, NOISE.robot)
    state = HandEyeState(X, T_base_board=T_BASE_BOARD)
    total = sum(frame_information(problem, state, f) for f in problem.frames)
    np.testing.assert_allclose(total, state_information(problem, state), rtol=1e-12, atol=1e-9)


def test_candidates_keep_only_views_with_every_marker_in_the_image() -> None:
    X, candidates, usable, informations = _candidates(1, 200)
    assert 0.5 * len(candidates) < len(usable) < len(candidates)  # rolls and tilts push some out
    assert informations.shape == (len(usable), 12, 12)
    flanges = [candidates[i].T_base_flange for i in usable]
    observations = synthetic_observations(
        BOARD, INTRINSICS, X, T_BASE_BOARD, flanges, NOISE, None, exact=True
    )
    assert all(len(o.markers) == len(BOARD.marker_ids) for o in observations)
    dropped = [candidates[i].T_base_flange for i in range(len(candidates)) if i not in set(usable)]
    observations = synthetic_observations(
        BOARD, INTRINSICS, X, T_BASE_BOARD, dropped, NOISE, None, exact=True, margin_px=20.0
    )
    assert all(len(o.markers) < len(BOARD.marker_ids) for o in observations)


def _worst_sigma(state_information: np.ndarray) -> float:
    """The bound's worst direction in units of 0.15 mm and 0.015 deg (plan_views' default)."""
    units = np.r_[np.full(3, 0.15e-3), np.full(3, np.radians(0.015))]
    mount = eliminate_board(state_information) * units[:, None] * units[None, :]
    return float(1.0 / np.sqrt(np.linalg.eigvalsh(mount)[0]))


@pytest.mark.parametrize("criterion", CRITERIA)
@pytest.mark.parametrize("seed", [1, 2])
def test_planned_views_reach_the_default_lists_bound_with_at_most_half_its_views(
    criterion: str, seed: int
) -> None:
    """What the default 17 views reach at the end, at most 8 planned views reach: d-optimal both
    RSS 1-sigmas (translation and rotation), worst-direction the bound's worst direction. Each
    added view lowers the prediction (information only adds); no candidate is chosen twice."""
    X, _, _, informations = _candidates(seed)
    default = rotation_rich_waypoints(T_BASE_BOARD, X, DISTANCE)
    usable, default_informations = view_informations(default, BOARD, INTRINSICS, X, T_BASE_BOARD, NOISE)
    assert len(usable) == len(default)
    final_mm, final_deg = predicted_sigmas(default_informations.sum(axis=0))
    final_worst = _worst_sigma(default_informations.sum(axis=0))
    steps = plan_views(informations, 17, criterion)
    totals = np.cumsum(informations[[s.candidate for s in steps]], axis=0)
    if criterion == "d-optimal":
        reached = [s.sigma_translation_mm <= final_mm and s.sigma_rotation_deg <= final_deg for s in steps]
    else:
        reached = [k >= 2 and _worst_sigma(total) <= final_worst for k, total in enumerate(totals)]
    assert any(reached) and reached.index(True) + 1 <= 8, (reached, final_mm, final_deg, final_worst)
    sigmas = np.array([(s.sigma_translation_mm, s.sigma_rotation_deg) for s in steps[3:]])
    assert np.all(np.diff(sigmas, axis=0) <= 1e-12)
    assert len({s.candidate for s in steps}) == len(steps)


def test_planning_stops_at_the_target() -> None:
    _, _, _, informations = _candidates(3)
    steps = plan_views(informations, 40, "d-optimal", target_sigma=(0.3, 0.05))
    last = steps[-1]
    assert last.sigma_translation_mm <= 0.3 and last.sigma_rotation_deg <= 0.05
    before = steps[-2]
    assert before.sigma_translation_mm > 0.3 or before.sigma_rotation_deg > 0.05
    assert len(steps) < 40


def test_the_views_already_taken_count_toward_the_next_choice_and_its_prediction() -> None:
    """With recorded, a step's choice and prediction are those of the recorded views plus it."""
    _, _, _, informations = _candidates(3)
    recorded, offered = informations[:4].sum(axis=0), informations[4:]
    steps = plan_views(offered, 2, "d-optimal", recorded=recorded)
    without = plan_views(offered, 1, "d-optimal")
    assert steps[0].candidate != without[0].candidate
    mm, deg = predicted_sigmas(recorded + offered[steps[0].candidate])
    assert (steps[0].sigma_translation_mm, steps[0].sigma_rotation_deg) == pytest.approx((mm, deg), rel=1e-12)
    best_mm = min(predicted_sigmas(recorded + info)[0] for info in offered)
    assert steps[0].sigma_translation_mm < 2 * best_mm


def test_an_unknown_criterion_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown criterion 'a-optimal'"):
        plan_views(np.zeros((3, 12, 12)), 3, "a-optimal")


def test_reachability_uses_the_arms_kinematics_and_the_workspace_box() -> None:
    X = random_mount(np.random.default_rng(4))
    near = rotation_rich_waypoints(T_BASE_BOARD, X, DISTANCE)[0]
    seed = np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
    joints = reachable(near, UR5, seed)
    assert joints is not None
    np.testing.assert_allclose(forward(UR5, joints), near.T_base_flange, atol=1e-7)
    far = Waypoint(0, "3 m away", T_base_flange=make_transform(np.eye(3), np.array([3.0, 0.0, 0.0])))
    assert reachable(far, UR5, seed) is None
    p = near.T_base_flange[:3, 3]
    assert reachable(near, UR5, seed, (p + 0.01, p + 1.0)) is None


def test_a_refused_candidate_is_skipped_and_never_offered_again() -> None:
    _, _, _, informations = _candidates(4, 100)
    free_choice = plan_views(informations, 5)
    asked: list[int] = []

    def accept(candidate: int) -> bool:
        asked.append(candidate)
        return candidate != free_choice[1].candidate

    steps = plan_views(informations, 5, accept=accept)
    assert steps[0].candidate == free_choice[0].candidate
    assert free_choice[1].candidate not in [s.candidate for s in steps]
    assert asked.count(free_choice[1].candidate) == 1 and len(steps) == 5


@pytest.mark.needs("sim")
def test_hec_plan_writes_planned_views_the_simulator_renders_and_calibrates(tmp_path: Path) -> None:
    """hec plan's 8 views (corners assumed at 0.02 px, as the renders give) predict less than the
    default 17 views do; rendered, detected and calibrated, the mount is within 0.3 mm / 0.03 deg
    of the truth with an honest NEES."""
    out = tmp_path / "planned.csv"
    code, said, err = run_hec(
        ["plan", "--out", str(out), "--views", "8", "--candidates", "300", "--corner-sigma-px", "0.02"]
    )
    assert code == 0, err
    waypoints = read_waypoint_file(out)
    # The first views cannot determine the mount yet: they say so instead of an infinite sigma.
    determined = ["predicted 1-sigma" in w.label for w in waypoints]
    assert len(waypoints) == 8 and determined[-1] and determined == sorted(determined)
    assert all(
        ok or "mount not determined yet" in w.label for ok, w in zip(determined, waypoints, strict=True)
    )
    assert "inf" not in said
    last = re.findall(r"predicted 1-sigma ([0-9.]+) mm / ([0-9.]+) deg", said)[-1]
    default = re.search(r"the default 17 views predict ([0-9.]+) mm / ([0-9.]+) deg", said)
    assert float(last[0]) < float(default[1]) and float(last[1]) < float(default[2]), said
    (tmp_path / "scenario.toml").write_text('[trajectory]\nkind = "file"\nfile = "planned.csv"\n')
    dataset = tmp_path / "ds"
    for argv in (
        ["simulate", "--out", str(dataset), "--scenario", str(tmp_path / "scenario.toml"), "--quiet"],
        ["detect", str(dataset), "--quiet"],
    ):
        code, _, err = run_hec(argv)
        assert code == 0, err
    code, report, err = run_hec(["calibrate", str(dataset), "--verbose"])
    assert code == 0, err
    errors = re.search(
        r"translation error ([0-9.]+) mm, rotation error ([0-9.]+) deg.*NEES, ~6 if honest\) ([0-9.]+)",
        report,
    )
    assert float(errors[1]) < 0.3 and float(errors[2]) < 0.03 and float(errors[3]) < 20.0, report


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--target-sigma-mm", "0.2"], "--target-sigma-mm and --target-sigma-deg go together"),
        (["--views", "5", "--target-sigma-mm", "0.2", "--target-sigma-deg", "0.02"], "not both"),
        (["--views", "2"], "at least 3 views"),
        (["--target-sigma-mm", "0", "--target-sigma-deg", "0.02"], "both must be > 0"),
        (["--views", "20", "--candidates", "10"], "--candidates 10 must be at least the views (20)"),
        (["--calibration", "c.json", "--scenario", "realistic"], "not both"),
        (["--cell", "cell.toml"], "--cell: only with --calibration"),
    ],
)
def test_hec_plan_refuses_bad_options(tmp_path: Path, argv: list[str], said: str) -> None:
    code, _, err = run_hec(["plan", "--out", str(tmp_path / "w.csv"), *argv])
    assert code == 2 and said in err, err
    assert not (tmp_path / "w.csv").exists()


def test_hec_plan_for_a_real_cell_keeps_its_views_in_the_cell_files_workspace_box(
    tmp_path: Path, default_dataset: Path
) -> None:
    """Planned from a calibration and its dataset, with the workspace box just around the recorded
    flange positions: every planned flange is inside the box and reachable, and the plan predicts
    less than the recorded views do."""
    from hec.estimator.io.dataset import load_dataset

    cal = tmp_path / "cal.json"
    code, _, err = run_hec(
        ["calibrate", str(default_dataset), "--no-loo", "--json", str(cal), "--quiet", "--verbose"]
    )
    assert code == 0, err
    recorded = np.array([row["T_base_flange"][:3, 3] for row in load_dataset(default_dataset).rows])
    lower, upper = recorded.min(axis=0) - 0.02, recorded.max(axis=0) + 0.02
    cell = tmp_path / "cell.toml"
    cell.write_text(f"[robot]\nworkspace_lower_m = {lower.tolist()}\nworkspace_upper_m = {upper.tolist()}\n")
    out = tmp_path / "planned.csv"
    argv = ["plan", "--out", str(out), "--calibration", str(cal), "--cell", str(cell), "--views", "10"]
    code, said, err = run_hec([*argv, "--candidates", "400", "--corner-sigma-px", "0.05"])
    assert code == 0, err
    waypoints = read_waypoint_file(out)
    assert len(waypoints) == 10
    for w in waypoints:
        p = w.T_base_flange[:3, 3]
        assert np.all(p >= lower) and np.all(p <= upper), p
        assert reachable(w, UR5, np.zeros(6)) is not None
    last = re.findall(r"predicted 1-sigma ([0-9.]+) mm / ([0-9.]+) deg", said)[-1]
    recorded_sigma = re.search(r"the 17 views of \S+ predict ([0-9.]+) mm / ([0-9.]+) deg", said)
    assert recorded_sigma is not None, said
    assert float(last[0]) < float(recorded_sigma[1]) and float(last[1]) < float(recorded_sigma[2]), said
