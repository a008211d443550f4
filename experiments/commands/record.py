"""`hec record` and `hec run`: a calibration session on the real cell (a UR arm and a RealSense)
or, with --sim, on the simulated one; `hec run` calibrates the recording afterwards.

Order on the real cell: read the waypoints, connect to the arm, plan (joint targets, limits,
workspace box), print the plan, stop there for --dry-run, open the camera, ask before the
first motion (unless --yes), then record frame by frame (hec.session.session).
With --target-sigma-mm/--target-sigma-deg the session is adaptive (hec.session.adaptive):
each next view is chosen from a pool (a --waypoints file, or in simulation candidate views around the
scenario's nominal values) and the session stops once the running estimate's RSS 1-sigma reaches the
target, or at --max-views.
Exit codes: 0 done (an adaptive session too when it did not reach its target: it says so, and the
dataset.json session block records it), 2 nothing moved (bad input, refused, unreachable), 3 the
session stopped part-way (the frames so far are kept; --resume continues a fixed plan).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hec.commands import arguments
from hec.commands.verbs import HELP
from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.common.setups import EYE_IN_HAND
from hec.estimator.geometry.kinematics import ROBOTS, forward, solve_ik_nearest, ur_ik_branches
from hec.estimator.geometry.waypoints import (
    PlannedMove,
    Waypoint,
    WaypointFileError,
    read_waypoint_file,
    waypoints_fingerprint,
)
from hec.estimator.io.lock import FolderLockedError
from hec.estimator.io.recorder import DatasetRecorder
from hec.estimator.observe.frames import DatasetError, GroundTruth
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS
from hec.estimator.solve.verify import spread_views
from hec.session import preview
from hec.session.adaptive import (
    DEFAULT_MAX_VIEWS,
    POOL_CANDIDATES,
    AdaptiveViews,
    SelfCalibratedPlanning,
    TargetError,
    scenario_planning,
    sigma_target,
)
from hec.session.cell_config import CellConfig, CellConfigError, load_cell_config
from hec.session.plan_text import motion_time_s, print_plan
from hec.session.session import LiveEstimate, SessionCell, run_session

if TYPE_CHECKING:
    from hec.hardware.cell import HardwareCell
    from hec.sim.session_cell import SimulatedCell

EXIT_STOPPED = 3
CALIBRATION_FILE = "calibration.json"
# dataset.json fields a resumed session must share with the frames before it: a simulation's seed and
# scenario (its trajectory, mount, noise), the frame the robot poses are in, and the waypoints (a
# --waypoints file may stand in for the scenario's trajectory, and a file may have been edited).
RESUME_FIXED = ("simulation", "pose_frame", "waypoints")
# Tags the adaptive session's candidate pool stream, apart from default_rng(seed) (the true cell) and
# hec.sim.noise.waypoint_rng's stream (the frames' noise).
_POOL_STREAM = 2


class RecordError(ValueError):
    """The session cannot start; nothing has moved."""


def add_parsers(sub: argparse._SubParsersAction) -> None:
    for name in ("record", "run"):
        p = sub.add_parser(name, help=HELP[name])
        where = p.add_mutually_exclusive_group()
        where.add_argument("--robot", metavar="HOST", help="the UR controller's address (or the cell file's)")
        where.add_argument("--sim", action="store_true", help="run the session on the simulated cell")
        p.add_argument(
            "--camera",
            nargs="?",
            const="",
            metavar="SERIAL",
            help="RealSense serial number (default: the cell file's, else the first camera found)",
        )
        p.add_argument("--cell", type=Path, metavar="FILE", help="cell TOML (see models/cells/ur5_d435.toml)")
        p.add_argument(
            "--waypoints",
            type=Path,
            metavar="FILE",
            help="waypoint CSV (required on the real cell; --sim: default the scenario's trajectory)",
        )
        p.add_argument("--scenario", type=Path, help="--sim: scenario TOML (default: the built-in one)")
        p.add_argument(
            "--seed",
            type=arguments.seed,
            help="--sim: the seed of the cell's model errors and, unless --noise-seed, of the noise "
            "(default: the scenario's)",
        )
        p.add_argument(
            "--noise-seed",
            type=arguments.seed,
            metavar="N",
            help="--sim: each frame's noise from N instead (the same cell; default: --seed)",
        )
        p.add_argument("--out", required=True, type=Path, help="dataset folder to create (or --resume)")
        p.add_argument("--dry-run", action="store_true", help="print the plan and stop; nothing moves")
        preview.add_argument(p)
        p.add_argument("--yes", action="store_true", help="do not ask before the first motion")
        p.add_argument("--resume", action="store_true", help="continue an interrupted session in --out")
        p.add_argument("--no-live", action="store_true", help="no detection and running estimate per frame")
        p.add_argument(
            "--target-sigma-mm",
            type=float,
            metavar="MM",
            help="adaptive session: choose each next view by the information it adds and stop when the "
            "running estimate's RSS 1-sigma is this (mm) ...",
        )
        p.add_argument("--target-sigma-deg", type=float, metavar="DEG", help="... and this (degrees)")
        p.add_argument(
            "--max-views",
            type=int,
            metavar="N",
            help=f"adaptive session: stop after N views (default {DEFAULT_MAX_VIEWS})",
        )
        if name == "run":
            p.add_argument("--method", default=DEFAULT_METHOD, choices=list(METHODS))
            p.add_argument(
                "--verify",
                type=Path,
                metavar="CALIBRATION",
                help="record a short verification session (5 of the waypoints) and test this calibration "
                "(hec verify) instead of calibrating",
            )


# ---------------------------------------------------------------- opening a cell


def _check_out(args: argparse.Namespace) -> None:
    if args.resume and not (args.out / "dataset.json").is_file():
        raise RecordError(f"{args.out}: no session to resume (no dataset.json)")
    preview.check_preview_path(args)
    if not args.resume and not args.dry_run and args.out.exists():
        raise RecordError(f"{args.out} already exists; add --resume to continue it, or choose another --out")


def _open_sim(args: argparse.Namespace) -> tuple[SimulatedCell, list[Waypoint], dict, GroundTruth, Callable]:
    from hec.sim.cell import SimCell
    from hec.sim.scenario import load_scenario
    from hec.sim.session_cell import SimulatedCell
    from hec.sim.simulate import scenario_waypoints, simulation_metadata

    scenario = load_scenario(args.scenario)
    seed = scenario.seed if args.seed is None else args.seed
    noise_seed = seed if args.noise_seed is None else args.noise_seed
    waypoints = read_waypoint_file(args.waypoints) if args.waypoints else scenario_waypoints(scenario)
    cell = SimCell(scenario, np.random.default_rng(seed))
    extra = simulation_metadata(scenario, seed, noise_seed)
    if args.resume:
        extra = _as_older_recording(args.out / "dataset.json", extra)
    return (
        SimulatedCell(cell, noise_seed),
        waypoints,
        extra,
        cell.ground_truth(),
        lambda q: forward(cell.cell.kinematics, q),
    )


def _as_older_recording(meta_path: Path, extra: dict) -> dict:
    """extra without simulation.noise_seed when the recording being resumed has none (an older hec,
    whose frames drew their noise from the seed) and it is the seed: that session goes on as it
    was. Another noise seed stays, and the resume is refused for it."""
    recorded = read_json_object(meta_path, DatasetError, "missing: nothing to resume here").get("simulation")
    simulation = dict(extra["simulation"])
    if (
        isinstance(recorded, dict)
        and "noise_seed" not in recorded
        and simulation["noise_seed"] == simulation["seed"]
    ):
        del simulation["noise_seed"]
    return extra | {"simulation": simulation}


def _inverse(model: str) -> Callable[[np.ndarray, np.ndarray], np.ndarray | None]:
    kinematics = ROBOTS[model]
    return lambda T_base_flange, q_seed: solve_ik_nearest(kinematics, T_base_flange, q_seed)


def _branches(model: str) -> Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    kinematics = ROBOTS[model]
    return lambda T_base_flange, q_near, lower, upper: ur_ik_branches(
        kinematics, T_base_flange, q_near, lower, upper
    )


def _confirm(text: str, read_line: Callable[[str], str] | None) -> bool:
    if read_line is None:
        if not sys.stdin.isatty():
            raise RecordError("no terminal to confirm the motion on; pass --yes to start without asking")
        read_line = input
    try:
        return read_line(text).strip().lower() in ("y", "yes")
    except EOFError:
        return False


# ---------------------------------------------------------------- the command


def run(
    args: argparse.Namespace,
    camera_context: object | None = None,
    read_line: Callable[[str], str] | None = None,
) -> int:
    """`hec record` / `hec run`. camera_context: the librealsense context to find the camera in
    (None: a fresh one); read_line: asks for confirmation (None: the terminal)."""
    from hec.hardware.camera_settings import CameraError
    from hec.hardware.ur_robot import RobotError

    user_errors: tuple[type[Exception], ...] = (
        RecordError,
        TargetError,
        CellConfigError,
        WaypointFileError,
        RobotError,
        CameraError,
        FileExistsError,
        FolderLockedError,
        DatasetError,
    )
    if args.sim:  # only then: importing sim picks an OpenGL backend, which a robot PC may lack
        from hec.sim.scenario import ScenarioError

        user_errors += (ScenarioError,)
    try:
        sigma_target(args)
        _check_out(args)
        if args.sim:
            if args.cell is not None:
                raise RecordError(
                    f"--cell {args.cell}: describes the real cell; with --sim the scenario (--scenario) is "
                    "the cell: leave --cell out, or drop --sim to record on the real cell"
                )
            return _record_sim(args)
        return _record_hardware(args, camera_context, read_line)
    except user_errors as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2


def _record_sim(args: argparse.Namespace) -> int:
    cell, waypoints, extra, truth, forward_fk = _open_sim(args)
    try:
        if sigma_target(args) is not None and args.waypoints is None:
            return _record_sim_adaptive(args, cell, extra, truth)
        moves = cell.plan(waypoints)
        print_plan(moves, forward_fk)
        if args.dry_run:
            print("dry run: nothing moved")
            return 0
        return _session(args, cell, moves, extra, truth, _nominal(cell), forward_fk, planning=_planning(cell))
    finally:
        cell.close()


def _nominal(cell: SimulatedCell) -> tuple[np.ndarray, np.ndarray]:
    """A simulated cell's scenario's nominal T_flange_cam and T_base_board (4, 4)."""
    scenario = cell.cell.scenario
    return scenario.mount.transform(), scenario.board.transform()


def _planning(cell: SimulatedCell) -> SelfCalibratedPlanning | None:
    """What an adaptive session marginalises on a simulated cell (scenario_planning)."""
    return scenario_planning(cell.cell.scenario)


def _record_sim_adaptive(
    args: argparse.Namespace, cell: SimulatedCell, extra: dict, truth: GroundTruth
) -> int:
    """The adaptive session on the simulated cell, its pool POOL_CANDIDATES candidate views drawn
    around the scenario's nominal values (from the session's seed)."""
    from hec.session.view_plan import scenario_candidates

    seed = extra["simulation"]["seed"]
    pool = scenario_candidates(
        cell.cell.scenario, POOL_CANDIDATES, np.random.default_rng([seed, _POOL_STREAM])
    )
    print(
        f"adaptive session: a pool of {len(pool)} candidate views around the scenario's nominal mount "
        "and board pose; each chosen view is planned (IK, collisions, markers in view) when chosen"
    )
    if args.dry_run:
        print("dry run: nothing moved")
        return 0
    return _session(args, cell, [], extra, truth, _nominal(cell), pool=pool, planning=_planning(cell))


def _record_hardware(
    args: argparse.Namespace, camera_context: object | None, read_line: Callable[[str], str] | None
) -> int:
    from hec.estimator.io.board_file import find_board
    from hec.hardware.cell import HardwareCell, plan_moves
    from hec.hardware.realsense import RealSenseCamera

    config = load_cell_config(args.cell)
    if args.waypoints is None:
        raise RecordError("give the waypoints with --waypoints FILE (teach them with `hec teach`)")
    waypoints = read_waypoint_file(args.waypoints)
    kinematics = ROBOTS[config.robot.model]
    inverse = _inverse(config.robot.model)
    with config.open_robot(config.robot_host(args.robot), read_only=args.dry_run) as robot:
        cable_limit = float(np.radians(config.robot.wrist_cable_limit_deg))
        cell_model = config.cell_model.cell_model(config.robot.model)

        def plan(waypoints: list[Waypoint]) -> list[PlannedMove]:
            branches = _branches(config.robot.model)
            return plan_moves(robot, inverse, waypoints, cable_limit, branches, cell_model.problem)

        moves = plan(waypoints)
        print_plan(moves, lambda q: forward(kinematics, q))
        if args.preview is not None:
            print(f"preview: {preview.write_path_preview(args.preview, moves, robot.joints())}")
        print(
            f"joint speed {config.robot.joint_speed_deg_s:g} deg/s, acceleration "
            f"{config.robot.joint_acceleration_deg_s2:g} deg/s^2, dwell {config.robot.dwell_s:g} s: "
            f"about {motion_time_s(moves, robot.joints(), config):.0f} s"
        )
        if args.dry_run:
            print("dry run: nothing moved")
            return 0
        target = sigma_target(args)
        if target is not None and config.robot.pose_frame != "flange":
            raise RecordError(
                "an adaptive session (--target-sigma-mm/--target-sigma-deg) needs robot.pose_frame = "
                f"'flange' in the cell file, not {config.robot.pose_frame!r}"
            )
        with RealSenseCamera(config.camera_settings(args.camera), camera_context) as camera:
            usable = sum(m.joints is not None for m in moves)
            if target is not None:
                usable = min(usable, target.max_views)
            question = (
                f"The arm at {robot.host} will move through {'up to ' if target else ''}{usable} waypoints. "
                "Keep the cell clear and a hand on the emergency stop. Start? [y/N] "
            )
            if not args.yes and not _confirm(question, read_line):
                print("not started: nothing moved")
                return 2
            cell = HardwareCell(robot, camera, find_board(config.board), plan, config.robot.pose_frame)
            extra = _hardware_metadata(args, config, cell)
            return _session(args, cell, moves, extra, None, None, lambda q: forward(kinematics, q))


def _hardware_metadata(args: argparse.Namespace, config: CellConfig, cell: HardwareCell) -> dict:
    extra = {
        "depth_noise": config.camera.depth_noise(cell.depth_scale_m).to_dict(),
        "robot_pose_noise": config.robot.pose_noise().to_dict(),
        "robot_model": config.robot.model,
        "pose_frame": cell.pose_frame,
        "cell": cell.describe(),
        "cell_config": config.to_dict(),
        "waypoint_file": str(args.waypoints),
    }
    if config.setup != EYE_IN_HAND:
        extra["setup"] = config.setup
    if cell.pose_frame == "tcp":
        extra["flange_pose"] = (
            "reported T_base_tcp: the controller's TCP (offset in cell.robot.T_flange_tcp) in the base "
            "frame; metres, quaternion w x y z"
        )
    return extra


def _pool(moves: list[PlannedMove], forward_fk: Callable[[np.ndarray], np.ndarray]) -> list[Waypoint]:
    """An adaptive session's pool from a waypoint file's plan: the usable waypoints in the file's
    order (not the plan's visit order), each with its flange pose (joint waypoints: the nominal
    kinematics of their joints)."""
    return [
        replace(m.waypoint, T_base_flange=forward_fk(m.joints))
        if m.waypoint.T_base_flange is None
        else m.waypoint
        for m in sorted(moves, key=lambda m: m.waypoint.index)
        if m.joints is not None
    ]


def _session(
    args: argparse.Namespace,
    cell: SessionCell,
    moves: list[PlannedMove],
    extra: dict,
    truth: GroundTruth | None,
    nominal: tuple[np.ndarray, np.ndarray] | None = None,
    forward_fk: Callable[[np.ndarray], np.ndarray] | None = None,
    pool: list[Waypoint] | None = None,
    planning: SelfCalibratedPlanning | None = None,
) -> int:
    """Record the planned moves into --out (or resume it), then report; `hec run` calibrates.
    With a target the session is adaptive: its pool is pool, else the usable planned moves'
    waypoints (flange poses from forward_fk for joint waypoints); nominal: the (T_flange_cam,
    T_base_board) (4, 4) its first views are chosen at (None: spread over the pool); planning: the
    self-calibration groups its choice marginalises (None: the mount and board pose alone)."""
    target = sigma_target(args)
    if target is not None and extra.get("setup", EYE_IN_HAND) != EYE_IN_HAND:
        raise RecordError(
            "an adaptive session (--target-sigma-mm/--target-sigma-deg) chooses its views eye-in-hand only; "
            "for a fixed camera give --waypoints (hec plan --scenario or --calibration writes them)"
        )
    if target is not None and pool is None:
        pool = _pool(moves, forward_fk)
    if not (pool if target is not None else any(m.joints is not None for m in moves)):
        raise RecordError("no waypoint can be used; see the reasons above")
    if getattr(args, "verify", None) is not None:
        moves = spread_views([m for m in moves if m.joints is not None])
        chosen = ", ".join(str(m.waypoint.index) for m in moves)
        print(f"verification session: {len(moves)} of the waypoints ({chosen})")
    with DatasetRecorder(
        args.out,
        cell.intrinsics,
        cell.board,
        cell.depth_scale_m,
        cell.source,
        extra=extra
        | {
            "waypoints": waypoints_fingerprint(
                pool or sorted((m.waypoint for m in moves), key=lambda w: w.index)
            )
        },
        ground_truth=truth,
        resume=args.resume,
        fixed=RESUME_FIXED,
    ) as recorder:  # unlocked however the session ends
        for note in recorder.notes:
            print(f"note: {note}", file=sys.stderr)
        target_sigma = None if target is None else (target.sigma_mm, target.sigma_deg)
        live = None if args.no_live else LiveEstimate(recorder.root, target_sigma=target_sigma)
        adaptive = (
            None
            if target is None
            else AdaptiveViews(cell, pool, live, target, nominal, self_calibration=planning)
        )
        outcome = run_session(cell, moves if adaptive is None else adaptive, recorder, live)
    print(f"dataset: {outcome.root} ({outcome.total} frames, {outcome.recorded} recorded now)")
    if outcome.stopped is not None:
        print(f"hec: session stopped: {outcome.stopped}", file=sys.stderr)
        then = (
            "fix the cause, then run the same command with --resume"
            if adaptive is None
            else f"an adaptive session cannot be resumed: `hec calibrate {outcome.root}`, or start a new one"
        )
        print(f"the {outcome.total} frames recorded are kept in {outcome.root}; {then}", file=sys.stderr)
        return EXIT_STOPPED
    if adaptive is not None:
        print(adaptive.summary())
    if args.command == "run" and args.verify is not None:
        return _verify(args)
    if args.command == "run":
        return _calibrate(args)
    print(f"next: hec calibrate {outcome.root}")
    return 0


def _verify(args: argparse.Namespace) -> int:
    from hec.commands import verify

    print()
    return verify.run(
        argparse.Namespace(calibration=args.verify, dataset=args.out, method=None, json=None, quiet=True)
    )


def _calibrate(args: argparse.Namespace) -> int:
    from hec.commands.calibrate import CalibrateSettings, calibrate_dataset
    from hec.estimator.solve.calibration import Calibration

    print()
    results = calibrate_dataset(
        args.out,
        CalibrateSettings(method=args.method),
        args.out / CALIBRATION_FILE,
        quiet=True,
        report_dir=args.out,
    )
    return 0 if isinstance(results[0], Calibration) else 2
