"""Robustness benchmark: every method on data that break the model the estimators are told, against
the truth and the OpenCV baselines on the same data.

Each case declares one noise model to the estimators and gives the data another (or the ideal
cell, where the two agree). Measurement fidelity builds on hec.support.synthetic_scenes (a random
mount per trial, the default 17 views, 0.3 px corners, stereo depth noise, 0.1 mm / 0.01 deg
robot noise declared); render fidelity renders every trial with MuJoCo into a temporary dataset
and detects the board, as the render sweeps do (hec.sweep.trials).

    ideal                 declared = actual (the default scenario)
    depth bias S + O      depth measured as (1 + S) z + O; the estimators assume none
    arm noise Nx          reported flange poses N times noisier than the declared 0.1 mm / 0.01 deg
    corner noise 3x       corners 3x noisier than their covariance says (measurements only)
    board scale S         the printed board S larger than its definition (observations of the
                          scaled board, the problem built with the nominal one)
    realistic             models/scenarios/realistic.toml, every model error on (render only)

Per case and method over the trials: median and 95th-percentile translation (mm) and rotation
(deg) error, mean NEES (methods with a covariance), the fraction of runs that warned, the mean
fraction of observations rejected and the failures. Then the acceptance lines of the default
method (hec.estimator.solve.methods.DEFAULT_METHOD) against the best OpenCV method (the lowest median
among those that succeeded in at least half the trials, per quantity), and the Cramer-Rao bound
at the truth under the actual noise: the median root-sum-square of its 1-sigmas and the median error
an efficient unbiased estimator would have (comparable to a method's median; a model bias such as a
depth scale adds error no bound accounts for), beside the target, so a reader can see when no
estimator could reach it. Exit status 1 when an acceptance line fails.

Trial t of case c draws everything from numpy.random.default_rng([seed, c, t]), c the case's
index in CASES (the same in every run), as the sweeps do; a render trial whose random mount hides
the board from every view is drawn again (RENDER_REDRAWS).

    .venv/bin/python -m hec.bench.robustness [--trials 50] [--render-trials 20] [--seed 0]
        [--fidelity measurements|render|both] [--cases WORD,...] [--workers 2] [--json OUT]
        [--plot OUT.png] [--page PATH.md]

--page also writes the tables as a documentation page (with the plot beside it).
"""

from __future__ import annotations

import os

# One BLAS thread per process: the trials run in parallel processes (see hec.bench.estimators).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from hec.bench.robustness_plot import plot  # noqa: E402
from hec.bench.robustness_summary import NEES_RANGE, TARGET_RATIO, best_opencv, format_case, summarise  # noqa: E402
from hec.calibration.report import check_json_path, write_json  # noqa: E402
from hec.estimator.common.noise import RobotPoseNoise  # noqa: E402
from hec.estimator.geometry.lie import pose_nees  # noqa: E402
from hec.estimator.geometry.transforms import pose_error  # noqa: E402
from hec.estimator.geometry.waypoints import rotation_rich_waypoints  # noqa: E402
from hec.estimator.observe.observations import camera_points  # noqa: E402
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations  # noqa: E402
from hec.estimator.solve.calibration import MethodOptions  # noqa: E402
from hec.estimator.solve.measurement_model import HandEyeState  # noqa: E402
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS, needs_learned_noise, run_method  # noqa: E402
from hec.estimator.solve.noise_learning import learn_noise  # noqa: E402
from hec.estimator.solve.observability import observability  # noqa: E402
from hec.estimator.solve.problem import CalibrationInputError, build_problem  # noqa: E402
from hec.estimator.targets.board import BoardDefinition  # noqa: E402
from hec.sim.scenario import Scenario, load_scenario, scenario_from_dict  # noqa: E402
from hec.support.parallel import results_as_done  # noqa: E402
from hec.support.results_page import write_results_page  # noqa: E402
from hec.support.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount, scene  # noqa: E402
from hec.sweep.parameters import MEASUREMENTS, RENDER  # noqa: E402
from hec.sweep.rows import SweepError  # noqa: E402

DECLARED = SyntheticNoise()  # what the estimators are told at measurement fidelity
# Render fidelity: a random mount can put the camera behind the wrist (every view hidden); such a
# trial is drawn again from default_rng([seed, case, trial, k]), k = 1, 2, ... up to this many times.
RENDER_REDRAWS = 4
# Warning kinds, told apart by words of the fit check and the observability check (a warning
# counts as every kind whose words it contains; the rejection warning quotes its likely cause).
WARNING_KINDS = (
    ("were left out as outliers", "rejections"),
    ("the arm is less exact", "arm"),
    ("the depth is biased", "depth bias"),
    ("the depth reads", "depth bias"),
    ("depth and pixels disagree", "depth noise"),
    ("the board looks", "board scale"),
    ("the board is printed", "board scale"),
    ("cannot tell the board's print scale", "scale ambiguity"),
    ("grow toward the image border", "intrinsics"),
    ("the intrinsics are off", "intrinsics"),
    ("the lens distortion differs", "intrinsics"),
    ("the corners fit", "pixel noise"),
    ("the prior disagrees", "prior"),
    ("observable", "observability"),
    ("poorly determined", "observability"),
)


