"""Verification benchmark: how often `hec verify` says "moved" when the mount moved between calibration
and verification, and when it did not (the false alarm rate).

Per seed, at measurement fidelity (hec.support.synthetic_scenes: a random mount, the default 17
views, 0.3 px corners, stereo depth noise, 0.1 mm / 0.01 deg robot noise): calibrate with the
default method (learning the noise), then record VERIFY_VIEWS views spread over the same
trajectory (planned with the mount as calibrated, as a real cell would) with new noise, once with
the mount as it was and once moved by --shift-mm along a random direction and --shift-deg about a
random axis, and test each (hec.estimator.solve.verify). Seed s draws from default_rng([s, 0]).

At render fidelity (--fidelity render) each seed renders the --scenario's cell (default or
realistic) with a random mount at the rotation-rich views into a temporary dataset and detects it,
as a render sweep's trial does (hec.sweep.trials.render_views); the verification views are
rendered in the same cell (the same seed for its model errors: the arm's true kinematics, the
lens, the printed board are the cell's), with new noise in every frame (another noise seed), at
VERIFY_VIEWS of the views the calibration used. Seed s draws from default_rng([s, 1, k]), k the
redraw (a random mount that hides the board is drawn again, up to RENDER_REDRAWS times).

    .venv/bin/python -m hec.bench.verify [--fidelity measurement|render]
        [--scenario default|realistic] [--seeds N] [--shift-mm 1] [--shift-deg 0.2]
        [--corner-factor 1] [--workers 2] [--json OUT]

--seeds: default 100 (measurement), 30 (render: 10-40 s a seed). --corner-factor N (measurement
only) gives the data N times the corner noise their covariances declare (in both calibration and
verification: the learned levels must carry it over). Exit status 1 when the detection rate is
below 95 % or the false alarm rate above 5 %.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one BLAS thread per worker process

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from hec.bench.robustness import RENDER_REDRAWS, _declare_corner_sigma  # noqa: E402
from hec.calibration.report import check_json_path, write_json  # noqa: E402
from hec.estimator.common.noise import LearnedNoiseLevels  # noqa: E402
from hec.estimator.geometry.lie import pose_nees, pose_plus  # noqa: E402
from hec.estimator.geometry.transforms import pose_error  # noqa: E402
from hec.estimator.geometry.waypoints import rotation_rich_waypoints  # noqa: E402
from hec.estimator.io.calibration_file import learned_noise_levels  # noqa: E402
from hec.estimator.observe.frames import Dataset  # noqa: E402
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations  # noqa: E402
from hec.estimator.solve.calibration import Calibration, MethodOptions  # noqa: E402
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import run_method  # noqa: E402
from hec.estimator.solve.noise_learning import LearnedNoise, learn_noise  # noqa: E402
from hec.estimator.solve.problem import (
    CalibrationInputError,
    CalibrationProblem,
    build_problem,
    dataset_arm,
    dataset_robot_noise,
)
from hec.estimator.solve.verify import (
    VERIFY_VIEWS,
    Verification,
    spread_views,
    verification_problem,
    verify_mount,
)
from hec.sim.scenario import Scenario, load_scenario  # noqa: E402
from hec.support.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount  # noqa: E402
from hec.sweep.rows import SweepError  # noqa: E402
from hec.sweep.trials import render_views  # noqa: E402

DETECTION_TARGET = 0.95
FALSE_ALARM_TARGET = 0.05
DECLARED = SyntheticNoise()
FIDELITIES = ("measurement", "render")
SCENARIOS = ("default", "realistic")
DEFAULT_SEEDS = {"measurement": 100, "render": 30}


def learned_levels(learned: LearnedNoise) -> LearnedNoiseLevels:
    """What a calibration file records of the learned noise, read as `hec verify` reads it
    (hec.estimator.io.calibration_file)."""
    return learned_noise_levels(learned.to_dict(), Path("<learned noise>"))


def random_shift(rng: np.random.Generator, shift_mm: float, shift_deg: float) -> np.ndarray:
    """(6,) a shift of shift_mm along a random direction and shift_deg about a random axis."""
    t, w = rng.standard_normal(3), rng.standard_normal(3)
    return np.concatenate(
        [1e-3 * shift_mm * t / np.linalg.norm(t), np.radians(shift_deg) * w / np.linalg.norm(w)]
    )


def _cases(
    T_flange_cam: np.ndarray, rng: np.random.Generator, shift_mm: float, shift_deg: float
) -> list[tuple[str, np.ndarray]]:
    """The verification cell's true mount (4, 4) per case: "unmoved" the calibration's, "moved" it
    shifted by random_shift."""
    return [
        ("unmoved", T_flange_cam),
        ("moved", pose_plus(T_flange_cam, random_shift(rng, shift_mm, shift_deg))),
    ]


def _calibrate(problem: CalibrationProblem, observations: list) -> tuple[Calibration, LearnedNoiseLevels]:
    """The default method with learned noise, as hec calibrate runs it: the calibration and the
    levels its file records."""
    options = MethodOptions()
    learned = learn_noise(problem, options)
    return run_method(DEFAULT_METHOD, problem, options, observations, learned), learned_levels(learned)


def _calibration_row(cal: Calibration, T_flange_cam_true: np.ndarray) -> dict:
    """The calibration against the truth: error (mm, deg) and NEES."""
    error_m, error_rad = pose_error(cal.T_flange_cam, T_flange_cam_true)
    nees = pose_nees(cal.T_flange_cam, T_flange_cam_true, cal.covariance)
    return {"error_mm": 1e3 * error_m, "error_deg": float(np.degrees(error_rad)), "nees": nees}


def _case_row(v: Verification, T_flange_cam_true: np.ndarray) -> dict:
    """One verification: p-value, verdict, estimated shift (mm), test 1-sigma (mm, deg), fit chi2 per
    degree of freedom and the NEES of the verification frames' own mount estimate."""
    return {
        "p": v.p_value,
        "moved": v.moved,
        "shift_mm": v.shift_mm,
        "sigma": v.test_sigma,
        "fit": v.fit_chi2_dof,
        "nees_verify": pose_nees(v.T_flange_cam_verify, T_flange_cam_true, v.covariance_verify),
    }


