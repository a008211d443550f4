"""Every calibration method behind one call, with the observability check added to each result."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.baselines import OPENCV_METHODS, opencv_calibrate
from hec.estimator.solve.batch import batch
from hec.estimator.solve.calibration import Calibration, MethodOptions, calibration_state, marker_residuals
from hec.estimator.solve.filters import run_filter
from hec.estimator.solve.fit_check import check_fit
from hec.estimator.solve.misfit import misfit_warning
from hec.estimator.solve.noise_learning import LearnedNoise, learn_noise
from hec.estimator.solve.noise_levels import scaled_problem
from hec.estimator.solve.observability import observability
from hec.estimator.solve.problem import MIN_FRAMES, CalibrationInputError, CalibrationProblem
from hec.estimator.solve.seed_ekf import check_depth, seed_ekf
from hec.estimator.solve.seed_ekf_check import check_assumptions
from hec.estimator.solve.ukf import ukf

Method = Callable[[CalibrationProblem, MethodOptions, list[FrameObservations]], Calibration]

METHODS: dict[str, Method] = {
    "seed-ekf": seed_ekf,
    "ekf": lambda problem, options, _: run_filter(problem, options, iterated=False),
    "iekf": lambda problem, options, _: run_filter(problem, options, iterated=True),
    "ukf": lambda problem, options, _: ukf(problem, options),
    "batch": lambda problem, options, _: batch(problem, options),
    **{
        name: (lambda problem, options, _, name=name: opencv_calibrate(problem, options, name))
        for name in OPENCV_METHODS
    },
}
# The methods that model the noise (and so learn it with options.learn_noise); the OpenCV
# baselines weigh every view alike.
NOISE_MODEL_METHODS = ("seed-ekf", "ekf", "iekf", "ukf", "batch")
# Corners that miss by this much (RMS) at the learned optimum do not come from this board and camera.
MAX_CORNER_RMS_PX = 25.0
# More than this share of observations rejected against the declared noise gets a warning.
MAX_REJECTED_FRACTION = 0.10


def needs_learned_noise(name: str, options: MethodOptions) -> bool:
    return options.learn_noise and name in NOISE_MODEL_METHODS


def solve(
    name: str,
    problem: CalibrationProblem,
    options: MethodOptions,
    observations: list[FrameObservations],
    learned: LearnedNoise | None = None,
) -> Calibration:
    """Run one method. With options.learn_noise a noise-modelling method runs on the learned levels
    (learned: from learn_noise(problem, options), computed here when not given; pass it to share one
    learning between methods), without the learning pass's outliers; its result says so, with the
    fit check's warnings."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; choose one of {', '.join(METHODS)} or 'all'")
    if name == "seed-ekf":
        check_depth(observations)  # before the learning pass, which would fail on another count
    if not needs_learned_noise(name, options):
        result = METHODS[name](problem, options, observations)
        result.setup = problem.setup
        rejected = result.observations_rejected
        if rejected > MAX_REJECTED_FRACTION * problem.observation_count:
            result.warnings.append(
                f"{rejected} of {problem.observation_count} observations were rejected against the declared "
                "noise: it is likely too small for these data, or the model does not fit them (learning the "
                "noise from the data, the default, says which)"
            )
        return result
    learned = learned or learn_noise(problem, options)
    adjusted, solved, solved_options = learned_setup(name, problem, options, learned)
    _check_usable(problem, adjusted, solved, learned)
    result = METHODS[name](solved, solved_options, observations)
    result.setup = problem.setup
    _account_for_learning(problem, adjusted, result, learned)
    if name == "seed-ekf":
        check = check_assumptions(result, learned, solved, solved_options)
        result.diagnostics["assumptions"] = check
        if not check.holds:
            result.warnings.insert(0, check.warning())
    return result


