"""`hec plan --out W.csv`: views chosen by the information about T_flange_cam they add
(estimator.solve.view_planning), for a simulated cell's scenario, as a waypoint file that
`hec record`, `hec run` and a scenario's `trajectory.kind = "file"` take.

The candidates are predicted with the scenario's nominal mount, board pose, camera, robot pose noise
and depth noise, and a corner noise the detector reports (--corner-sigma-px). Each view the
planner would choose is first checked in the simulated cell as `hec simulate` checks a waypoint
(sim.cell.SimCell.move_to: inverse kinematics within the joint limits from the previous view's
joints, no collision, every marker in view and not hidden); a refused one is passed over."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from estimator.geometry.waypoints import Waypoint, rotation_rich_waypoints, waypoint_csv
from estimator.io.files import write_atomic
from estimator.observe.synthetic import SyntheticNoise
from estimator.solve.view_planning import (
    CRITERIA,
    candidate_views,
    plan_views,
    predicted_sigmas,
    view_informations,
)
from experiments import arguments

DEFAULT_VIEWS = 12
DEFAULT_MAX_VIEWS = 40


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="choose views by the information they add; write a waypoint file")
    p.add_argument("--out", required=True, type=Path, help="waypoint CSV to write")
    arguments.add_scenario(p)
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


def run(args: argparse.Namespace) -> int:
    from sim.cell import SimCell
    from sim.noise import depth_noise_model, robot_pose_noise_model
    from sim.scenario import load_scenario

    count, target = _count_and_target(args)
    scenario = load_scenario(args.scenario)
    board, intrinsics = scenario.board_definition(), scenario.camera.intrinsics()
    T_base_board, T_flange_cam = scenario.board.transform(), scenario.mount.transform()
    noise = SyntheticNoise(
        args.corner_sigma_px, depth_noise_model(scenario.noise), robot_pose_noise_model(scenario.noise)
    )
    rng = np.random.default_rng(args.seed)
    distance = scenario.trajectory.distance_m
    candidates = candidate_views(T_base_board, T_flange_cam, distance, args.candidates, rng)
    usable, informations = view_informations(candidates, board, intrinsics, T_flange_cam, T_base_board, noise)
    cell = SimCell(scenario, np.random.default_rng(scenario.seed))
    steps = plan_views(
        informations, count, args.criterion, target, lambda k: cell.accepts(candidates[usable[k]])
    )
    default = rotation_rich_waypoints(T_base_board, T_flange_cam, distance)
    _, default_informations = view_informations(default, board, intrinsics, T_flange_cam, T_base_board, noise)
    default_mm, default_deg = predicted_sigmas(default_informations.sum(axis=0))
    waypoints = []
    print(f"{len(usable)} of {args.candidates} candidates hold the whole board in view; {args.criterion}:")
    for k, step in enumerate(steps):
        view = candidates[usable[step.candidate]]
        label = view.label.split(": ", 1)[1]
        sigma = f"predicted 1-sigma {step.sigma_translation_mm:.3f} mm / {step.sigma_rotation_deg:.4f} deg"
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
        f"the default {len(default)} views predict {default_mm:.3f} mm / {default_deg:.4f} deg (RSS 1-sigma, "
        f"corners at {args.corner_sigma_px:g} px)"
    )
    write_atomic(args.out, waypoint_csv(waypoints))
    print(f"wrote {args.out}: {len(waypoints)} waypoints")
    return 0
