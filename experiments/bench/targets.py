"""Which target is best? Every board kind rendered on the same default scenario (trajectory, noise,
camera, board pose and sheet size), detected, graded against the truth and calibrated.

Per board: the share of fully visible markers found with the right ID, wrong IDs, corner RMS
error and mean normalised corner error (e^T C^-1 e / 2, 1 when the covariances are honest),
detection time per frame (including the depth fit), and per method the median and worst
translation and rotation error of T_flange_cam over the seeds with its mean pose NEES (6 when the
reported covariance is honest).

    .venv/bin/python -m hec.bench.targets [--seeds 3] [--boards NAME,...] [--scenario default realistic]
        [--page PATH.md]
    (default: every board in models/boards/, the ideal default cell; --page also writes the tables as
    a documentation page)

With --scenario, the cell's model errors apply to every board; a board printed as one pattern
(every kind but QR) gets no per-marker placement error (errors.board.marker_placement_sigma_m = 0),
the rest of the print error (scale, bend) as the scenario says.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import time
from pathlib import Path

import numpy as np

import hec.sim as sim  # noqa: F401  (selects the GL backend before mujoco loads)
from hec.estimator.common.models import models_dir
from hec.estimator.geometry.lie import pose_nees
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.io.board_file import find_board
from hec.estimator.io.tomlfile import read_toml
from hec.estimator.observe.grading import grade_observations
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import solve
from hec.estimator.solve.problem import dataset_problem
from hec.estimator.targets.qr import DetectorSettings
from hec.sim.scenario import Scenario, ScenarioError, resolve_scenario_path, scenario_from_dict
from hec.sim.simulate import simulate_in_memory
from hec.support.detection import detect_dataset
from hec.support.results_page import write_results_page

BOARDS = tuple(sorted(p.stem for p in (models_dir() / "boards").glob("*.json")))
METHODS = ("ekf", "batch", "opencv-park", "opencv-daniilidis")


def board_scenario(board: str, scenario: str | None = None) -> Scenario:
    """The scenario (a file or a name in models/scenarios/; None: the default) with this board (module
    doc: no per-marker placement error on a board printed as one pattern)."""
    path = resolve_scenario_path(scenario) if scenario is not None else None
    data = read_toml(path, ScenarioError, "scenario") if path is not None else {}
    data["board"] = {**data.get("board", {}), "definition": board}
    if not find_board(board).markers_placed_one_by_one and "board" in data.get("errors", {}):
        data["errors"]["board"]["marker_placement_sigma_m"] = 0.0
    return scenario_from_dict(
        data, source=f"bench {board} {scenario or 'default'}", base_dir=path.parent if path else Path(".")
    )


def board_trial(board: str, seed: int, scenario: str | None = None) -> dict:
    """Render the scenario (board_scenario) with this board, detect, grade and calibrate: the
    measurement summary (grading.MeasurementErrors.summary), ms_per_frame, frames, corner_noise (the
    learned floor, hec.estimator.observe.corner_noise.CornerNoise), and per method its
    (translation mm, rotation deg, pose NEES) or the failure's message."""
    scenario = board_scenario(board, scenario)
    with contextlib.redirect_stderr(io.StringIO()):
        dataset = simulate_in_memory(scenario, seed, name=f"{board} seed {seed}")
    start = time.perf_counter()
    observations, corner_noise = detect_dataset(dataset, DetectorSettings(), quiet=True)
    ms_per_frame = 1e3 * (time.perf_counter() - start) / len(dataset)
    truth = dataset.ground_truth
    result = grade_observations(observations, truth, dataset.board, dataset.intrinsics).summary()
    result |= {"ms_per_frame": ms_per_frame, "frames": len(dataset), "corner_noise": corner_noise}
    problem = dataset_problem(dataset, observations)
    for method in METHODS:
        try:
            calibration = solve(method, problem, MethodOptions(), observations)
        except Exception as exc:  # noqa: BLE001  (a method's failure is its entry)
            result[method] = f"{type(exc).__name__}: {exc}"
            continue
        error_m, error_rad = pose_error(calibration.T_flange_cam, truth.T_flange_cam)
        nees = math.nan
        if calibration.covariance is not None:
            nees = pose_nees(calibration.T_flange_cam, truth.T_flange_cam, calibration.covariance)
        result[method] = (1e3 * error_m, math.degrees(error_rad), nees)
    return result


def _table(board: str, trials: list[dict]) -> str:
    mean = {
        k: float(np.mean([t[k] for t in trials])) for k in ("corner_rms_px", "corner_nees", "ms_per_frame")
    }
    visible = sum(t["visible_markers"] for t in trials)
    found = sum(t["detected_visible"] for t in trials)
    lines = [
        f"{board}: {found}/{visible} fully visible markers found ({found / max(visible, 1):.1%}), "
        f"{sum(t['wrong_id'] for t in trials)} wrong IDs, corner RMS {mean['corner_rms_px']:.3f} px, "
        f"normalised corner error {mean['corner_nees']:.2f}, {mean['ms_per_frame']:.0f} ms/frame "
        f"({trials[0]['frames']} frames)"
    ]
    for method in METHODS:
        ok = [t[method] for t in trials if isinstance(t[method], tuple)]
        failed = [t[method] for t in trials if not isinstance(t[method], tuple)]
        if not ok:
            lines.append(f"  {method:18s} failed: {failed[0]}")
            continue
        mm, deg, nees = (np.array(v) for v in zip(*ok, strict=True))
        lines.append(
            f"  {method:18s} translation median {np.median(mm):.3f} max {mm.max():.3f} mm, rotation median "
            f"{np.median(deg):.4f} max {deg.max():.4f} deg"
            + (f", NEES {np.mean(nees[np.isfinite(nees)]):.1f}" if np.isfinite(nees).any() else "")
            + (f" ({len(failed)} failed: {failed[0]})" if failed else "")
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=3, help="seeds per board (default 3)")
    parser.add_argument("--boards", default=",".join(BOARDS), help="comma-separated board names")
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
        print(f"scenario {scenario}:")
        sections.append(f"## {scenario}")
        for board in args.boards.split(","):
            trials = [board_trial(board, seed, scenario) for seed in range(args.seeds)]
            table = _table(board, trials)
            print(table, flush=True)
            sections.append("```\n" + table.strip("\n") + "\n```")
    if args.page:
        intro = (
            "Every board kind on the same sheet and scenario (trajectory, noise, camera, board pose),"
            " rendered, detected, graded against the truth and calibrated: markers found, wrong IDs,"
            " corner RMS and normalised error (1 when the covariances are honest), detection time per"
            " frame, and per method the median and worst error of T_flange_cam over"
            f" {args.seeds} seeds with its mean NEES (6 when honest)."
        )
        command = (
            f"python -m hec.bench.targets --seeds {args.seeds} --boards {args.boards}"
            f" --scenario {' '.join(args.scenario)} --page {args.page}"
        )
        write_results_page(args.page, "Target kinds", command, [intro, *sections])


if __name__ == "__main__":
    main()