@dataclass(frozen=True)
class Case:
    """One way the data differ from the model. depth_bias: (scale, offset_m) of the measured depth;
    arm_factor / corner_factor: actual over declared noise; board_scale: printed over defined size;
    scenario: render fidelity, the preset the trial starts from."""

    name: str
    fidelity: str
    depth_bias: tuple[float, float] = (1.0, 0.0)
    arm_factor: float = 1.0
    corner_factor: float = 1.0
    board_scale: float = 1.0
    scenario: str = "default"

    @property
    def key(self) -> str:
        return f"{self.fidelity}: {self.name}"


def _cases() -> list[Case]:
    both = [
        Case("ideal", MEASUREMENTS),
        Case("depth bias 1% + 2 mm", MEASUREMENTS, depth_bias=(1.01, 0.002)),
        Case("depth bias 2% + 5 mm", MEASUREMENTS, depth_bias=(1.02, 0.005)),
        Case("board scale 1%", MEASUREMENTS, board_scale=1.01),
        Case("board scale 2%", MEASUREMENTS, board_scale=1.02),
    ]
    measurements_only = [
        Case("arm noise 3x", MEASUREMENTS, arm_factor=3.0),
        Case("arm noise 10x", MEASUREMENTS, arm_factor=10.0),
        Case("corner noise 3x", MEASUREMENTS, corner_factor=3.0),
    ]
    render = [replace(c, fidelity=RENDER) for c in both] + [Case("realistic", RENDER, scenario="realistic")]
    return both[:3] + measurements_only + both[3:] + render


# Append new cases at the end: a case's index is part of its trials' seeds.
CASES: list[Case] = _cases()


# --- inputs ------------------------------------------------------------------------------------


def _scaled_board(scale: float) -> BoardDefinition:
    """BOARD printed `scale` times its size (every length in its plane)."""
    centers = {i: (scale * x, scale * y) for i, (x, y) in BOARD.marker_centers_m.items()}
    size = (scale * BOARD.size_m[0], scale * BOARD.size_m[1])
    return replace(BOARD, size_m=size, marker_size_m=scale * BOARD.marker_size_m, marker_centers_m=centers)


def _declare_corner_sigma(observations: list, sigma_px: float) -> list:
    """The same corners, with covariances that say sigma_px per coordinate (the points' covariances
    recomputed from them, as the detector would report)."""
    for obs in observations:
        for i, m in enumerate(obs.markers):
            factor = (sigma_px / np.sqrt(m.corners_cov[0, 0])) ** 2
            m = replace(m, corners_cov=factor * m.corners_cov, center_cov=factor * m.center_cov)
            points, points_cov = camera_points(m, m.depth_m, m.depth_cov, np.zeros((5, 2)), INTRINSICS)
            obs.markers[i] = replace(m, points_cam=points, points_cov=points_cov)
    return observations


def measurement_inputs(case: Case, rng: np.random.Generator) -> tuple:
    """(observations, problem the estimators get, problem with the actual noise (for the bound),
    true T_flange_cam, T_base_board) of one measurement trial."""
    from hec.sweep.trials import _with_depth_bias

    X = random_mount(rng)
    robot = DECLARED.robot
    actual = replace(
        DECLARED,
        corner_sigma_px=case.corner_factor * DECLARED.corner_sigma_px,
        robot=RobotPoseNoise(
            case.arm_factor * robot.translation_sigma_m, case.arm_factor * robot.rotation_sigma_rad
        ),
    )
    flange = [
        w.T_base_flange for w in rotation_rich_waypoints(T_BASE_BOARD, X, SCENARIO.trajectory.distance_m)
    ]
    if case.board_scale == 1.0:
        observations = scene(X, rng, noise=actual)  # the same views
    else:  # scene()'s views, of the printed board
        board = _scaled_board(case.board_scale)
        observations = synthetic_observations(board, INTRINSICS, X, T_BASE_BOARD, flange, actual, rng)
    if case.depth_bias != (1.0, 0.0):
        scale, offset = case.depth_bias
        biased = {"noise": {"depth_bias": {"enabled": True, "scale": scale, "offset_m": offset}}}
        observations = _with_depth_bias(observations, flange, X, scenario_from_dict(biased), BOARD)
    truth_problem = build_problem(observations, BOARD, INTRINSICS, actual.robot)  # its own copy
    if case.corner_factor != 1.0:
        observations = _declare_corner_sigma(observations, DECLARED.corner_sigma_px)
    problem = build_problem(observations, BOARD, INTRINSICS, DECLARED.robot)
    return observations, problem, truth_problem, X, T_BASE_BOARD


