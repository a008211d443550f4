"""Benchmark: calibrating from pose pairs (no images), as easy_handeye2 users do, against the truth.

Each trial renders the default (or another) scenario, detects the board, and turns each frame into a
pose pair: the reported T_base_flange and T_cam_board solved from the frame's corners by PnP (what
a pose-pair tool gives, without covariance). Every OpenCV method and hec's pose-pair model (batch,
ekf, iekf; the board pose's noise learned) then calibrate from the pairs alone. Prints per method
the median and worst translation and rotation error of T_flange_cam and hec's mean NEES (6 when
its covariance is honest), and whether hec's batch is at least as accurate as the best OpenCV
method (median translation).

    .venv/bin/python -m hec.bench.pose_pairs [--seeds 5] [--scenario default realistic] [--page PATH.md]

--page also writes the tables as a documentation page.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
from pathlib import Path

import numpy as np

import hec.sim as sim  # noqa: F401  (selects the GL backend before mujoco loads)
from hec.estimator.geometry.lie import pose_nees
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.pose_pairs import PosePair
from hec.estimator.solve.baselines import OPENCV_METHODS
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.initialise import board_pose_pnp
from hec.estimator.solve.pose_pair_methods import POSE_PAIR_MODEL_METHODS, solve_pose_pairs
from hec.estimator.solve.problem import build_problem, dataset_robot_noise
from hec.estimator.targets.qr import DetectorSettings
from hec.sim.scenario import load_scenario
from hec.sim.simulate import simulate_in_memory
from hec.support.detection import detect_dataset
from hec.support.results_page import write_results_page

METHODS = (*POSE_PAIR_MODEL_METHODS, *OPENCV_METHODS)


def rendered_pairs(dataset: Dataset) -> list[PosePair]:
    """Per usable frame of a rendered dataset: its reported flange pose and its PnP board pose."""
    observations, _ = detect_dataset(dataset, DetectorSettings(), quiet=True)
    problem = build_problem(observations, dataset.board, dataset.intrinsics, dataset_robot_noise(dataset))
    return [PosePair(f.frame, f.T_base_flange, board_pose_pnp(problem, f)) for f in problem.frames]


def trial(scenario: str | None, seed: int) -> dict[str, tuple[float, float, float] | str]:
    """method -> (translation mm, rotation deg, NEES) or the failure's message."""
    with contextlib.redirect_stderr(io.StringIO()):
        dataset = simulate_in_memory(load_scenario(scenario), seed, name=f"pose pairs {seed}")
    pairs = rendered_pairs(dataset)
    truth = dataset.ground_truth.T_flange_cam
    out: dict[str, tuple[float, float, float] | str] = {}
    for method in METHODS:
        try:
            result = solve_pose_pairs(method, pairs, MethodOptions(), dataset_robot_noise(dataset))
        except Exception as exc:  # noqa: BLE001  (a method's failure is its entry)
            out[method] = f"{type(exc).__name__}: {exc}"
            continue
        error_m, error_rad = pose_error(result.T_flange_cam, truth)
        nees = (
            math.nan
            if result.covariance is None
            else pose_nees(result.T_flange_cam, truth, result.covariance)
        )
        out[method] = (1e3 * error_m, math.degrees(error_rad), nees)
    return out


def table(trials: list[dict]) -> list[str]:
    """One line per method and the acceptance line."""
    lines, medians = [], {}
    for method in METHODS:
        ok = [t[method] for t in trials if isinstance(t[method], tuple)]
        if not ok:
            lines.append(f"  {method:18s} failed: {trials[0][method]}")
            continue
        mm, deg, nees = (np.array(v) for v in zip(*ok, strict=True))
        medians[method] = float(np.median(mm))
        lines.append(
            f"  {method:18s} translation median {np.median(mm):.3f} max {mm.max():.3f} mm, rotation median "
            f"{np.median(deg):.4f} max {deg.max():.4f} deg"
            + (f", NEES {np.mean(nees):.1f}" if np.isfinite(nees).all() else "")
            + (f" ({len(trials) - len(ok)} failed)" if len(ok) < len(trials) else "")
        )
    best = min((m for m in medians if m in OPENCV_METHODS), key=medians.get)
    verdict = "yes" if medians.get("batch", math.inf) <= medians[best] else "NO"
    lines.append(
        f"  batch at least as accurate as the best OpenCV method ({best}, {medians[best]:.3f} mm): {verdict}"
    )
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=5, help="trials per scenario (default 5)")
    parser.add_argument(
        "--scenario",
        nargs="+",
        default=["default"],
        help="scenario files or names in models/scenarios/ (default: the ideal cell, default)",
    )
    parser.add_argument("--page", type=Path, help="also write the tables as this Markdown page")
    args = parser.parse_args(argv)
    sections = []
    for scenario in args.scenario:
        trials = [trial(scenario, seed) for seed in range(args.seeds)]
        heading = f"pose pairs from the {scenario} scenario, {args.seeds} seeds:"
        print(heading)
        print("\n".join(table(trials)))
        sections += [f"## {scenario}", "```\n" + "\n".join(table(trials)) + "\n```"]
    if args.page:
        intro = (
            "Rendered frames turned into pose pairs (the reported flange pose and the board's PnP pose from"
            " the detected corners, no covariance, as easy_handeye2 records them), calibrated from the pairs"
            " alone by hec's pose-pair model and every OpenCV method; errors of T_flange_cam against the"
            f" truth over {args.seeds} seeds per scenario, and hec's mean NEES (about 6 when honest)."
        )
        command = f"python -m hec.bench.pose_pairs --seeds {args.seeds} --scenario {' '.join(args.scenario)}"
        write_results_page(args.page, "Pose pairs", f"{command} --page {args.page}", [intro, *sections])


if __name__ == "__main__":
    main()
