"""`hec plan --out W.csv`: views chosen by the information about T_flange_cam they add, as a
waypoint file that `hec record`, `hec run` and a scenario's `trajectory.kind = "file"` take. The work
is hec.plan (hec.session.view_plan, whose doc says how candidates are drawn and checked, in a
simulated cell or a real one); this parses the options and prints the plan."""

from __future__ import annotations

import argparse
from pathlib import Path

from hec.commands import arguments
from hec.commands.verbs import HELP
from hec.estimator.solve.methods import METHODS
from hec.estimator.solve.view_planning import CRITERIA
from hec.session.view_plan import DEFAULT_MAX_VIEWS, DEFAULT_VIEWS, plan_views_for


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


def run(args: argparse.Namespace) -> int:
    """`hec plan`: the views, printed and written to --out (checked first; never over an input)."""
    plan = plan_views_for(
        args.out,
        args.scenario,
        args.calibration,
        args.method,
        args.dataset,
        args.cell,
        args.views,
        args.target_sigma_mm,
        args.target_sigma_deg,
        args.max_views,
        args.criterion,
        args.candidates,
        args.corner_sigma_px,
        args.seed,
    )
    if plan.groups:
        print(
            "the cell self-calibrates: views chosen by the mount's information with these estimated "
            f"too: {', '.join(g.replace('_', ' ') for g in plan.groups)}"
        )
    print(f"{plan.usable} of {plan.candidates} candidates hold the whole board in view; {plan.criterion}:")
    for k, view in enumerate(plan.views):
        print(f"  {k + 1:2d}  {view.label:40s} {view.sigma}")
    steps = len(plan.steps)
    if plan.target is not None:
        print(
            f"target {plan.target[0]:g} mm / {plan.target[1]:g} deg "
            + (f"reached with {steps} views" if plan.reached else f"not reached in {steps} views")
        )
    name, reference_mm, reference_deg = plan.reference
    print(
        f"{name} predict {reference_mm:.3f} mm / {reference_deg:.4f} deg (RSS 1-sigma, "
        f"corners at {plan.corner_sigma_px:g} px)"
    )
    if plan.target is None and steps < plan.count:
        print(
            f"note: {steps} views, not the {plan.count} asked: only {plan.usable} of the {plan.candidates} "
            f"candidates hold the whole board in view and {plan.usable - steps} of those fail the "
            "cell's checks (reach, joint limits, workspace, collisions); give more --candidates for more"
        )
    print(f"wrote {plan.path}: {len(plan.views)} waypoints")
    return 0
