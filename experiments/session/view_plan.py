"""Views chosen by the information about T_flange_cam they add (hec.estimator.solve.view_planning),
as a waypoint file that `hec record`, `hec run` and a scenario's `trajectory.kind = "file"` take:
what `hec plan` and hec.plan compute.

The candidates are predicted with a nominal mount, board pose, camera, robot pose noise and depth
noise, and a corner noise the detector reports (corner_sigma_px). They come from either
- a simulated cell's scenario (the built-in one by default): each view the planner would choose is
  first checked in the simulated cell as `hec simulate` checks a waypoint
  (hec.sim.cell.SimCell.accepts: inverse kinematics within the joint limits from the previous view's
  joints, no collision, every marker in view and not hidden), or
- a real cell's calibration (a calibration file, a cell file and the dataset it came from): its
  mount and board pose, the dataset's camera, board, depth noise and viewing distance, the cell
  file's arm, pose noise, joint limits and workspace box (nominal kinematics; no renderer).
A refused view is passed over and the next best taken.

A cell that self-calibrates plans on the whole state the default method estimates there
(hec.estimator.solve.self_calibrated_planning): a scenario with model errors switched on, every
group planning_groups names (the arm's kinematics when its arm errors are on); a real cell's
calibration that self-calibrated, the groups it kept. Otherwise the plan is on the mount and the
board pose alone."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hec.estimator.common.files import check_output_file, refuse_writing_over_inputs, write_atomic
from hec.estimator.common.setups import BOARD_POSE_NAMES, EYE_IN_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import IK_RESTARTS, ROBOTS, URKinematics
from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import (
    Waypoint,
    eye_to_hand_waypoints,
    rotation_rich_waypoints,
    waypoint_csv,
)
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.self_calibrated_planning import planning_groups, self_calibrated_informations
from hec.estimator.solve.self_calibration import NUISANCE_GROUPS
from hec.estimator.solve.setup_roles import model_pose
from hec.estimator.solve.view_planning import (
    CRITERIA,
    PlanStep,
    candidate_views,
    plan_views,
    predicted_sigmas,
    reachable,
    view_informations,
)
from hec.estimator.targets.target import Target

if TYPE_CHECKING:
    from hec.sim.scenario import Scenario

DEFAULT_VIEWS = 12
DEFAULT_MAX_VIEWS = 40


class PlanError(ValueError):
    """Options that do not make a plan, or a cell that admits none: the one-line message `hec plan`
    prints (nothing is written)."""


@dataclass(frozen=True)
class PlanningCell:
    """What planning needs of a cell: the board and camera, the nominal T_flange_cam and T_base_board
    ((4, 4), metres; eye-to-hand T_base_cam and T_flange_board, hec.estimator.solve.setup_roles), a
    frame's noise, the nominal distance to the board (m), accepts (True when the arm can take a view
    from the last view accepted), the views to compare with (name, waypoints) and the set-up. A cell
    that self-calibrates: groups (NUISANCE_GROUPS planned for), the arm's nominal kinematics and the
    joints its views start from (for the kinematics group)."""

    board: Target
    intrinsics: CameraIntrinsics
    T_flange_cam: np.ndarray
    T_base_board: np.ndarray
    noise: SyntheticNoise
    distance_m: float
    accepts: Callable[[Waypoint], bool]
    reference: tuple[str, list[Waypoint]]
    setup: str = EYE_IN_HAND
    groups: tuple[str, ...] = ()
    kinematics: URKinematics | None = None
    start_joints: np.ndarray | None = None

    def informations(self, waypoints: list[Waypoint]) -> tuple[list[int], np.ndarray, np.ndarray | None]:
        """The usable waypoints (indices), their (n, d, d) informations and the (d, d) prior on the
        self-calibration corrections (None without them), at the nominal values."""
        nominal = (self.board, self.intrinsics, self.T_flange_cam, self.T_base_board, self.noise)
        if not self.groups:
            return *view_informations(waypoints, *nominal, setup=self.setup), None
        return self_calibrated_informations(
            waypoints, *nominal, self.groups, self.kinematics, self.start_joints, setup=self.setup
        )


@dataclass(frozen=True)
class PlannedView:
    """One chosen view: its waypoint (T_base_flange, metres), the candidate's label and the
    predicted RSS 1-sigma after it, in words."""

    waypoint: Waypoint
    label: str
    sigma: str


@dataclass(frozen=True)
class ViewPlan:
    """A plan: the views in order (the last step's predicted RSS 1-sigmas in steps[-1]), how many
    candidates were drawn and how many held the whole board in view, the count asked, the target
    (mm, deg) and whether it was reached (None without one), the reference views' predicted
    1-sigmas (name, mm, deg) and path, the waypoint file written (None when not asked), and the
    self-calibration groups the mount's information was marginalised over (() when none)."""

    views: tuple[PlannedView, ...]
    steps: tuple[PlanStep, ...]
    criterion: str
    candidates: int
    usable: int
    count: int
    target: tuple[float, float] | None
    reached: bool | None
    reference: tuple[str, float, float]
    corner_sigma_px: float
    path: Path | None = None
    groups: tuple[str, ...] = ()

    @property
    def waypoints(self) -> list[Waypoint]:
        """The planned views as waypoints, in order."""
        return [v.waypoint for v in self.views]


def scenario_candidates(scenario: Scenario, count: int, rng: np.random.Generator) -> list[Waypoint]:
    """count random candidate views (view_planning.candidate_views, flange poses in the base frame)
    aimed at the scenario's nominal board pose through its nominal mount, around its trajectory's
    distance."""
    return candidate_views(
        scenario.board.transform(), scenario.mount.transform(), scenario.trajectory.distance_m, count, rng
    )


def simulated_cell(scenario_name: str | Path | None, corner_sigma_px: float) -> PlanningCell:
    """The scenario's nominal cell (None: the built-in one); views are checked in its simulated cell
    as `hec simulate` checks a waypoint (hec.sim.cell.SimCell.accepts)."""
    from hec.sim.cell import SimCell
    from hec.sim.noise import depth_noise_model, robot_pose_noise_model
    from hec.sim.scenario import load_scenario

    scenario = load_scenario(scenario_name)
    noise = SyntheticNoise(
        corner_sigma_px, depth_noise_model(scenario.noise), robot_pose_noise_model(scenario.noise)
    )
    distance = scenario.trajectory.distance_m
    if scenario.eye_to_hand:  # the roles swapped (setup_roles)
        T_base_board, T_flange_cam = scenario.board_mount.transform(), scenario.stand.transform()
        default = eye_to_hand_waypoints(T_flange_cam, T_base_board, distance)
    else:
        T_base_board, T_flange_cam = scenario.board.transform(), scenario.mount.transform()
        default = rotation_rich_waypoints(T_base_board, T_flange_cam, distance)
    cell = SimCell(scenario, np.random.default_rng(scenario.seed))
    board = scenario.board_definition()
    arm = scenario.errors.arm.enabled
    groups = planning_groups(board, arm) if scenario.errors.any_enabled() else ()
    return PlanningCell(
        board,
        scenario.camera.intrinsics(),
        T_flange_cam,
        T_base_board,
        noise,
        distance,
        cell.accepts,
        (f"the default {len(default)} views", default),
        scenario.setup,
        groups,
        ROBOTS[scenario.robot] if arm else None,
        cell.joints.copy(),
    )


def calibrated_cell(
    calibration: Path,
    method: str | None,
    dataset: Path | None,
    cell_file: Path | None,
    corner_sigma_px: float,
) -> PlanningCell:
    """A real cell from a calibration (its mount and board pose) and the dataset it came from (None:
    the one it names; the camera, the board, the depth noise, the distance of its views): views are
    checked with the cell file's nominal kinematics, joint limits and workspace box, no renderer."""
    from hec.estimator.io.calibration_file import CalibrationFileError, pose_field, read_calibration
    from hec.estimator.io.dataset import load_dataset
    from hec.estimator.observe.observations import dataset_depth_noise
    from hec.session.cell_config import load_cell_config

    cal = read_calibration(calibration, method)
    if cal.pose_frame != "flange":
        raise CalibrationFileError(
            f"{calibration}: calibrated with the robot's {cal.pose_frame} poses; plan from a "
            "calibration of flange poses (the waypoints are flange poses)"
        )
    board_key = BOARD_POSE_NAMES[cal.setup]  # eye-to-hand T_flange_board, in T_base_board's role
    if cal.data.get(board_key) is None:
        raise CalibrationFileError(
            f"{calibration}: the {cal.method} result has no board pose ({board_key}); plan from a "
            "method that estimates one, such as the default"
        )
    T_base_board = pose_field(cal.data, board_key, cal.path, CalibrationFileError)
    root = dataset if dataset is not None else cal.dataset
    if root is None:
        raise CalibrationFileError(
            f"{calibration}: names no dataset; give the one it came from with --dataset"
        )
    data = load_dataset(root)
    config = load_cell_config(cell_file)
    kinematics, limits = ROBOTS[config.robot.model], config.robot.limits()
    box = (config.robot.workspace_lower_m, config.robot.workspace_upper_m)
    joints = [IK_RESTARTS[2]]

    def accepts(waypoint: Waypoint) -> bool:
        q = reachable(waypoint, kinematics, joints[-1], box)
        if q is None or limits.problem_with_joints(q) is not None:
            return False
        joints.append(q)
        return True

    recorded = [
        Waypoint(i, f"frame {i}", T_base_flange=np.asarray(row["T_base_flange"]))
        for i, row in enumerate(data.rows)
    ]
    T_cam_flange = invert(cal.T_flange_cam)
    distances = [
        np.linalg.norm((T_cam_flange @ invert(model_pose(cal.setup, w.T_base_flange)) @ T_base_board)[:3, 3])
        for w in recorded
    ]
    noise = SyntheticNoise(corner_sigma_px, dataset_depth_noise(data), config.robot.pose_noise())
    return PlanningCell(
        data.board,
        data.intrinsics,
        cal.T_flange_cam,
        T_base_board,
        noise,
        float(np.median(distances)),
        accepts,
        (f"the {len(recorded)} views of {data.root}", recorded),
        cal.setup,
        kept_groups(cal.data),
        kinematics,
        IK_RESTARTS[2],
    )


def kept_groups(result: dict) -> tuple[str, ...]:
    """The NUISANCE_GROUPS a calibration result self-calibrated (its noise's self_calibration
    groups_kept, in NUISANCE_GROUPS order), () without self-calibration."""
    block = (result.get("noise") or {}).get("self_calibration") or {}
    kept = set(block.get("groups_kept") or ())
    return tuple(g for g in NUISANCE_GROUPS if g in kept)


def _count_and_target(
    real: bool,
    scenario: object,
    real_only: list[str],
    views: int | None,
    target: tuple[float | None, float | None],
    max_views: int,
    candidates: int,
    corner_sigma_px: float,
) -> tuple[int, tuple[float, float] | None]:
    """How many views to plan and the target (mm, deg) or None; PlanError for options that clash."""
    if real and scenario is not None:
        raise PlanError("give --scenario (a simulated cell) or --calibration (a real cell), not both")
    if not real and real_only:
        raise PlanError(f"{', '.join(real_only)}: only with --calibration")
    if (target[0] is None) != (target[1] is None):
        raise PlanError("--target-sigma-mm and --target-sigma-deg go together: give both or neither")
    if target[0] is not None and views is not None:
        raise PlanError("give --views or a target (--target-sigma-mm/--target-sigma-deg), not both")
    if target[0] is not None and (target[0] <= 0 or target[1] <= 0):
        raise PlanError(f"--target-sigma-mm {target[0]} / --target-sigma-deg {target[1]}: both must be > 0")
    count = views if views is not None else DEFAULT_VIEWS if target[0] is None else max_views
    if count < 3:
        raise PlanError(f"--views/--max-views {count}: at least 3 views determine a mount")
    if candidates < count or corner_sigma_px <= 0:
        raise PlanError(
            f"--candidates {candidates} must be at least the views ({count}) and --corner-sigma-px "
            f"{corner_sigma_px} > 0"
        )
    return count, None if target[0] is None else (target[0], target[1])


def plan_views_for(
    out: Path | None = None,
    scenario: str | Path | None = None,
    calibration: Path | None = None,
    method: str | None = None,
    dataset: Path | None = None,
    cell: Path | None = None,
    views: int | None = None,
    target_sigma_mm: float | None = None,
    target_sigma_deg: float | None = None,
    max_views: int = DEFAULT_MAX_VIEWS,
    criterion: str = CRITERIA[0],
    candidates: int = 1000,
    corner_sigma_px: float = 0.1,
    seed: int = 0,
) -> ViewPlan:
    """Plan views for a simulated cell (scenario) or a real one (calibration, cell, dataset); write
    them to out (a waypoint CSV; checked first, never over an input) when given. See the module
    doc; the options are `hec plan`'s."""
    real_only = [
        f"--{o}" for o, v in (("method", method), ("dataset", dataset), ("cell", cell)) if v is not None
    ]
    count, target = _count_and_target(
        calibration is not None,
        scenario,
        real_only,
        views,
        (target_sigma_mm, target_sigma_deg),
        max_views,
        candidates,
        corner_sigma_px,
    )
    if out is not None:
        check_output_file(out, "a waypoint CSV file name")
        scenario_file = None if scenario is None or not Path(scenario).exists() else Path(scenario)
        inputs = {"calibration file": calibration, "cell file": cell, "dataset": dataset}
        refuse_writing_over_inputs(out, inputs | {"scenario file": scenario_file})
    if calibration is not None:
        planning = calibrated_cell(calibration, method, dataset, cell, corner_sigma_px)
    else:
        planning = simulated_cell(scenario, corner_sigma_px)
    plan = _plan(planning, count, target, criterion, candidates, corner_sigma_px, seed)
    if out is None:
        return plan
    write_atomic(out, waypoint_csv(plan.waypoints))
    return replace(plan, path=out)


def _plan(
    cell: PlanningCell,
    count: int,
    target: tuple[float, float] | None,
    criterion: str,
    candidate_count: int,
    corner_sigma_px: float,
    seed: int,
) -> ViewPlan:
    rng = np.random.default_rng(seed)
    candidates = candidate_views(
        cell.T_base_board, cell.T_flange_cam, cell.distance_m, candidate_count, rng, setup=cell.setup
    )
    usable, informations, prior = cell.informations(candidates)
    steps = plan_views(
        informations, count, criterion, target, lambda k: cell.accepts(candidates[usable[k]]), prior=prior
    )
    if not steps:
        raise PlanError(
            f"none of the {len(usable)} candidates with the whole board in view passes the cell's checks "
            "(reach, joint limits, workspace, collisions)"
        )
    name, reference = cell.reference
    _, reference_informations, _ = cell.informations(reference)
    reference_total = reference_informations.sum(axis=0) + (0.0 if prior is None else prior)
    reference_mm, reference_deg = (
        predicted_sigmas(reference_total) if len(reference_informations) else (np.inf, np.inf)
    )
    planned = []
    for k, step in enumerate(steps):
        view = candidates[usable[step.candidate]]
        label = view.label.split(": ", 1)[1]
        sigma = (
            f"predicted 1-sigma {step.sigma_translation_mm:.3f} mm / {step.sigma_rotation_deg:.4f} deg"
            if np.isfinite(step.sigma_translation_mm) and np.isfinite(step.sigma_rotation_deg)
            else "mount not determined yet (it needs views turned about two axes)"
        )
        waypoint = Waypoint(k, f"planned view {k + 1}: {label}; {sigma}", T_base_flange=view.T_base_flange)
        planned.append(PlannedView(waypoint, label, sigma))
    last = steps[-1]
    reached = None
    if target is not None:
        reached = bool(last.sigma_translation_mm <= target[0] and last.sigma_rotation_deg <= target[1])
    return ViewPlan(
        tuple(planned),
        tuple(steps),
        criterion,
        candidate_count,
        len(usable),
        count,
        target,
        reached,
        (name, reference_mm, reference_deg),
        corner_sigma_px,
        groups=cell.groups,
    )