# --- measurement fidelity ------------------------------------------------------------------------


def _observations(
    T_flange_cam: np.ndarray, flange: list, rng: np.random.Generator, corner_factor: float
) -> list:
    actual = replace(DECLARED, corner_sigma_px=corner_factor * DECLARED.corner_sigma_px)
    observations = synthetic_observations(BOARD, INTRINSICS, T_flange_cam, T_BASE_BOARD, flange, actual, rng)
    if corner_factor != 1.0:
        observations = _declare_corner_sigma(observations, DECLARED.corner_sigma_px)
    return observations


def run_seed(seed: int, shift_mm: float, shift_deg: float, corner_factor: float) -> dict:
    """One seed at measurement fidelity: the verification with the mount unmoved and moved."""
    rng = np.random.default_rng([seed, 0])
    X = random_mount(rng)
    flange = [
        w.T_base_flange for w in rotation_rich_waypoints(T_BASE_BOARD, X, SCENARIO.trajectory.distance_m)
    ]
    observations = _observations(X, flange, rng, corner_factor)
    cal, levels = _calibrate(build_problem(observations, BOARD, INTRINSICS, DECLARED.robot), observations)
    out = {"seed": seed, "calibration": _calibration_row(cal, X)}
    for case, X_now in _cases(X, rng, shift_mm, shift_deg):
        views = _observations(X_now, spread_views(flange, VERIFY_VIEWS), rng, corner_factor)
        v_problem = verification_problem(build_problem(views, BOARD, INTRINSICS, DECLARED.robot), levels)
        out[case] = _case_row(verify_mount(v_problem, cal.T_flange_cam, cal.covariance), X_now)
    return out


# --- render fidelity -----------------------------------------------------------------------------


def _dataset_problem(dataset: Dataset, observations: list) -> CalibrationProblem:
    """The problem hec calibrate and hec verify build from a dataset (its robot noise and arm)."""
    robot, arm = dataset_robot_noise(dataset), dataset_arm(dataset)
    return build_problem(observations, dataset.board, dataset.intrinsics, robot, arm=arm)


