"""Benchmark: is the uncertainty honest with few views? Mean NEES of one method over seeds, by views.

Each seed draws a random mount (hec.support.synthetic_scenes.random_mount) and synthetic observations
of the default board from the first N of the default views, with the default noise (the flange
poses' optionally a factor noisier than the noise the problem declares, so the levels learned from
the data matter). Prints per number of views the mean and median NEES (6 when honest), the share
above chi2(6)'s 95 % line (12.59; 5 % when honest) and the median translation error.

    .venv/bin/python -m hec.bench.few_views [--seeds 40] [--views 6 8 12 17] [--robot-factor 3] [--method ekf]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.lie import NEES_95_LINE, pose_minus
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import run_method
from hec.estimator.solve.problem import build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene


def nees_by_views(method: str, seeds: int, views: int, robot_factor: float) -> tuple[np.ndarray, np.ndarray]:
    """(seeds,) NEES and (seeds,) translation errors (metres) of method with views views, the flange
    poses robot_factor x noisier than declared."""
    declared = SyntheticNoise()
    robot = declared.robot
    data = replace(
        declared,
        robot=RobotPoseNoise(
            robot_factor * robot.translation_sigma_m, robot_factor * robot.rotation_sigma_rad
        ),
    )
    nees, errors = [], []
    for seed in range(seeds):
        rng = np.random.default_rng([seed, views])
        X = random_mount(rng)
        observations = scene(X, rng, noise=data, views=views)
        problem = build_problem(observations, BOARD, INTRINSICS, robot)
        result = run_method(method, problem, MethodOptions(), observations)
        e = pose_minus(result.T_flange_cam, X)
        nees.append(float(e @ np.linalg.solve(result.covariance, e)))
        errors.append(float(np.linalg.norm(e[:3])))
    return np.array(nees), np.array(errors)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=40, help="seeds per number of views (default 40)")
    parser.add_argument("--views", type=int, nargs="+", default=[6, 8, 12, 17], help="numbers of views")
    parser.add_argument(
        "--robot-factor", type=float, default=1.0, help="flange pose noise over the declared (default 1)"
    )
    parser.add_argument("--method", default=DEFAULT_METHOD, help=f"method (default {DEFAULT_METHOD})")
    args = parser.parse_args(argv)
    for views in args.views:
        nees, errors = nees_by_views(args.method, args.seeds, views, args.robot_factor)
        print(
            f"{args.method}, {views} views, flange noise {args.robot_factor:g}x declared, "
            f"{args.seeds} seeds: mean NEES {nees.mean():.2f}, median {np.median(nees):.2f}, "
            f"{100 * np.mean(nees > NEES_95_LINE):.0f} % above {NEES_95_LINE}; "
            f"median error {1e3 * np.median(errors):.3f} mm",
            flush=True,
        )


if __name__ == "__main__":
    main()