def render_scenario(case: Case) -> Scenario:
    """The scenario a render trial starts from: the case's preset with its depth bias and board
    scale (only the print scale: no bend, no marker placement error)."""
    base = load_scenario(None if case.scenario == "default" else case.scenario)
    data = base.to_dict()
    if case.depth_bias != (1.0, 0.0):
        scale, offset = case.depth_bias
        data["noise"]["depth_bias"] = {"enabled": True, "scale": scale, "offset_m": offset}
    if case.board_scale != 1.0:
        e = case.board_scale - 1.0
        board = {
            "enabled": True,
            "scale_error": [e, e],
            "bend_m": [0.0, 0.0],
            "marker_placement_sigma_m": 0.0,
        }
        data.setdefault("errors", {})["board"] = board
    return scenario_from_dict(data, f"robustness case {case.name!r}", Path(base.base_dir))


def render_inputs(case: Case, rng: np.random.Generator, seed: int, trial: int) -> tuple:
    """As measurement_inputs, for a trial rendered and detected (a random
    mount and the scenario's views, as a render sweep's trial)."""
    from hec.sweep.trials import TrialTask
    from hec.sweep.trials import render_inputs as render_trial_inputs

    scenario = render_scenario(case)
    parameters = {"mount": "random", "trajectory": "rotation-rich", "waypoints": None}
    base_dir, index = str(Path(scenario.base_dir).resolve()), CASES.index(case)
    task = TrialTask(
        f"r{index:02d}-t{trial:04d}", case.name, index, trial, seed, RENDER, parameters, (), {}, base_dir
    )
    observations, board, intrinsics, robot, arm, X, T_base_board = render_trial_inputs(task, scenario, rng)
    problem = build_problem(observations, board, intrinsics, robot, arm=arm)
    return observations, problem, problem, X, T_base_board


# --- one trial ---------------------------------------------------------------------------------


def _warning_kinds(text: str) -> set[str]:
    kinds = {kind for words, kind in WARNING_KINDS if words in text}
    return kinds or {text.split(":")[0][:40]}


def _rss(values) -> float:
    total = float(np.sqrt(np.sum(np.square(values)))) if values is not None else math.nan
    return total if math.isfinite(total) else math.nan


def run_trial(case_index: int, seed: int, trial: int) -> dict:
    """One trial of CASES[case_index]: the bound at the truth (RSS mm and deg; its covariance blocks,
    mm^2 and deg^2) and per method the errors, NEES, warning kinds and rejected fraction, or its
    failure."""
    case = CASES[case_index]
    rng = np.random.default_rng([seed, case_index, trial])
    out = {"case": case.key, "trial": trial, "crb": [math.nan, math.nan], "crb_cov": None, "methods": {}}
    for redraw in range(RENDER_REDRAWS + 1):
        try:
            if case.fidelity == MEASUREMENTS:
                observations, problem, truth_problem, X, T_base_board = measurement_inputs(case, rng)
            else:
                observations, problem, truth_problem, X, T_base_board = render_inputs(case, rng, seed, trial)
            break
        except (CalibrationInputError, SweepError) as exc:
            if case.fidelity == MEASUREMENTS or redraw == RENDER_REDRAWS:
                out["methods"] = {m: {"failed": f"inputs: {exc}"} for m in METHODS}
                return out
            # A mount that puts the camera behind the wrist sees nothing: draw the trial again.
            rng = np.random.default_rng([seed, case_index, trial, redraw + 1])
            out["redrawn"] = redraw + 1
    bound = observability(truth_problem, HandEyeState(X, T_base_board=T_base_board))
    if bound.observable:
        out["crb"] = [_rss(bound.crb_sigma_translation_mm), _rss(bound.crb_sigma_rotation_deg)]
        C = bound.crb_covariance
        out["crb_cov"] = [(1e6 * C[:3, :3]).tolist(), (np.degrees(1.0) ** 2 * C[3:, 3:]).tolist()]
    options, learned = MethodOptions(), None
    for method in METHODS:
        try:
            if learned is None and needs_learned_noise(method, options):
                learned = learn_noise(problem, options)  # once, shared by the noise-modelling methods
            result = run_method(method, problem, options, observations, learned)  # with the printed warnings
        except Exception as exc:  # noqa: BLE001  (any failure of one method is that method's failure)
            text = str(exc) if isinstance(exc, CalibrationInputError) else f"{type(exc).__name__}: {exc}"
            out["methods"][method] = {"failed": " ".join(text.split())}
            continue
        error_m, error_rad = pose_error(result.T_flange_cam, X)
        nees = None
        if result.covariance is not None:
            try:
                nees = pose_nees(result.T_flange_cam, X, result.covariance)
            except np.linalg.LinAlgError:
                nees = math.inf
        out["methods"][method] = {
            "error_mm": 1e3 * error_m,
            "error_deg": math.degrees(error_rad),
            "nees": nees,
            "warnings": sorted(set().union(*(_warning_kinds(w) for w in result.warnings))),
            "rejected": result.observations_rejected / max(problem.observation_count, 1),
        }
    return out