def _used_targets(dataset: Dataset, flange: list[np.ndarray]) -> list[np.ndarray]:
    """The T_base_flange (4, 4) targets the rendering did not skip (dataset.json lists the skipped)."""
    skipped = {s["index"] for s in dataset.metadata["simulation"]["skipped_waypoints"]}
    return [T for i, T in enumerate(flange) if i not in skipped]


@dataclass(frozen=True)
class RenderedCalibration:
    """A seed's rendered and calibrated cell. rng: the seed's generator, after the draws so far;
    T_flange_cam_true: (4, 4) the true mount; targets: the T_base_flange (4, 4) targets the
    calibration's frames were rendered at; cell_seed: the seed of the cell's model errors
    (hec.sim.simulate.simulate); calibration and levels: the default method's and its learned noise."""

    rng: np.random.Generator
    T_flange_cam_true: np.ndarray
    targets: list[np.ndarray]
    cell_seed: int
    calibration: Calibration
    levels: LearnedNoiseLevels


def _rendered_calibration(scenario: Scenario, seed: int) -> RenderedCalibration:
    """Render and calibrate seed's cell, drawing the mount again when it hides the board. Raises
    SweepError when no draw gives a calibration."""
    problem_text = ""
    for redraw in range(RENDER_REDRAWS + 1):
        rng = np.random.default_rng([seed, 1, redraw])
        X = random_mount(rng)
        T_base_board, distance = scenario.board.transform(), scenario.trajectory.distance_m
        flange = [w.T_base_flange for w in rotation_rich_waypoints(T_base_board, X, distance)]
        cell_seed = int(rng.integers(0, 2**63 - 1))
        try:
            dataset, observations = render_views(scenario, X, flange, cell_seed, f"verify-{seed}")
            cal, levels = _calibrate(_dataset_problem(dataset, observations), observations)
        except (CalibrationInputError, SweepError) as exc:
            problem_text = str(exc)
            continue
        return RenderedCalibration(rng, X, _used_targets(dataset, flange), cell_seed, cal, levels)
    raise SweepError(f"no usable mount in {RENDER_REDRAWS + 1} draws: {problem_text}")


def run_render_seed(seed: int, scenario_name: str, shift_mm: float, shift_deg: float) -> dict:
    """One seed at render fidelity (module doc): the verification with the mount unmoved and moved,
    or {"seed", "failed"} when the rendering or a fit failed."""
    scenario = load_scenario(None if scenario_name == "default" else scenario_name)
    try:
        r = _rendered_calibration(scenario, seed)
        cal = r.calibration
        out = {"seed": seed, "calibration": _calibration_row(cal, r.T_flange_cam_true)}
        for case, X_now in _cases(r.T_flange_cam_true, r.rng, shift_mm, shift_deg):
            noise_seed = int(r.rng.integers(0, 2**63 - 1))  # the same cell, new noise in every frame
            dataset, views = render_views(
                scenario,
                X_now,
                spread_views(r.targets),
                r.cell_seed,
                f"verify-{seed}-{case}",
                noise_seed=noise_seed,
            )
            v_problem = verification_problem(_dataset_problem(dataset, views), r.levels)
            v = verify_mount(v_problem, cal.T_flange_cam, cal.covariance, cal.depth_scale)
            out[case] = _case_row(v, X_now)
    except (CalibrationInputError, SweepError) as exc:
        return {"seed": seed, "failed": str(exc)}
    return out


# --- the benchmark -------------------------------------------------------------------------------


