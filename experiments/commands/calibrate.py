"""`hec calibrate`: estimate T_flange_cam from a dataset with one method or all of them, and report
(the report's text and JSON forms are in hec.calibration.report)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hec.calibration.calibration_json import (
    CalibrationContext,
    calibration_context,
    frame_notes,
    robot_noise_source,
)
from hec.calibration.comparison import format_comparison
from hec.calibration.loo import (
    BUDGET_S,
)
from hec.calibration.report import (
    MethodFailure,
    Result,
    calibration_to_dict,
    check_json_path,
    format_calibration,
    result_to_dict,
    write_json,
)
from hec.calibration.run import check_poses_fit, run_methods, without_depth
from hec.calibration.summary import format_summary
from hec.estimator.common.files import refuse_writing_over_inputs
from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.io.calibration_file import (
    covariance_field,
    pose_field,
)
from hec.estimator.io.dataset import dataset_inputs, load_dataset
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.batch import one_blas_thread
from hec.estimator.solve.calibration import MethodOptions, Prior
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS
from hec.estimator.solve.problem import (
    CalibrationInputError,
    CalibrationProblem,
    dataset_problem,
    dataset_robot_noise,
)
from hec.support.detection import cached_or_detected

ALL_METHODS = "all"
# An imported dataset fitted worse than this (RMS pixel residual) gets its pose convention checked.
POOR_FIT_PX = 2.0


class PriorFileError(ValueError):
    """A --prior file is missing, not JSON, or has a bad field."""


@dataclass(frozen=True)
class CalibrateSettings:
    """What `hec calibrate` was asked for. method: a name in METHODS or 'all'.
    robot_sigma_mm / robot_sigma_deg: override the dataset's robot pose noise when given.
    loo: leave-one-frame-out cross-validation of the methods run (one calibration per frame), of those
    whose folds fit in hec.calibration.loo.BUDGET_S unless loo_all. verbose: the full report of one
    method instead of its verdict and findings (hec.calibration.summary)."""

    method: str = DEFAULT_METHOD
    map_model: str = "board"
    estimate_depth_scale: bool = False
    use_depth: bool = True
    prior_file: Path | None = None
    robot_sigma_mm: float | None = None
    robot_sigma_deg: float | None = None
    loo: bool = True
    loo_all: bool = False
    verbose: bool = False

    @property
    def loo_budget_s(self) -> float | None:
        return None if self.loo_all else BUDGET_S

    @property
    def methods(self) -> list[str]:
        return list(METHODS) if self.method == ALL_METHODS else [self.method]


# ---------------------------------------------------------------- inputs


def load_prior(path: Path) -> Prior:
    """A Prior from a JSON object with 'T_flange_cam' (4x4, metres) and optional 'covariance'
    (6x6, the COVARIANCE_CONVENTION; null or absent: the wide default), such as a --json output."""
    data = read_json_object(path, PriorFileError)
    if "T_flange_cam" not in data:
        hint = (
            "; a --method all output holds one per entry of 'results', copy one out"
            if "results" in data
            else ""
        )
        raise PriorFileError(f"{path}: missing field 'T_flange_cam' (a 4x4 matrix, metres){hint}")
    T = pose_field(data, "T_flange_cam", path, PriorFileError)
    if data.get("covariance") is None:
        return Prior(T)
    return Prior(T, covariance_field(data, "covariance", path, PriorFileError))


def robot_noise(
    dataset: Dataset, sigma_mm: float | None, sigma_deg: float | None
) -> tuple[RobotPoseNoise, str]:
    """The dataset's robot pose noise with the command-line overrides, and where it came from."""
    base = dataset_robot_noise(dataset)
    source = robot_noise_source(dataset)
    if sigma_mm is None and sigma_deg is None:
        return base, source
    noise = RobotPoseNoise(
        base.translation_sigma_m if sigma_mm is None else sigma_mm / 1000.0,
        base.rotation_sigma_rad if sigma_deg is None else float(np.radians(sigma_deg)),
    )
    return noise, "command line" if None not in (sigma_mm, sigma_deg) else f"command line and {source}"


