"""View-planning benchmark: how many views each way of choosing them needs to reach a
Cramer-Rao bound, and whether calibrations on planned views are as accurate as predicted.

Placement p draws everything from numpy.random.default_rng([seed, p]): a random mount
(hec.support.synthetic_scenes.random_mount, up to 50 mm and about 20 degrees from the default) and
the default board (face up on its table) moved up to 0.1 m along each base axis and turned up to
30 degrees about its normal. The planner knows the placement (as `hec plan` knows a scenario's
nominal mount and board pose) and the scenario's noise, with corners at --corner-sigma-px (the
detector reports about 0.013-0.02 px on the default renders). Every strategy's views are checked in
the placement's simulated cell as `hec simulate` checks them (hec.sim.cell.SimCell.accepts: inverse
kinematics within the joint limits from the previous view, no collision, every marker in view and
not hidden), in their order, and kept when the whole board is in view with
hec.estimator.solve.view_planning.VIEW_MARGIN_PX:

    d-optimal, worst-direction  hec.estimator.solve.view_planning.plan_views over --candidates
                                random candidates (candidate_views), up to MAX_VIEWS views
    default                     the default 17-view list (rotation_rich_waypoints) in its order
    random                      the same candidates in a random order, up to MAX_VIEWS
    easy_handeye                easy_handeye's pattern: head-on at the nominal distance, +-25 deg
                                about the board's x and y axes and about the optical axis, then
                                +-0.1 m along the board's x and y and the viewing direction (13)

Per strategy: the views needed to reach TARGET (RSS 1-sigma, mm and deg; inf when its views never
do), the fraction of placements within WITHIN views, and, for the planners, the views they need to
reach the default list's final bound (goal: at most half the default's views).
Achieved accuracy: per placement, noisy synthetic observations (the planner's noise) of the first
k views of the d-optimal plan and of the default list, k in ACHIEVED_COUNTS, calibrated with the
default method (hec.estimator.solve.methods.DEFAULT_METHOD): the RMS of the error over the
placements beside the RMS of the predicted RSS 1-sigma, and the mean NEES of the WITHIN-view
plan against chi-square's 95 % band. --render-placements N renders the first N placements' plan
(WITHIN views) and default list with MuJoCo at the default and the realistic scenario
(hec.sweep.trials.render_views), detects and calibrates them the same way.
Speed: planning with --candidates candidates (view_informations and plan_views with the IK checks)
timed beside one default-method calibration of the default 17 views, in the main process.

    .venv/bin/python -m hec.bench.view_planning [--placements 50] [--seed 0]
        [--candidates 1000] [--corner-sigma-px 0.02] [--render-placements 0] [--workers 2]
        [--json OUT] [--plot OUT.png] [--page PATH.md]

--page also writes the summary as a documentation page (with the plot, PAGE's stem .png, beside it).
Exit status 1 when an acceptance line fails.
"""

from __future__ import annotations

import os

# One BLAS thread per process: the placements run in parallel processes.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from hec.bench.view_planning_report import (
    ACHIEVED_COUNTS,
    MAX_VIEWS,
    PLANNERS,
    RENDER_SCENARIOS,
    TARGET,
    WITHIN,
    acceptance,
    plot,
    print_summary,
    summarise,
)
from hec.calibration.report import check_json_path, write_json  # noqa: E402
from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.camera import CameraIntrinsics  # noqa: E402
from hec.estimator.geometry.lie import pose_nees  # noqa: E402
from hec.estimator.geometry.transforms import (
    invert,
    make_transform,
    pose_error,
    rotation_about,
    rpy_from_transform,
)
from hec.estimator.geometry.waypoints import Waypoint, look_at_board, rotation_rich_waypoints  # noqa: E402
from hec.estimator.observe.observations import FrameObservations  # noqa: E402
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations  # noqa: E402
from hec.estimator.solve.calibration import MethodOptions  # noqa: E402
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import run_method  # noqa: E402
from hec.estimator.solve.problem import (
    CalibrationInputError,
    ReportedArm,
    build_problem,
    dataset_arm,
    dataset_robot_noise,
)
from hec.estimator.solve.view_planning import candidate_views, plan_views, predicted_sigmas, view_informations
from hec.estimator.targets.target import Target  # noqa: E402
from hec.sim.cell import SimCell  # noqa: E402
from hec.sim.noise import depth_noise_model, robot_pose_noise_model  # noqa: E402
from hec.sim.scenario import Scenario, load_scenario, scenario_from_dict  # noqa: E402
from hec.support.parallel import results_as_done  # noqa: E402
from hec.support.results_page import write_results_page  # noqa: E402
from hec.support.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount  # noqa: E402
from hec.sweep.rows import SweepError  # noqa: E402

