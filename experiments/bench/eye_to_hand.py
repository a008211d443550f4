"""Benchmark: the eye-to-hand set-up (the camera fixed, the board on the flange).

Two parts:

- ``acceptance SWEEP_DIR``: a sweep's rows (models/sweeps/eye_to_hand*.toml) per set-up and method:
  median error, RMS error over the Cramer-Rao bound, mean NEES with the 95 % band of the mean of that
  many chi-square(6) values, and the median against the best OpenCV method's.
- ``noise-model``: why the robot's pose noise is kept in the reported pose's frames
  (hec.estimator.solve.setup_roles): measurement-fidelity eye-to-hand trials solved exactly, and
  naively (the poses inverted and the declared per-axis noise put on the inverted pose), with the
  declared noise, RMS error over the bound and mean NEES of each.

    .venv/bin/python -m hec.bench.eye_to_hand acceptance DIR
    .venv/bin/python -m hec.bench.eye_to_hand noise-model [--trials 200] [--rotation-sigma-deg 0.05]
    .venv/bin/python -m hec.bench.eye_to_hand page --measurements DIR --ideal DIR --realistic DIR --page F.md
"""

from __future__ import annotations

import argparse
import copy
import csv
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.lie import pose_minus, pose_nees
from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import eye_to_hand_waypoints
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.methods import solve
from hec.estimator.solve.observability import observability
from hec.estimator.solve.problem import build_problem
from hec.sim.scenario import load_scenario
from hec.support.results_page import markdown_table, write_results_page


def nees_band(count: int, dof: int = 6) -> tuple[float, float]:
    """The 95 % band of the mean of count chi-square(dof) values."""
    lo, hi = chi2.ppf([0.025, 0.975], dof * count) / count
    return float(lo), float(hi)


ACCEPTANCE_HEADER = (
    "setup", "method", "trials ok", "median mm", "median deg", "RMS / CRB mm", "RMS / CRB deg", "mean NEES",
    "NEES 95 % band", "median / best OpenCV",
)  # fmt: skip