def method_options(settings: CalibrateSettings) -> MethodOptions:
    prior = None if settings.prior_file is None else load_prior(settings.prior_file)
    return MethodOptions(
        prior=prior, map_model=settings.map_model, estimate_depth_scale=settings.estimate_depth_scale
    )


# ---------------------------------------------------------------- the command


def _print_header(
    dataset: Dataset,
    problem: CalibrationProblem,
    observations: list[FrameObservations],
    settings: CalibrateSettings,
    source: str,
    noise_source: str,
) -> None:
    n = problem.robot_noise
    inputs = "pixels and depth" if settings.use_depth else "pixels only"
    print(f"dataset: {dataset.root} ({len(dataset)} frames; observations {source})")
    if dataset.metadata.get("pose_frame") == "tcp":
        print(
            "robot poses: the controller's TCP, not the flange (dataset.json 'pose_frame'): the "
            "T_flange_cam below is the camera in that TCP frame"
        )
    print(
        f"problem: {len(problem.frames)} frames, {problem.observation_count} marker observations of "
        f"{len(problem.marker_ids)} markers ({inputs}; map: {settings.map_model}); robot pose noise "
        f"{1e3 * n.translation_sigma_m:.3f} mm, {np.degrees(n.rotation_sigma_rad):.4f} deg ({noise_source})"
    )
    for line in problem.rejected:
        print(f"  left out: {line}")
    for line in frame_notes(observations):
        print(f"  warning: {line}")


def _note_ignored_options(settings: CalibrateSettings) -> None:
    """Say so when the one method asked for is an OpenCV baseline that ignores the options given."""
    if not settings.method.startswith("opencv-"):
        return
    ignored = [
        option
        for option, given in (
            ("--prior", settings.prior_file is not None),
            ("--map landmarks", settings.map_model != "board"),
            ("--depth-scale", settings.estimate_depth_scale),
        )
        if given
    ]
    if ignored:
        print(f"note: {settings.method} uses only the pixels; ignoring {', '.join(ignored)}", file=sys.stderr)


def calibrate_dataset(
    dataset_path: Path,
    settings: CalibrateSettings,
    json_out: Path | None = None,
    quiet: bool = False,
    observations: list[FrameObservations] | None = None,
    report_dir: Path | None = None,
) -> list[Result]:
    """`hec calibrate`: observations (given, cached or detected now), the problem, the methods, the
    printed report, the JSON and, with report_dir, the HTML report (hec.calibration.html_report).
    Raises CalibrationInputError and the other input errors."""
    if json_out is not None:
        check_json_path(json_out)
        refuse_writing_over_inputs(json_out, dataset_inputs(dataset_path), "--json")
    if report_dir is not None:
        from hec.calibration.html_report import check_report_dir

        check_report_dir(report_dir)
    dataset = load_dataset(dataset_path)
    options = method_options(settings)
    noise, noise_source = robot_noise(dataset, settings.robot_sigma_mm, settings.robot_sigma_deg)
    if dataset.metadata.get("pose_pairs_file"):
        from hec.calibration.pose_pairs import calibrate_pose_pairs

        return calibrate_pose_pairs(dataset, settings.method, options, noise, noise_source, json_out)
    source = "as just detected"
    if observations is None:
        observations, source = cached_or_detected(dataset, quiet)
    if not settings.use_depth:
        observations = without_depth(observations)
    problem = dataset_problem(dataset, observations, noise, settings.use_depth)
    _note_ignored_options(settings)
    check_poses_fit(dataset, problem)
    try:
        with one_blas_thread():  # small matrices: BLAS threads cost more than they give (hec.bench.calibrate)
            results = run_methods(
                settings.methods, problem, options, observations, quiet, settings.loo, settings.loo_budget_s
            )
    except CalibrationInputError as exc:
        for line in convention_lines(dataset, problem, [MethodFailure(settings.method, str(exc))]):
            print(line)
        raise
    T_true = None if dataset.ground_truth is None else dataset.ground_truth.hand_eye
    if settings.verbose or settings.method == ALL_METHODS:
        _print_header(dataset, problem, observations, settings, source, noise_source)
    if settings.method == ALL_METHODS:
        print(format_comparison(results, T_true))
    elif settings.verbose:
        print(format_calibration(results[0], T_true))
    else:
        print(format_summary(results[0], T_true))
    for line in convention_lines(dataset, problem, results):
        print(line)
    if json_out is not None:
        context = CalibrationContext(
            noise_source,
            settings.use_depth,
            settings.map_model,
            settings.estimate_depth_scale,
            settings.prior_file,
            settings.loo,
            settings.loo_budget_s,
        )
        data = calibration_context(dataset, problem, context) | {"frame_notes": frame_notes(observations)}
        if settings.method == ALL_METHODS:
            data["results"] = [result_to_dict(r, T_true) for r in results]
        else:
            data |= calibration_to_dict(results[0], T_true)
        print(f"wrote {write_json(json_out, data)}")
    if report_dir is not None:
        _write_report(report_dir, dataset, problem, results, settings, T_true)
    return results