EASY_HANDEYE_DEG, EASY_HANDEYE_M = 25.0, 0.1
DISTANCE_M = SCENARIO.trajectory.distance_m


def placement(seed: int, index: int) -> tuple[np.ndarray, np.ndarray, np.random.Generator]:
    """Placement index: (T_flange_cam, T_base_board, the generator the rest of it draws from)."""
    rng = np.random.default_rng([seed, index])
    T_flange_cam = random_mount(rng)
    shift = rng.uniform(-0.1, 0.1, 3)  # base frame
    turn = rotation_about("z", np.radians(rng.uniform(-30.0, 30.0)))  # about the board's normal
    R = T_BASE_BOARD[:3, :3] @ turn
    return T_flange_cam, make_transform(R, T_BASE_BOARD[:3, 3] + shift), rng


def placement_scenario(name: str, T_flange_cam: np.ndarray, T_base_board: np.ndarray) -> Scenario:
    """The named scenario ("default" or a preset) with the placement's mount and board pose."""
    base = load_scenario(None if name == "default" else name)
    data = base.to_dict()
    data["mount"] = {
        "translation_m": [float(v) for v in T_flange_cam[:3, 3]],
        "rotation_rpy_deg": [float(v) for v in np.degrees(rpy_from_transform(T_flange_cam))],
    }
    data["board"] = {
        **data["board"],
        "translation_m": [float(v) for v in T_base_board[:3, 3]],
        "rotation_rpy_deg": [float(v) for v in np.degrees(rpy_from_transform(T_base_board))],
    }
    return scenario_from_dict(data, f"{name} scenario, placement", Path(base.base_dir))


def easy_handeye_waypoints(T_base_board: np.ndarray, T_flange_cam: np.ndarray) -> list[Waypoint]:
    """easy_handeye's pattern about the head-on view at the nominal distance: +-25 degrees about
    the board's x and y axes (aimed at its centre) and about the optical axis, then the head-on
    camera moved +-0.1 m along the board's x and y axes and along its optical axis."""
    a, d = EASY_HANDEYE_DEG, EASY_HANDEYE_M
    views = [(0.0, 0.0, 0.0), (a, 0.0, 0.0), (-a, 0.0, 0.0), (a, 90.0, 0.0), (-a, 90.0, 0.0)]
    views += [(0.0, 0.0, a), (0.0, 0.0, -a)]
    T_board_cams = [look_at_board(tilt, az, roll, DISTANCE_M) for tilt, az, roll in views]
    head_on = look_at_board(0.0, 0.0, 0.0, DISTANCE_M)
    for shift in np.vstack([np.eye(3) * d, -np.eye(3) * d]):
        moved = head_on.copy()
        moved[:3, 3] += shift if shift[2] == 0 else head_on[:3, 2] * shift[2]
        T_board_cams.append(moved)
    T_cam_flange = invert(T_flange_cam)
    return [
        Waypoint(i, f"easy_handeye view {i}", T_base_flange=T_base_board @ T @ T_cam_flange)
        for i, T in enumerate(T_board_cams)
    ]


def _taken_in_order(cell: SimCell, waypoints: list[Waypoint]) -> list[Waypoint]:
    """The waypoints the cell takes, visited in their order."""
    return [w for w in waypoints if cell.accepts(w)]


def _curve(informations: np.ndarray) -> list[tuple[float, float]]:
    """Predicted RSS 1-sigmas (mm, deg) after each of the views, in order."""
    return [predicted_sigmas(total) for total in np.cumsum(informations, axis=0)]


def _views_to(curve: list[tuple[float, float]], bound: tuple[float, float]) -> float:
    """The fewest views whose prediction is within bound (mm, deg), inf when none is."""
    for k, (mm, deg) in enumerate(curve, start=1):
        if mm <= bound[0] * (1 + 1e-9) and deg <= bound[1] * (1 + 1e-9):
            return float(k)
    return math.inf


