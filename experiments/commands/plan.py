"""`hec plan --out W.csv`: views chosen by the information about T_flange_cam they add
(hec.estimator.solve.view_planning), as a waypoint file that `hec record`, `hec run` and a scenario's
`trajectory.kind = "file"` take.

The candidates are predicted with a nominal mount, board pose, camera, robot pose noise and depth
noise, and a corner noise the detector reports (--corner-sigma-px). They come from either
- a simulated cell's scenario (--scenario, default the built-in one): each view the planner would
  choose is first checked in the simulated cell as `hec simulate` checks a waypoint
  (hec.sim.cell.SimCell.accepts: inverse kinematics within the joint limits from the previous view's
  joints, no collision, every marker in view and not hidden), or
- a real cell's calibration (--calibration CAL.json, with --cell F and the dataset it came from):
  its mount and board pose, the dataset's camera, board, depth noise and viewing distance, the cell
  file's arm, pose noise, joint limits and workspace box (nominal kinematics; no renderer).
A refused view is passed over and the next best taken."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hec.commands import arguments
from hec.commands.verbs import HELP
from hec.estimator.common.files import check_output_file, refuse_writing_over_inputs, write_atomic
from hec.estimator.common.setups import BOARD_POSE_NAMES, EYE_IN_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import IK_RESTARTS, ROBOTS
from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import (
    Waypoint,
    eye_to_hand_waypoints,
    rotation_rich_waypoints,
    waypoint_csv,
)
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.methods import METHODS
from hec.estimator.solve.setup_roles import model_pose
from hec.estimator.solve.view_planning import (
    CRITERIA,
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


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help=HELP["plan"])
    p.add_argument("--out", required=True, type=Path, help="waypoint CSV to write")
    arguments.add_scenario(p)
    p.add_argument(
        "--calibration",
        type=Path,
        metavar="CAL.json",
        help="plan for the real cell of this calibration (hec calibrate --json) instead of a scenario",
    )
    p.add_argument(
        "--method", choices=list(METHODS), help="--calibration: the result to use (default: its first)"
    )
    p.add_argument(
        "--dataset", type=Path, help="--calibration: the dataset it came from (default: the one it names)"
    )
    p.add_argument(
        "--cell", type=Path, metavar="FILE", help="--calibration: cell TOML (see models/cells/ur5_d435.toml)"
    )
    p.add_argument("--views", type=int, help=f"how many views (default {DEFAULT_VIEWS} without a target)")
    p.add_argument(
        "--target-sigma-mm", type=float, help="stop when the predicted RSS 1-sigma is this (mm) ..."
    )
    p.add_argument("--target-sigma-deg", type=float, help="... and this (degrees)")
    p.add_argument(
        "--max-views",
        type=int,
        default=DEFAULT_MAX_VIEWS,
        help="most views with a target (default %(default)s)",
    )
    p.add_argument("--criterion", choices=CRITERIA, default=CRITERIA[0], help="default: %(default)s")
    p.add_argument(
        "--candidates", type=int, default=1000, help="random candidate views (default %(default)s)"
    )
    p.add_argument(
        "--corner-sigma-px",
        type=float,
        default=0.1,
        help="corner noise the prediction assumes, pixels per coordinate (default %(default)s)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the candidates (default %(default)s)")


def _count_and_target(args: argparse.Namespace) -> tuple[int, tuple[float, float] | None]:
    if args.calibration is not None and args.scenario is not None:
        raise ValueError("give --scenario (a simulated cell) or --calibration (a real cell), not both")
    real_only = [f"--{o}" for o in ("method", "dataset", "cell") if getattr(args, o) is not None]
    if args.calibration is None and real_only:
        raise ValueError(f"{', '.join(real_only)}: only with --calibration")
    target = (args.target_sigma_mm, args.target_sigma_deg)
    if (target[0] is None) != (target[1] is None):
        raise ValueError("--target-sigma-mm and --target-sigma-deg go together: give both or neither")
    if target[0] is not None and args.views is not None:
        raise ValueError("give --views or a target (--target-sigma-mm/--target-sigma-deg), not both")
    if target[0] is not None and (target[0] <= 0 or target[1] <= 0):
        raise ValueError(f"--target-sigma-mm {target[0]} / --target-sigma-deg {target[1]}: both must be > 0")
    count = args.views if args.views is not None else DEFAULT_VIEWS if target[0] is None else args.max_views
    if count < 3:
        raise ValueError(f"--views/--max-views {count}: at least 3 views determine a mount")
    if args.candidates < count or args.corner_sigma_px <= 0:
        raise ValueError(
            f"--candidates {args.candidates} must be at least the views ({count}) and --corner-sigma-px "
            f"{args.corner_sigma_px} > 0"
        )
    return count, None if target[0] is None else target


@dataclass(frozen=True)
class PlanningCell:
    """What planning needs of a cell: the board and camera, the nominal T_flange_cam and T_base_board
    ((4, 4), metres; eye-to-hand T_base_cam and T_flange_board, hec.estimator.solve.setup_roles), a
    frame's noise, the nominal distance to the board (m), accepts (True when the arm can take a view
    from the last view accepted), the views to compare with (name, waypoints) and the set-up."""

    board: Target
    intrinsics: CameraIntrinsics
    T_flange_cam: np.ndarray
    T_base_board: np.ndarray
    noise: SyntheticNoise
    distance_m: float
    accepts: Callable[[Waypoint], bool]
    reference: tuple[str, list[Waypoint]]
    setup: str = EYE_IN_HAND


def scenario_candidates(scenario: Scenario, count: int, rng: np.random.Generator) -> list[Waypoint]:
    """count random candidate views (view_planning.candidate_views, flange poses in the base frame)
    aimed at the scenario's nominal board pose through its nominal mount, around its trajectory's
    distance."""
    return candidate_views(
        scenario.board.transform(), scenario.mount.transform(), scenario.trajectory.distance_m, count, rng
    )


def simulated_cell(args: argparse.Namespace) -> PlanningCell:
    """The scenario's nominal cell; views are checked in its simulated cell as `hec simulate` checks
    a waypoint (hec.sim.cell.SimCell.accepts)."""
    from hec.sim.cell import SimCell
    from hec.sim.noise import depth_noise_model, robot_pose_noise_model
    from hec.sim.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    noise = SyntheticNoise(
        args.corner_sigma_px, depth_noise_model(scenario.noise), robot_pose_noise_model(scenario.noise)
    )
    distance = scenario.trajectory.distance_m
    if scenario.eye_to_hand:  # the roles swapped (setup_roles)
        T_base_board, T_flange_cam = scenario.board_mount.transform(), scenario.stand.transform()
        default = eye_to_hand_waypoints(T_flange_cam, T_base_board, distance)
    else:
        T_base_board, T_flange_cam = scenario.board.transform(), scenario.mount.transform()
        default = rotation_rich_waypoints(T_base_board, T_flange_cam, distance)
    cell = SimCell(scenario, np.random.default_rng(scenario.seed))
    return PlanningCell(
        scenario.board_definition(),
        scenario.camera.intrinsics(),
        T_flange_cam,
        T_base_board,
        noise,
        distance,
        cell.accepts,
        (f"the default {len(default)} views", default),
        scenario.setup,
    )


def calibrated_cell(args: argparse.Namespace) -> PlanningCell:
    """A real cell from a calibration (its mount and board pose) and the dataset it came from (the
    camera, the board, the depth noise, the distance of its views): views are checked with the
    cell file's nominal kinematics, joint limits and workspace box, no renderer."""
    from hec.estimator.io.calibration_file import CalibrationFileError, pose_field, read_calibration
    from hec.estimator.io.dataset import load_dataset
    from hec.estimator.observe.observations import dataset_depth_noise
    from hec.session.cell_config import load_cell_config

    cal = read_calibration(args.calibration, args.method)
    if cal.pose_frame != "flange":
        raise CalibrationFileError(
            f"{args.calibration}: calibrated with the robot's {cal.pose_frame} poses; plan from a "
            "calibration of flange poses (the waypoints are flange poses)"
        )
    board_key = BOARD_POSE_NAMES[cal.setup]  # eye-to-hand T_flange_board, in T_base_board's role
    if cal.data.get(board_key) is None:
        raise CalibrationFileError(
            f"{args.calibration}: the {cal.method} result has no board pose ({board_key}); plan from a "
            "method that estimates one, such as the default"
        )
    T_base_board = pose_field(cal.data, board_key, cal.path, CalibrationFileError)
    root = args.dataset if args.dataset is not None else cal.dataset
    if root is None:
        raise CalibrationFileError(
            f"{args.calibration}: names no dataset; give the one it came from with --dataset"
        )
    dataset = load_dataset(root)
    config = load_cell_config(args.cell)
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
        for i, row in enumerate(dataset.rows)
    ]
    T_cam_flange = invert(cal.T_flange_cam)
    distances = [
        np.linalg.norm((T_cam_flange @ invert(model_pose(cal.setup, w.T_base_flange)) @ T_base_board)[:3, 3])
        for w in recorded
    ]
    noise = SyntheticNoise(args.corner_sigma_px, dataset_depth_noise(dataset), config.robot.pose_noise())
    return PlanningCell(
        dataset.board,
        dataset.intrinsics,
        cal.T_flange_cam,
        T_base_board,
        noise,
        float(np.median(distances)),
        accepts,
        (f"the {len(recorded)} views of {dataset.root}", recorded),
        cal.setup,
    )