def acceptance(rows_csv: Path) -> list[list[str]]:
    """The acceptance table's rows (ACCEPTANCE_HEADER) of a sweep's rows.csv, per set-up and method."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for row in csv.DictReader(rows_csv.open()):
        if row["status"] == "ok":
            groups.setdefault((row.get("setup", EYE_IN_HAND), row["method"]), []).append(row)
    table = []
    for (setup, method), rows in groups.items():

        def column(name: str, rows: list[dict] = rows) -> np.ndarray:
            return np.array([float(r[name]) for r in rows])

        def ratio(error: str, bound: str) -> str:
            return f"{np.sqrt(np.mean(column(error) ** 2) / np.mean(column(bound) ** 2)):.3f}"

        opencv = [
            float(np.median([float(r["error_translation_mm"]) for r in g]))
            for (s, m), g in groups.items()
            if s == setup and m.startswith("opencv-")
        ]
        median = float(np.median(column("error_translation_mm")))
        nees = column("nees")
        nees = nees[np.isfinite(nees)]
        band = "[{:.2f}, {:.2f}]".format(*nees_band(len(nees))) if len(nees) else "-"
        table.append(
            [
                setup,
                method,
                str(len(rows)),
                f"{median:.3f}",
                f"{np.median(column('error_rotation_deg')):.4f}",
                ratio("error_translation_mm", "crb_translation_mm"),
                ratio("error_rotation_deg", "crb_rotation_deg"),
                f"{nees.mean():.2f}" if len(nees) else "-",
                band,
                f"{median / min(opencv):.2f}" if opencv and not method.startswith("opencv-") else "-",
            ]
        )
    return table


def text_table(header: tuple[str, ...], rows: list[list[str]]) -> list[str]:
    """Rows as aligned text lines under their header."""
    widths = [max(len(c) for c in column) for column in zip(header, *rows, strict=True)]
    return ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in (header, *rows)]


def noise_model(trials: int, rotation_sigma_deg: float, method: str = "ekf") -> list[str]:
    """The exact and the naive eye-to-hand noise model on the same trials (module doc)."""
    scenario = load_scenario("eye_to_hand")
    board, intrinsics = scenario.board_definition(), scenario.camera.intrinsics()
    T_base_cam, T_flange_board = scenario.stand.transform(), scenario.board_mount.transform()
    flange = [w.T_base_flange for w in eye_to_hand_waypoints(T_base_cam, T_flange_board, 0.45)]
    noise = SyntheticNoise(robot=RobotPoseNoise(1e-4, float(np.radians(rotation_sigma_deg))))
    options = MethodOptions(learn_noise=False)  # the declared noise: the model alone
    results: dict[str, list[tuple[np.ndarray, float]]] = {"exact": [], "naive": []}
    bound = None
    for t in range(trials):
        rng = np.random.default_rng([45, t])
        observations = synthetic_observations(
            board, intrinsics, T_base_cam, T_flange_board, flange, noise, rng, setup=EYE_TO_HAND
        )
        exact = build_problem(observations, board, intrinsics, noise.robot, setup=EYE_TO_HAND)
        if bound is None:
            bound = observability(exact, HandEyeState(T_base_cam, T_base_board=T_flange_board)).crb_covariance
        inverted = copy.deepcopy(observations)
        for obs in inverted:
            obs.T_base_flange = invert(obs.T_base_flange)
        naive = build_problem(inverted, board, intrinsics, noise.robot, setup=EYE_IN_HAND)
        for name, problem in (("exact", exact), ("naive", naive)):
            result = solve(method, problem, options, observations)
            error = pose_minus(result.T_flange_cam, T_base_cam)
            results[name].append((error, pose_nees(result.T_flange_cam, T_base_cam, result.covariance)))
    bound_mm = 1e3 * np.sqrt(np.trace(bound[:3, :3]))
    bound_deg = np.degrees(np.sqrt(np.trace(bound[3:, 3:])))
    lo, hi = nees_band(trials)
    lines = [
        f"{trials} trials, robot pose noise 0.1 mm per base axis, {rotation_sigma_deg:g} deg per flange axis "
        f"(declared), {method}; Cramer-Rao bound {bound_mm:.3f} mm, {bound_deg:.4f} deg; NEES band "
        f"[{lo:.2f}, {hi:.2f}]"
    ]
    for name, rows in results.items():
        E = np.array([e for e, _ in rows])
        rms_mm = 1e3 * np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1)))
        rms_deg = np.degrees(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, axis=1))))
        lines.append(
            f"  {name:6s} RMS {rms_mm:.3f} mm ({rms_mm / bound_mm:.2f}x bound), {rms_deg:.4f} deg "
            f"({rms_deg / bound_deg:.2f}x), mean NEES {np.mean([n for _, n in rows]):.2f}"
        )
    return lines


PAGE_TEXT = (
    "Both set-ups side by side, at measurement fidelity (`hec sweep models/sweeps/eye_to_hand.toml`: "
    "the same noise, the same views of the board seen from the camera, paired trials) and rendered "
    "(`models/sweeps/eye_to_hand_render.toml`, the ideal eye-to-hand cell, and "
    "`models/sweeps/eye_to_hand_realistic.toml`, every model error of a real cell on). The "
    "Cramer-Rao bound is the declared model's: in the realistic cell the model errors (the arm's "
    "kinematics above all) are not in it. The last column is the median translation error over the "
    "best OpenCV method's."
)


def write_page(path: Path, command: str, sweeps: list[tuple[str, Path]], noise_lines: list[str]) -> Path:
    """The results page: each sweep's acceptance table under its title, then the noise-model check."""
    body = [PAGE_TEXT]
    for title, folder in sweeps:
        body += [f"## {title}", markdown_table(ACCEPTANCE_HEADER, acceptance(folder / "rows.csv"))]
    body += ["## The robot pose noise under the swapped roles", "```\n" + "\n".join(noise_lines) + "\n```"]
    return write_results_page(path, "Eye-to-hand against eye-in-hand", command, body)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="part", required=True)
    a = sub.add_parser("acceptance", help="the acceptance table of a sweep's rows")
    a.add_argument("sweep", type=Path, help="a hec sweep --out folder")
    p = sub.add_parser("page", help="write the results page from the three sweeps and the noise-model check")
    p.add_argument("--measurements", type=Path, required=True, help="sweep of models/sweeps/eye_to_hand.toml")
    p.add_argument("--ideal", type=Path, required=True, help="sweep of models/sweeps/eye_to_hand_render.toml")
    p.add_argument("--realistic", type=Path, required=True, help="sweep of eye_to_hand_realistic.toml")
    p.add_argument("--trials", type=int, default=200, help="noise-model trials")
    p.add_argument("--page", type=Path, required=True, help="the page to write")
    n = sub.add_parser("noise-model", help="exact against naive robot pose noise, eye-to-hand")
    n.add_argument("--trials", type=int, default=200)
    n.add_argument("--rotation-sigma-deg", type=float, default=0.05)
    n.add_argument("--method", default="ekf")
    args = parser.parse_args(argv)
    if args.part == "acceptance":
        lines = text_table(ACCEPTANCE_HEADER, acceptance(args.sweep / "rows.csv"))
    elif args.part == "noise-model":
        lines = noise_model(args.trials, args.rotation_sigma_deg, args.method)
    else:
        sweeps = [
            ("Measurement fidelity, both set-ups", args.measurements),
            ("Rendered, the ideal eye-to-hand cell", args.ideal),
            ("Rendered, the realistic eye-to-hand cell", args.realistic),
        ]
        noise = noise_model(args.trials, 0.05)
        command = "python -m hec.bench.eye_to_hand " + " ".join(argv if argv is not None else sys.argv[1:])
        lines = [f"wrote {write_page(args.page, command, sweeps, noise)}"]
    print("\n".join(lines))


if __name__ == "__main__":
    main()
