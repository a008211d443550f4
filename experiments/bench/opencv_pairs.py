"""Benchmark: pose pairs drawn the way OpenCV's own hand-eye test draws them, against the truth.

OpenCV checks cv2.calibrateHandEye (modules/calib3d/test/test_calibration_hand_eye.cpp) on random
sets of 10 pose pairs, once exact and once with noise. This benchmark draws such sets with its own
generator (numpy, from the test's description):

- every pose has a rotation vector theta * a, a's components uniform in [-1, 1] (not normalised),
  theta uniform in a range with a random sign, and a translation whose components are uniform in
  a range, each with a random sign;
- the mount T_flange_cam: theta 10-50 deg, translations 0.05-0.5 m; the board T_base_board: theta
  5-85 deg, 0.5-3.5 m; each flange pose T_base_flange: theta 5-45 deg, 0.5-1.5 m;
- T_cam_board = inv(T_flange_cam) inv(T_base_flange) T_base_board; with noise, its rotation vector
  gets N(0, 0.002 rad) and its translation N(0, 5 mm) per component.

The test also draws noise for the flange poses (N(0, 0.001) on the rotation vector and N(0, 1 mm)
on the translation) but adds it to a copy that is not passed on, so its methods see exact flange
poses; that is the default here, and --robot-noise adds it for real. The test's thresholds are on
the norm of the difference of the rotation vectors (1e-8 exact; with noise 0.02 rad for Tsai, Park
and Horaud, 0.01 rad for Andreff and Daniilidis) and of the translations (1e-8 m exact, 0.05 m with
noise); methods the test does not cover are held to its strictest ones.

Every OpenCV method and hec's pose-pair model (batch, ekf, iekf; the board pose's noise learned, the
flange pose's noise declared as what was added) calibrate each set. Prints per method the median
and 95th percentile of the translation and rotation errors of T_flange_cam, the share of sets within
the test's thresholds, hec's mean NEES (6 when its covariance is honest) with the share above
chi2(6)'s 95 % line (12.59; 5 % when honest), and how many results carried each kind of warning.

    .venv/bin/python -m hec.bench.opencv_pairs [--trials 200] [--pairs 10] [--robot-noise] [--page PATH.md]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.lie import NEES_95_LINE, pose_nees
from hec.estimator.geometry.transforms import invert, make_transform
from hec.estimator.observe.pose_pairs import PosePair
from hec.estimator.solve.baselines import OPENCV_METHODS
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.pose_pair_methods import POSE_PAIR_MODEL_METHODS, solve_pose_pairs
from hec.support.results_page import markdown_table, write_results_page

METHODS = (*POSE_PAIR_MODEL_METHODS, *OPENCV_METHODS)
# The test's noise: on the board pose's rotation vector (rad) and translation (m), per component; on
# the flange pose's (drawn but not passed on by the test; --robot-noise).
BOARD_NOISE = (0.002, 0.005)
FLANGE_NOISE = (0.001, 0.001)
# The test's thresholds with noise (rotation-vector difference rad, translation m); exact: 1e-8 both.
NOISY_THRESHOLDS = {
    "opencv-tsai": (0.02, 0.05),
    "opencv-park": (0.02, 0.05),
    "opencv-horaud": (0.02, 0.05),
    "opencv-andreff": (0.01, 0.05),
    "opencv-daniilidis": (0.01, 0.05),
}
STRICTEST = (0.01, 0.05)
EXACT_THRESHOLD = 1e-8
# Kinds of warning, by a phrase of their text.
WARNING_KINDS = {
    "tracking bias": "tracking poses' translations read",
    "scale undetermined": "cannot measure a scale common",
    "misfit": "does not fit its data",
    "exact fit": "fit each other exactly",
    "noise learned": "noise was learned",
    "zero noise": "0.000",
}


def random_pose(
    rng: np.random.Generator, theta_deg: tuple[float, float], translation_m: tuple[float, float]
) -> np.ndarray:
    """(4, 4) a pose drawn as the test draws one (module doc): rotation vector theta * a, translation
    components in translation_m, each with a random sign."""
    axis = rng.uniform(-1.0, 1.0, 3)
    theta = np.radians(rng.uniform(*theta_deg)) * rng.choice((-1.0, 1.0))
    t = rng.uniform(*translation_m, 3) * rng.choice((-1.0, 1.0), 3)
    return make_transform(Rotation.from_rotvec(theta * axis).as_matrix(), t)


def with_rotvec_noise(rng: np.random.Generator, T: np.ndarray, sigmas: tuple[float, float]) -> np.ndarray:
    """(4, 4) T with N(0, sigmas[0]) added to each component of its rotation vector and N(0, sigmas[1])
    to each of its translation (metres)."""
    rotvec = Rotation.from_matrix(T[:3, :3]).as_rotvec() + rng.normal(0.0, sigmas[0], 3)
    return make_transform(Rotation.from_rotvec(rotvec).as_matrix(), T[:3, 3] + rng.normal(0.0, sigmas[1], 3))


def opencv_test_pairs(
    rng: np.random.Generator, count: int, noisy: bool, robot_noise: bool = False
) -> tuple[list[PosePair], np.ndarray]:
    """count pose pairs drawn as the test draws them (module doc), with its noise on the board poses
    when noisy (and on the flange poses when robot_noise too), and the true (4, 4) T_flange_cam."""
    T_flange_cam = random_pose(rng, (10.0, 50.0), (0.05, 0.5))
    T_base_board = random_pose(rng, (5.0, 85.0), (0.5, 3.5))
    pairs = []
    for i in range(count):
        T_base_flange = random_pose(rng, (5.0, 45.0), (0.5, 1.5))
        T_cam_board = invert(T_flange_cam) @ invert(T_base_flange) @ T_base_board
        if noisy:
            T_cam_board = with_rotvec_noise(rng, T_cam_board, BOARD_NOISE)
            if robot_noise:
                T_base_flange = with_rotvec_noise(rng, T_base_flange, FLANGE_NOISE)
        pairs.append(PosePair(i, T_base_flange, T_cam_board))
    return pairs, T_flange_cam


def rotvec_errors(T_estimate: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """The test's errors: the norm of the difference of the rotation vectors (rad) and of the
    translations (m)."""
    rotvec = Rotation.from_matrix(T_estimate[:3, :3]).as_rotvec()
    rotvec_true = Rotation.from_matrix(T_true[:3, :3]).as_rotvec()
    return float(np.linalg.norm(rotvec - rotvec_true)), float(
        np.linalg.norm(T_estimate[:3, 3] - T_true[:3, 3])
    )


@dataclass
class MethodRecord:
    """One method's figures over the trials: errors (translation m, rotation rad as the test
    measures them), NEES, within the thresholds, warning kinds counted, failures."""

    translation_m: list[float] = field(default_factory=list)
    rotation_rad: list[float] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)
    passed: int = 0
    warnings: dict[str, int] = field(default_factory=lambda: dict.fromkeys(WARNING_KINDS, 0))
    failures: list[str] = field(default_factory=list)


def run(trials: int, pairs: int, noisy: bool, robot_noise: bool, seed: int = 0) -> dict[str, MethodRecord]:
    """method -> its record over trials sets of pairs pairs (seeded)."""
    rng = np.random.default_rng(seed)
    declared = (
        RobotPoseNoise(FLANGE_NOISE[1], FLANGE_NOISE[0])
        if noisy and robot_noise
        else RobotPoseNoise(0.0, 0.0)
    )
    records = {m: MethodRecord() for m in METHODS}
    for _ in range(trials):
        data, T_true = opencv_test_pairs(rng, pairs, noisy, robot_noise)
        for method in METHODS:
            record = records[method]
            try:
                result = solve_pose_pairs(method, data, MethodOptions(), declared)
            except Exception as exc:  # noqa: BLE001  (a method's failure is its entry)
                record.failures.append(f"{type(exc).__name__}: {exc}")
                continue
            rotation, translation = rotvec_errors(result.T_flange_cam, T_true)
            record.rotation_rad.append(rotation)
            record.translation_m.append(translation)
            limits = NOISY_THRESHOLDS.get(method, STRICTEST) if noisy else (EXACT_THRESHOLD, EXACT_THRESHOLD)
            record.passed += rotation <= limits[0] and translation <= limits[1]
            if result.covariance is not None and noisy:
                record.nees.append(pose_nees(result.T_flange_cam, T_true, result.covariance))
            for kind, phrase in WARNING_KINDS.items():
                record.warnings[kind] += any(phrase in w for w in result.warnings)
    return records


def rows(records: dict[str, MethodRecord], trials: int, noisy: bool) -> list[list[str]]:
    """One table row per method (see HEADER)."""
    out = []
    unit = 1e3 if noisy else 1.0
    for method, r in records.items():
        if not r.translation_m:
            out.append([method, "failed: " + r.failures[0], *[""] * (len(HEADER) - 2)])
            continue
        t, rot = (
            unit * np.array(r.translation_m),
            np.degrees(r.rotation_rad) if noisy else np.array(r.rotation_rad),
        )
        nees = np.array(r.nees)
        said = ", ".join(f"{kind} {n}" for kind, n in r.warnings.items() if n) or "none"
        out.append(
            [
                method,
                f"{np.median(t):.3g} / {np.percentile(t, 95):.3g}",
                f"{np.median(rot):.3g} / {np.percentile(rot, 95):.3g}",
                f"{r.passed}/{trials}",
                f"{nees.mean():.2f} ({100 * np.mean(nees > NEES_95_LINE):.0f} %)" if nees.size else "-",
                said + (f"; {len(r.failures)} failed" if r.failures else ""),
            ]
        )
    return out


HEADER = [
    "method",
    "translation median / p95",
    "rotation median / p95",
    "within the test's thresholds",
    "mean NEES (share > 12.59)",
    "results with a warning",
]


def section(records: dict[str, MethodRecord], trials: int, pairs: int, noisy: bool, robot_noise: bool) -> str:
    """The Markdown heading and table of one case."""
    if noisy:
        what = "with the test's noise" + (" (also on the flange poses)" if robot_noise else "")
        units = "errors in mm and deg"
    else:
        what, units = "exact", "errors in m and rad (the test's threshold 1e-8)"
    head = f"## {pairs} pairs, {what}: {trials} sets, {units}"
    return head + "\n\n" + markdown_table(HEADER, rows(records, trials, noisy))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--trials", type=int, default=200, help="sets of pairs per case (default 200)")
    parser.add_argument("--pairs", type=int, default=10, help="pairs per set (default 10, the test's)")
    parser.add_argument(
        "--robot-noise", action="store_true", help="also add the test's flange pose noise (it drops it)"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--page", type=Path, help="also write the tables as this Markdown page")
    args = parser.parse_args(argv)
    sections = []
    for noisy in (False, True):
        records = run(args.trials, args.pairs, noisy, args.robot_noise, args.seed)
        sections.append(section(records, args.trials, args.pairs, noisy, args.robot_noise))
        print(sections[-1] + "\n", flush=True)
    if args.page:
        intro = (
            f"Sets of {args.pairs} pose pairs drawn the way OpenCV's hand-eye test"
            " (modules/calib3d/test/test_calibration_hand_eye.cpp) draws them: random mounts, boards and"
            " flange poses metres apart, and its noise on the board poses (the flange noise it draws is"
            " never passed on" + (", added here" if args.robot_noise else ", nor here") + "). hec's"
            " pose-pair model learns the board pose noise from each set. Errors of T_flange_cam as the test"
            " measures them (the difference of the rotation vectors, of the translations); NEES about 6 and"
            " 5 % above 12.59 when the covariance is honest; warnings counted per kind over the sets."
        )
        flags = f"--trials {args.trials} --pairs {args.pairs}" + (
            " --robot-noise" if args.robot_noise else ""
        )
        if args.seed:
            flags += f" --seed {args.seed}"
        command = f"python -m hec.bench.opencv_pairs {flags} --page {args.page}"
        write_results_page(args.page, "Pose pairs as OpenCV's test draws them", command, [intro, *sections])


if __name__ == "__main__":
    main()