def _write_report(
    report_dir: Path,
    dataset: Dataset,
    problem: CalibrationProblem,
    results: list[Result],
    settings: CalibrateSettings,
    T_true: np.ndarray | None,
) -> None:
    """The HTML report of the default method's calibration (of the first that calibrated if it did not)."""
    from hec.calibration.html_report import write_calibration_report
    from hec.estimator.solve.calibration import Calibration

    calibrated = [r for r in results if isinstance(r, Calibration)]
    if not calibrated:
        return
    cal = next((r for r in calibrated if r.method == DEFAULT_METHOD), calibrated[0])
    comparison = format_comparison(results, T_true) if settings.method == ALL_METHODS else None
    print(f"wrote {write_calibration_report(report_dir, dataset, problem, cal, T_true, comparison)}")


def convention_lines(dataset: Dataset, problem: CalibrationProblem, results: list[Result]) -> list[str]:
    """For an imported dataset whose poses a method fits poorly (RMS over POOR_FIT_PX), or that no
    method calibrated, the convention check of its pose numbers and the board layout check
    (hec.estimator.io.convention_check): the lines to print."""
    from hec.estimator.io.convention_check import check_board_layout, check_pose_convention
    from hec.estimator.io.pose_file import PoseConvention

    record = dataset.metadata.get("provenance") or {}
    done = [r for r in results if not isinstance(r, MethodFailure)]
    poor = [r for r in done if r.residual_rms_px > POOR_FIT_PX] or ([] if done else results)
    if "pose_values" not in record or not poor:
        return []
    stated = PoseConvention(**record["pose_convention"])
    report = check_pose_convention(problem, np.array(record["pose_values"]), stated)
    why = (
        f"{poor[0].method} failed"
        if isinstance(poor[0], MethodFailure)
        else f"{poor[0].method} leaves {poor[0].residual_rms_px:.3g} px RMS"
    )
    return [
        f"convention check ({why}, a poor fit): {report.message}",
        f"board check: {check_board_layout(problem)}",
    ]


def run(args: argparse.Namespace) -> int:
    """`hec calibrate` from parsed arguments: 0 when a method calibrated, 2 when none could."""
    from hec.estimator.solve.calibration import Calibration

    settings = CalibrateSettings(
        method=args.method,
        map_model=args.map,
        estimate_depth_scale=args.depth_scale,
        use_depth=not args.no_depth,
        prior_file=args.prior,
        robot_sigma_mm=args.robot_sigma_mm,
        robot_sigma_deg=args.robot_sigma_deg,
        loo=not args.no_loo,
        loo_all=args.loo_all,
        verbose=args.verbose,
    )
    results = calibrate_dataset(args.dataset, settings, args.json, args.quiet, report_dir=args.report)
    if not any(isinstance(r, Calibration) for r in results):
        print("hec: error: no method could calibrate from these observations", file=sys.stderr)
        return 2
    return 0