def plan(
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray,
    noise: SyntheticNoise,
    candidates: int,
    rng: np.random.Generator,
) -> dict[str, tuple[list[np.ndarray], np.ndarray]]:
    """Per strategy: its views' T_base_flange (4, 4) in order and their (k, 12, 12) informations."""
    scenario = placement_scenario("default", T_flange_cam, T_base_board)
    pool = candidate_views(T_base_board, T_flange_cam, DISTANCE_M, candidates, rng)
    usable, informations = view_informations(pool, BOARD, INTRINSICS, T_flange_cam, T_base_board, noise)
    views = [pool[i] for i in usable]
    out: dict[str, tuple[list[np.ndarray], np.ndarray]] = {}
    for criterion in PLANNERS:
        cell = SimCell(scenario, np.random.default_rng(0))
        steps = plan_views(informations, MAX_VIEWS, criterion, None, lambda k, c=cell: c.accepts(views[k]))
        chosen = [s.candidate for s in steps]  # plan_views' worst-direction units: TARGET
        out[criterion] = ([views[k].T_base_flange for k in chosen], informations[chosen])
    order = rng.permutation(len(views))
    lists = {
        "default": rotation_rich_waypoints(T_base_board, T_flange_cam, DISTANCE_M),
        "random": [views[k] for k in order[: 2 * MAX_VIEWS]],
        "easy_handeye": easy_handeye_waypoints(T_base_board, T_flange_cam),
    }
    for name, waypoints in lists.items():
        taken = _taken_in_order(SimCell(scenario, np.random.default_rng(0)), waypoints)[:MAX_VIEWS]
        seen, infos = view_informations(taken, BOARD, INTRINSICS, T_flange_cam, T_base_board, noise)
        out[name] = ([taken[i].T_base_flange for i in seen], infos)
    return out


def _calibrate(
    observations: list[FrameObservations],
    board: Target,
    intrinsics: CameraIntrinsics,
    robot: RobotPoseNoise,
    arm: ReportedArm | None,
    T_true: np.ndarray,
) -> dict:
    """The default method's error (mm, deg), NEES and RSS 1-sigmas (mm, deg) against T_true."""
    problem = build_problem(observations, board, intrinsics, robot, arm=arm)
    result = run_method(DEFAULT_METHOD, problem, MethodOptions(), observations)
    error_m, error_rad = pose_error(result.T_flange_cam, T_true)
    out = {"error_mm": 1e3 * error_m, "error_deg": math.degrees(error_rad), "nees": None}
    if result.covariance is not None:
        out["nees"] = pose_nees(result.T_flange_cam, T_true, result.covariance)
        out["sigma_mm"] = float(np.linalg.norm(result.sigma_translation_mm))
        out["sigma_deg"] = float(np.linalg.norm(result.sigma_rotation_deg))
    return out


def _noise(corner_sigma_px: float) -> SyntheticNoise:
    return SyntheticNoise(
        corner_sigma_px, depth_noise_model(SCENARIO.noise), robot_pose_noise_model(SCENARIO.noise)
    )


def run_placement(seed: int, index: int, candidates: int, corner_sigma_px: float, render: bool) -> dict:
    """One placement: per strategy its predicted curve and views to the target; the achieved
    accuracy of the d-optimal plan and the default list; with render, the rendered calibrations."""
    X, T_base_board, rng = placement(seed, index)
    noise = _noise(corner_sigma_px)
    views = plan(X, T_base_board, noise, candidates, rng)
    out: dict = {"placement": index, "strategies": {}, "achieved": {}, "rendered": {}}
    for name, (_, informations) in views.items():
        curve = _curve(informations)
        out["strategies"][name] = {"curve": curve, "views": len(curve), "to_target": _views_to(curve, TARGET)}
    default_final = out["strategies"]["default"]["curve"][-1] if views["default"][0] else (math.inf,) * 2
    out["default_final"] = default_final
    for name in PLANNERS:
        out["strategies"][name]["to_default_final"] = _views_to(
            out["strategies"][name]["curve"], default_final
        )
    for name in ("d-optimal", "default"):
        flange, _ = views[name]
        for k in ACHIEVED_COUNTS:
            if k > len(flange):
                continue
            observations = synthetic_observations(BOARD, INTRINSICS, X, T_base_board, flange[:k], noise, rng)
            try:
                result = _calibrate(observations, BOARD, INTRINSICS, noise.robot, None, X)
            except (CalibrationInputError, ValueError, np.linalg.LinAlgError) as exc:
                result = {"failed": str(exc)}
            result["predicted"] = out["strategies"][name]["curve"][k - 1]
            out["achieved"].setdefault(name, {})[str(k)] = result
    if render:
        for scenario_name in RENDER_SCENARIOS:
            for name in ("d-optimal", "default"):
                flange = views[name][0][: WITHIN if name == "d-optimal" else None]
                sim_seed = int(rng.integers(0, 2**63 - 1))
                out["rendered"].setdefault(scenario_name, {})[name] = _render(
                    scenario_name, X, T_base_board, flange, sim_seed, f"p{index:03d}-{name}"
                )
    return out