def _check_usable(
    problem: CalibrationProblem,
    adjusted: CalibrationProblem,
    solved: CalibrationProblem,
    learned: LearnedNoise,
) -> None:
    """CalibrationInputError when the learning pass left too little to calibrate from, or when
    nothing fits: the corners miss by MAX_CORNER_RMS_PX or more even at the learned optimum."""
    left_out = len(learned.outliers)
    if len(solved.frames) < MIN_FRAMES:
        raise CalibrationInputError(
            f"{left_out} of {problem.observation_count} observations were rejected as outliers, leaving "
            f"{len(solved.frames)} frames (at least {MIN_FRAMES} needed): the model does not fit them "
            "(wrong board definition, intrinsics or robot poses?)"
        )
    used = [r.rms_px for r in marker_residuals(adjusted, learned.state, learned.outliers) if r.used]
    rms = float(np.sqrt(np.mean(np.square(used))))
    if rms >= MAX_CORNER_RMS_PX:
        raise CalibrationInputError(
            f"the corners do not fit any mount: RMS residual {rms:.0f} px at the best estimate with the "
            "noise learned from the data (wrong board definition, marker IDs, intrinsics or poses?)"
        )


def camera_problem(
    name: str, problem: CalibrationProblem, learned: LearnedNoise | None
) -> CalibrationProblem:
    """The problem with the camera, board, depth and arm a method solved with: the self-calibrated
    ones when the learning pass needed them, except for seed-ekf (it measures points from the observations
    with the declared camera)."""
    return problem if learned is None or name == "seed-ekf" else learned.adjusted(problem)


def learned_setup(
    name: str, problem: CalibrationProblem, options: MethodOptions, learned: LearnedNoise
) -> tuple[CalibrationProblem, CalibrationProblem, MethodOptions]:
    """What a noise-modelling method solves with the learned noise: the problem with the
    self-calibrated camera, board, depth and arm if the learning pass needed them (not for seed-ekf, which
    measures points from the observations with the declared camera), that problem at the learned
    levels without the pass's outliers, and the options (the pass over all frames found the
    outliers, so only batch keeps its robust loss)."""
    adjusted = camera_problem(name, problem, learned)
    solved = scaled_problem(adjusted, learned.learned, learned.outliers)
    return adjusted, solved, replace(options, robust=name == "batch")


def run_method(
    name: str,
    problem: CalibrationProblem,
    options: MethodOptions,
    observations: list[FrameObservations],
    learned: LearnedNoise | None = None,
) -> Calibration:
    """solve, and the result carries diagnostics['observability'] and the warnings it raises."""
    result = solve(name, problem, options, observations, learned)
    misfit = misfit_warning(problem, result)
    if misfit is not None:
        result.diagnostics["misfit"] = misfit
        result.warnings.append(misfit)
    noise = result.diagnostics.get("noise")
    seen = camera_problem(name, problem, noise)
    report = observability(seen, calibration_state(problem, result), result.covariance)
    result.diagnostics["observability"] = report
    result.warnings.extend(w for w in report.warnings if w not in result.warnings)
    return result


def _account_for_learning(
    problem: CalibrationProblem, adjusted: CalibrationProblem, result: Calibration, learned: LearnedNoise
) -> None:
    """Residuals and counts of a result solved on the learned problem, over the whole problem
    (adjusted: with the camera and board the method solved with): the learning pass's outliers
    and the method's own rejections are not used. The fit check reads the declared problem."""
    state = calibration_state(problem, result)
    rejected = learned.outliers | {(r.frame, r.marker_id) for r in result.residuals if not r.used}
    if len(rejected) == problem.observation_count:
        raise CalibrationInputError(
            f"all {len(rejected)} observations were rejected as outliers: the model does not fit "
            "them at all (wrong board definition, intrinsics or robot poses?)"
        )
    result.residuals = marker_residuals(adjusted, state, rejected)
    result.observations_rejected = len(rejected)
    result.observations_used = problem.observation_count - len(rejected)
    if adjusted is not problem and learned.consider_covariance is not None and result.covariance is not None:
        # The method solved with the self-calibrated camera fixed: add what its uncertainty costs.
        result.covariance = result.covariance + learned.consider_covariance
    if learned.level_widening is not None and result.covariance is not None:
        # The levels were learned from these data: their own uncertainty widens the mount's.
        result.covariance = result.covariance + learned.level_widening
    fit = check_fit(learned.measured(problem), learned, len(rejected))
    result.diagnostics["noise"] = learned
    result.diagnostics["fit"] = fit
    result.warnings.extend(w for w in fit.warnings if w not in result.warnings)
