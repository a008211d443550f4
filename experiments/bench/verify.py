"""Verification benchmark: how often `hec verify` says "moved" when the mount moved between calibration
and verification, and when it did not (the false alarm rate).

Per seed, at measurement fidelity (experiments.synthetic_scenes: a random mount, the default 17
views, 0.3 px corners, stereo depth noise, 0.1 mm / 0.01 deg robot noise): calibrate with the
default method (learning the noise), then record VERIFY_VIEWS views spread over the same
trajectory (planned with the mount as calibrated, as a real cell would) with new noise, once with
the mount as it was and once moved by --shift-mm along a random direction and --shift-deg about a
random axis, and test each (estimator.solve.verify). Seed s draws from default_rng([s, case]).

    .venv/bin/python -m experiments.bench.verify [--seeds 100] [--shift-mm 1] [--shift-deg 0.2]
        [--corner-factor 1] [--workers 2]

--corner-factor N gives the data N times the corner noise their covariances declare (in both
calibration and verification: the learned levels must carry it over). Exit status 1 when the
detection rate is below 95 % or the false alarm rate above 5 %.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one BLAS thread per worker process

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from estimator.geometry.lie import pose_plus  # noqa: E402
from estimator.geometry.waypoints import rotation_rich_waypoints  # noqa: E402
from estimator.io.calibration_file import LearnedNoiseLevels  # noqa: E402
from estimator.observe.synthetic import SyntheticNoise, synthetic_observations  # noqa: E402
from estimator.solve.calibration import MethodOptions  # noqa: E402
from estimator.solve.methods import DEFAULT_METHOD, run_method  # noqa: E402
from estimator.solve.noise_learning import LearnedNoise, learn_noise  # noqa: E402
from estimator.solve.problem import build_problem  # noqa: E402
from estimator.solve.verify import VERIFY_VIEWS, spread_views, verification_problem, verify_mount  # noqa: E402
from experiments.bench.robustness import _declare_corner_sigma  # noqa: E402
from experiments.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount  # noqa: E402

DETECTION_TARGET = 0.95
FALSE_ALARM_TARGET = 0.05
DECLARED = SyntheticNoise()


def learned_levels(learned: LearnedNoise) -> LearnedNoiseLevels:
    """What a calibration file records of the learned noise (estimator.io.calibration_file)."""
    theta = (
        {}
        if learned.theta is None
        else dict(zip(learned.theta_names, map(float, learned.theta), strict=True))
    )
    robot = learned.learned.robot
    return LearnedNoiseLevels(
        learned.learned.pixel_scale,
        learned.learned.depth_scale,
        robot.translation_sigma_m,
        robot.rotation_sigma_rad,
        theta,
    )


def random_shift(rng: np.random.Generator, shift_mm: float, shift_deg: float) -> np.ndarray:
    """(6,) a shift of shift_mm along a random direction and shift_deg about a random axis."""
    t, w = rng.standard_normal(3), rng.standard_normal(3)
    return np.concatenate(
        [1e-3 * shift_mm * t / np.linalg.norm(t), np.radians(shift_deg) * w / np.linalg.norm(w)]
    )


def _observations(
    T_flange_cam: np.ndarray, flange: list, rng: np.random.Generator, corner_factor: float
) -> list:
    actual = replace(DECLARED, corner_sigma_px=corner_factor * DECLARED.corner_sigma_px)
    observations = synthetic_observations(BOARD, INTRINSICS, T_flange_cam, T_BASE_BOARD, flange, actual, rng)
    if corner_factor != 1.0:
        observations = _declare_corner_sigma(observations, DECLARED.corner_sigma_px)
    return observations


def run_seed(seed: int, shift_mm: float, shift_deg: float, corner_factor: float) -> dict:
    """One seed: the verification's p-value, shift and test sigma with the mount unmoved and moved."""
    rng = np.random.default_rng([seed, 0])
    X = random_mount(rng)
    flange = [
        w.T_base_flange for w in rotation_rich_waypoints(T_BASE_BOARD, X, SCENARIO.trajectory.distance_m)
    ]
    observations = _observations(X, flange, rng, corner_factor)
    problem = build_problem(observations, BOARD, INTRINSICS, DECLARED.robot)
    options = MethodOptions()
    learned = learn_noise(problem, options)
    cal = run_method(DEFAULT_METHOD, problem, options, observations, learned)
    levels = learned_levels(learned)
    out = {"seed": seed}
    for case, X_now in (("unmoved", X), ("moved", pose_plus(X, random_shift(rng, shift_mm, shift_deg)))):
        views = _observations(X_now, spread_views(flange, VERIFY_VIEWS), rng, corner_factor)
        v_problem = verification_problem(build_problem(views, BOARD, INTRINSICS, DECLARED.robot), levels)
        v = verify_mount(v_problem, cal.T_flange_cam, cal.covariance)
        out[case] = {"p": v.p_value, "moved": v.moved, "shift_mm": v.shift_mm, "sigma": v.test_sigma}
    return out


def summary(rows: list[dict]) -> tuple[float, float, list[str]]:
    """(detection rate, false alarm rate, printed lines)."""
    detected = float(np.mean([r["moved"]["moved"] for r in rows]))
    false_alarm = float(np.mean([r["unmoved"]["moved"] for r in rows]))
    sigma = np.median([r["unmoved"]["sigma"] for r in rows], axis=0)
    shift = np.median([r["unmoved"]["shift_mm"] for r in rows])
    lines = [
        f"moved: reported moved in {100 * detected:.1f} % of {len(rows)} seeds "
        f"(target >= {100 * DETECTION_TARGET:.0f} %)",
        f"unmoved: reported moved in {100 * false_alarm:.1f} % (target <= {100 * FALSE_ALARM_TARGET:.0f} %)",
        f"test 1-sigma (median, calibration + {VERIFY_VIEWS} verification views): {sigma[0]:.3f} mm, "
        f"{sigma[1]:.4f} deg; unmoved shift estimate median {shift:.3f} mm",
    ]
    return detected, false_alarm, lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--shift-mm", type=float, default=1.0)
    parser.add_argument("--shift-deg", type=float, default=0.2)
    parser.add_argument("--corner-factor", type=float, default=1.0)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(
            pool.map(
                run_seed,
                range(args.seeds),
                [args.shift_mm] * args.seeds,
                [args.shift_deg] * args.seeds,
                [args.corner_factor] * args.seeds,
            )
        )
    detected, false_alarm, lines = summary(rows)
    print(
        f"verify benchmark, measurement fidelity: shift {args.shift_mm:g} mm and {args.shift_deg:g} deg, "
        f"corner noise {args.corner_factor:g}x declared, {VERIFY_VIEWS} views "
        f"({time.perf_counter() - start:.0f} s)"
    )
    print("\n".join(lines))
    return 0 if detected >= DETECTION_TARGET and false_alarm <= FALSE_ALARM_TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