# --- running -----------------------------------------------------------------------------------


def run_cases(cases: list[Case], trials: int, seed: int, workers: int, progress: bool = True) -> dict:
    """Summaries keyed by Case.key, every trial of every case; workers <= 1 runs here, in order."""
    jobs = [(CASES.index(c), seed, t) for c in cases for t in range(trials)]
    results: dict[str, list[dict]] = {c.key: [] for c in cases}
    label = cases[0].fidelity if cases else ""
    done = results_as_done(run_trial, jobs, workers)
    for out in tqdm(done, total=len(jobs), unit="trial", disable=not progress, desc=label):
        results[out["case"]].append(out)
    for trials_of_case in results.values():
        trials_of_case.sort(key=lambda t: t["trial"])
    return {key: summarise(t) for key, t in results.items()}


def _selected(case: Case, words: str | None) -> bool:
    return words is None or any(w.strip() and w.strip() in case.name for w in words.split(","))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=50, help="trials per measurement case")
    parser.add_argument("--render-trials", type=int, default=20, help="trials per render case (slow)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fidelity", choices=(MEASUREMENTS, RENDER, "both"), default="both")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--cases",
        help="only the cases whose name contains one of these comma-separated words (e.g. 'depth,board')",
    )
    parser.add_argument("--json", help="write the summaries to this file")
    parser.add_argument("--plot", help="write a PNG: median errors and the default's NEES per case")
    parser.add_argument("--page", type=Path, help="also write the tables as this Markdown page")
    args = parser.parse_args(argv)
    if args.json:
        check_json_path(Path(args.json))
    fidelities = (MEASUREMENTS, RENDER) if args.fidelity == "both" else (args.fidelity,)
    summaries, start = {}, time.perf_counter()
    for fidelity in fidelities:
        trials = args.trials if fidelity == MEASUREMENTS else args.render_trials
        cases = [c for c in CASES if c.fidelity == fidelity and _selected(c, args.cases)]
        summaries |= run_cases(cases, trials, args.seed, args.workers)
    print(f"default method: {DEFAULT_METHOD}; errors against the truth; seed {args.seed}")
    for key, summary in summaries.items():
        print("\n".join(format_case(key, summary)))
    failed = [
        f"{key}: {line['text']}"
        for key, s in summaries.items()
        for line in s["acceptance"]
        if line["ok"] is False
    ]
    print(f"\n{len(failed)} acceptance lines fail; wall time {time.perf_counter() - start:.0f} s")
    if args.plot:
        plot(summaries, args.plot, best_opencv, TARGET_RATIO, NEES_RANGE)
        print(f"plot: {args.plot}")
    if args.page:
        write_page(args, argv, summaries, len(failed))
    if args.json:
        write_json(
            Path(args.json), {"seed": args.seed, "default_method": DEFAULT_METHOD, "summaries": summaries}
        )
    return 1 if failed else 0


def write_page(args: argparse.Namespace, argv: list[str] | None, summaries: dict, failed: int) -> None:
    """The tables as a results page, with the plot (PAGE's stem .png beside it) when --plot is not given
    elsewhere."""
    picture = args.page.with_suffix(".png")
    plot(summaries, str(picture), best_opencv, TARGET_RATIO, NEES_RANGE)
    intro = (
        f"Every method on data that break the model the estimators are told (default method {DEFAULT_METHOD};"
        f" seed {args.seed}): per case the median and 95th-percentile error of T_flange_cam against the"
        " truth, the mean NEES (about 6 when the covariance is honest), the runs that warned, the"
        " observations rejected and the failures; then the default method's acceptance lines against the"
        f" best OpenCV method and the Cramer-Rao bound. {failed} acceptance lines fail."
    )
    blocks = ["```\n" + "\n".join(format_case(key, s)).strip() + "\n```" for key, s in summaries.items()]
    command = " ".join(["python -m hec.bench.robustness", *(argv if argv is not None else sys.argv[1:])])
    write_results_page(args.page, "Robustness", command, [intro, f"![the cases]({picture.name})", *blocks])


if __name__ == "__main__":
    raise SystemExit(main())