def summary(rows: list[dict]) -> tuple[float, float, list[str]]:
    """(detection rate, false alarm rate, printed lines) over the rows that did not fail."""
    done = [r for r in rows if "failed" not in r]
    detected = float(np.mean([r["moved"]["moved"] for r in done]))
    false_alarm = float(np.mean([r["unmoved"]["moved"] for r in done]))
    sigma = np.median([r["unmoved"]["sigma"] for r in done], axis=0)
    shift = np.median([r["unmoved"]["shift_mm"] for r in done])
    cal = {k: np.median([r["calibration"][k] for r in done]) for k in ("error_mm", "error_deg")}
    lines = [
        f"moved: reported moved in {100 * detected:.1f} % of {len(done)} seeds "
        f"(target >= {100 * DETECTION_TARGET:.0f} %)",
        f"unmoved: reported moved in {100 * false_alarm:.1f} % (target <= {100 * FALSE_ALARM_TARGET:.0f} %)",
        f"test 1-sigma (median, calibration + {VERIFY_VIEWS} verification views): {sigma[0]:.3f} mm, "
        f"{sigma[1]:.4f} deg; unmoved shift estimate median {shift:.3f} mm",
        f"fit of the verification frames (unmoved): chi-square per dof median "
        f"{np.median([r['unmoved']['fit'] for r in done]):.2f}",
        f"NEES (mean, 6 if honest): calibration {np.mean([r['calibration']['nees'] for r in done]):.1f}, "
        f"verification frames' mount {np.mean([r['unmoved']['nees_verify'] for r in done]):.1f}; "
        f"calibration error median {cal['error_mm']:.3f} mm, {cal['error_deg']:.4f} deg",
    ]
    failed = [r for r in rows if "failed" in r]
    if failed:
        lines.append(
            f"failed: {len(failed)} seeds (left out), e.g. seed {failed[0]['seed']}: {failed[0]['failed']}"
        )
    return detected, false_alarm, lines


def _run_seeds(args: argparse.Namespace) -> list[dict]:
    """Every seed's row (run_seed or run_render_seed), in seed order, with a progress bar."""
    if args.fidelity == "render":
        fn, extra = run_render_seed, (args.scenario, args.shift_mm, args.shift_deg)
    else:
        fn, extra = run_seed, (args.shift_mm, args.shift_deg, args.corner_factor)
    with ProcessPoolExecutor(args.workers) as pool:
        futures = [pool.submit(fn, seed, *extra) for seed in range(args.seeds)]
        rows = [f.result() for f in tqdm(as_completed(futures), total=len(futures), unit="seed")]
    return sorted(rows, key=lambda r: r["seed"])


def _header(args: argparse.Namespace, seconds: float) -> str:
    cell = (
        f"{args.scenario} scenario"
        if args.fidelity == "render"
        else f"corner noise {args.corner_factor:g}x declared"
    )
    return (
        f"verify benchmark, {args.fidelity} fidelity, {cell}: shift {args.shift_mm:g} mm and "
        f"{args.shift_deg:g} deg, {VERIFY_VIEWS} views ({seconds:.0f} s)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fidelity", choices=FIDELITIES, default="measurement")
    parser.add_argument("--scenario", choices=SCENARIOS, default="default", help="render fidelity: the cell")
    parser.add_argument("--seeds", type=int, help="default: 100 (measurement), 30 (render)")
    parser.add_argument("--shift-mm", type=float, default=1.0)
    parser.add_argument("--shift-deg", type=float, default=0.2)
    parser.add_argument("--corner-factor", type=float, default=1.0, help="measurement fidelity only")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path, metavar="OUT", help="also write every seed's row to this file")
    args = parser.parse_args(argv)
    if args.fidelity == "render" and args.corner_factor != 1.0:
        parser.error("--corner-factor is for measurement fidelity (the rendered cell has its own noise)")
    if args.fidelity == "measurement" and args.scenario != "default":
        parser.error("--scenario is for render fidelity (measurement fidelity is the default cell)")
    args.seeds = DEFAULT_SEEDS[args.fidelity] if args.seeds is None else args.seeds
    if args.json is not None:
        check_json_path(args.json)
    start = time.perf_counter()
    rows = _run_seeds(args)
    detected, false_alarm, lines = summary(rows)
    print(_header(args, time.perf_counter() - start))
    print("\n".join(lines))
    if args.json is not None:
        arguments = vars(args) | {"json": str(args.json)}
        print(f"wrote {write_json(args.json, {'arguments': arguments, 'rows': rows})}")
    return 0 if detected >= DETECTION_TARGET and false_alarm <= FALSE_ALARM_TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