def run(args: argparse.Namespace) -> int:
    """`hec plan`: the views, printed and written to --out (checked first; never over an input)."""
    count, target = _count_and_target(args)
    check_output_file(args.out, "a waypoint CSV file name")
    inputs = {"calibration file": args.calibration, "cell file": args.cell, "dataset": args.dataset}
    scenario = None if args.scenario is None or not Path(args.scenario).exists() else Path(args.scenario)
    refuse_writing_over_inputs(args.out, inputs | {"scenario file": scenario})
    cell = calibrated_cell(args) if args.calibration is not None else simulated_cell(args)
    nominal = (cell.intrinsics, cell.T_flange_cam, cell.T_base_board, cell.noise)
    rng = np.random.default_rng(args.seed)
    candidates = candidate_views(
        cell.T_base_board, cell.T_flange_cam, cell.distance_m, args.candidates, rng, setup=cell.setup
    )
    usable, informations = view_informations(candidates, cell.board, *nominal, setup=cell.setup)
    steps = plan_views(
        informations, count, args.criterion, target, lambda k: cell.accepts(candidates[usable[k]])
    )
    if not steps:
        raise ValueError(
            f"none of the {len(usable)} candidates with the whole board in view passes the cell's checks "
            "(reach, joint limits, workspace, collisions)"
        )
    name, reference = cell.reference
    _, reference_informations = view_informations(reference, cell.board, *nominal, setup=cell.setup)
    reference_mm, reference_deg = predicted_sigmas(reference_informations.sum(axis=0))
    waypoints = []
    print(f"{len(usable)} of {args.candidates} candidates hold the whole board in view; {args.criterion}:")
    for k, step in enumerate(steps):
        view = candidates[usable[step.candidate]]
        label = view.label.split(": ", 1)[1]
        sigma = (
            f"predicted 1-sigma {step.sigma_translation_mm:.3f} mm / {step.sigma_rotation_deg:.4f} deg"
            if np.isfinite(step.sigma_translation_mm) and np.isfinite(step.sigma_rotation_deg)
            else "mount not determined yet (it needs views turned about two axes)"
        )
        waypoints.append(
            Waypoint(k, f"planned view {k + 1}: {label}; {sigma}", T_base_flange=view.T_base_flange)
        )
        print(f"  {k + 1:2d}  {label:40s} {sigma}")
    last = steps[-1]
    if target is not None:
        reached = last.sigma_translation_mm <= target[0] and last.sigma_rotation_deg <= target[1]
        print(
            f"target {target[0]:g} mm / {target[1]:g} deg "
            + (f"reached with {len(steps)} views" if reached else f"not reached in {len(steps)} views")
        )
    print(
        f"{name} predict {reference_mm:.3f} mm / {reference_deg:.4f} deg (RSS 1-sigma, "
        f"corners at {args.corner_sigma_px:g} px)"
    )
    if target is None and len(steps) < count:
        print(
            f"note: {len(steps)} views, not the {count} asked: only {len(usable)} of the {args.candidates} "
            f"candidates hold the whole board in view and {len(usable) - len(steps)} of those fail the "
            "cell's checks (reach, joint limits, workspace, collisions); give more --candidates for more"
        )
    write_atomic(args.out, waypoint_csv(waypoints))
    print(f"wrote {args.out}: {len(waypoints)} waypoints")
    return 0