def _render(
    scenario_name: str,
    X: np.ndarray,
    T_base_board: np.ndarray,
    flange: list[np.ndarray],
    sim_seed: int,
    name: str,
) -> dict:
    """Render, detect and calibrate the views flange of a placement in the named scenario."""
    from hec.sweep.trials import render_views

    scenario = placement_scenario(scenario_name, X, T_base_board)
    try:
        dataset, observations = render_views(scenario, X, flange, sim_seed, name)
        truth = dataset.ground_truth
        result = _calibrate(
            observations,
            dataset.board,
            dataset.intrinsics,
            dataset_robot_noise(dataset),
            dataset_arm(dataset),
            truth.T_flange_cam,
        )
    except (CalibrationInputError, SweepError, ValueError, np.linalg.LinAlgError) as exc:
        return {"failed": " ".join(str(exc).split())}
    return result | {"frames": len(observations)}


def time_planning(seed: int, candidates: int, corner_sigma_px: float, rounds: int = 3) -> dict:
    """Seconds to plan placement 0 (candidates, informations, a d-optimal plan of WITHIN views with
    the cell's checks) and one default-method calibration of its default 17 views, side by side:
    the median of rounds of each, alternating."""
    plan_s, calibration_s = zip(
        *(_time_round(seed, candidates, corner_sigma_px) for _ in range(rounds)), strict=True
    )
    return {
        "candidates": candidates,
        "rounds": rounds,
        "plan_s": float(np.median(plan_s)),
        "calibration_s": float(np.median(calibration_s)),
    }


def _time_round(seed: int, candidates: int, corner_sigma_px: float) -> tuple[float, float]:
    """Seconds of one planning and of one calibration (time_planning)."""
    X, T_base_board, rng = placement(seed, 0)
    noise = _noise(corner_sigma_px)
    start = time.perf_counter()
    pool = candidate_views(T_base_board, X, DISTANCE_M, candidates, rng)
    usable, informations = view_informations(pool, BOARD, INTRINSICS, X, T_base_board, noise)
    cell = SimCell(placement_scenario("default", X, T_base_board), np.random.default_rng(0))
    plan_views(informations, WITHIN, "d-optimal", None, lambda k: cell.accepts(pool[usable[k]]))
    plan_s = time.perf_counter() - start
    flange = [w.T_base_flange for w in rotation_rich_waypoints(T_base_board, X, DISTANCE_M)]
    observations = synthetic_observations(BOARD, INTRINSICS, X, T_base_board, flange, noise, rng)
    start = time.perf_counter()
    _calibrate(observations, BOARD, INTRINSICS, noise.robot, None, X)
    return plan_s, time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--placements", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--candidates", type=int, default=1000)
    parser.add_argument("--corner-sigma-px", type=float, default=0.02)
    parser.add_argument("--render-placements", type=int, default=0, help="placements also rendered")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--plot", type=Path)
    parser.add_argument("--page", type=Path, help="also write the summary as this Markdown page")
    args = parser.parse_args(argv)
    if args.placements < 1 or args.candidates < MAX_VIEWS or args.corner_sigma_px <= 0:
        parser.error(f"--placements >= 1, --candidates >= {MAX_VIEWS} and --corner-sigma-px > 0")
    if args.json is not None:
        check_json_path(args.json)
    jobs = [
        (args.seed, p, args.candidates, args.corner_sigma_px, p < args.render_placements)
        for p in range(args.placements)
    ]
    start = time.perf_counter()
    done = results_as_done(run_placement, jobs, args.workers)
    placements = sorted(tqdm(done, total=len(jobs), unit="placement"), key=lambda p: p["placement"])
    elapsed = time.perf_counter() - start
    timing = time_planning(args.seed, args.candidates, args.corner_sigma_px)
    summary = summarise(placements)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        print_summary(summary, timing, args.corner_sigma_px)
    print(printed.getvalue(), end="")
    print(f"\n{len(placements)} placements in {elapsed:.0f} s")
    if args.json is not None:
        write_json(args.json, {"summary": summary, "timing": timing, "placements": placements})
    if args.plot is not None:
        plot(placements, summary, args.plot)
        print(f"wrote {args.plot}")
    if args.page is not None:
        picture = args.page.with_suffix(".png")
        plot(placements, summary, picture)
        options = argv if argv is not None else sys.argv[1:]
        command = " ".join(["python -m hec.bench.view_planning", *options])
        body = [__doc__.split("\n\n")[0].replace("\n", " "), f"![the strategies]({picture.name})"]
        body.append("```\n" + printed.getvalue().strip("\n") + "\n```")
        write_results_page(args.page, "View planning", command, body)
    return 0 if all(passed for _, passed in acceptance(summary, timing)) else 1


if __name__ == "__main__":
    raise SystemExit(main())
