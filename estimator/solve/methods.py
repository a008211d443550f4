"""Every calibration method behind one call, with the observability check added to each result."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from estimator.observe.observations import FrameObservations
from estimator.solve.baselines import OPENCV_METHODS, opencv_calibrate
from estimator.solve.batch import batch
from estimator.solve.calibration import Calibration, MethodOptions, marker_residuals
from estimator.solve.filters import run_filter
from estimator.solve.fit_check import check_fit
from estimator.solve.measurement_model import HandEyeState
from estimator.solve.noise_learning import LearnedNoise, learn_noise, scaled_problem
from estimator.solve.observability import observability
from estimator.solve.problem import CalibrationInputError, CalibrationProblem
from estimator.solve.seed_ekf import seed_ekf
from estimator.solve.ukf import ukf

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
DEFAULT_METHOD = "ekf"
# The methods that model the noise (and so learn it with options.learn_noise); the OpenCV
# baselines weigh every view alike.
NOISE_MODEL_METHODS = ("seed-ekf", "ekf", "iekf", "ukf", "batch")


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
    if not needs_learned_noise(name, options):
        return METHODS[name](problem, options, observations)
    learned = learned or learn_noise(problem, options)
    adjusted, solved, solved_options = learned_setup(name, problem, options, learned)
    result = METHODS[name](solved, solved_options, observations)
    _account_for_learning(problem, adjusted, result, learned)
    return result


def learned_setup(
    name: str, problem: CalibrationProblem, options: MethodOptions, learned: LearnedNoise
) -> tuple[CalibrationProblem, CalibrationProblem, MethodOptions]:
    """What a noise-modelling method solves with the learned noise: the problem with the
    self-calibrated camera and board if the learning pass needed them (not for seed-ekf, which
    measures points from the observations with the declared camera), that problem at the learned
    levels without the pass's outliers, and the options (the pass over all frames found the
    outliers, so only batch keeps its robust loss)."""
    adjusted = learned.adjusted(problem) if name != "seed-ekf" else problem
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
    noise = result.diagnostics.get("noise")
    seen = problem if noise is None or name == "seed-ekf" else noise.adjusted(problem)
    report = observability(seen, _map_state(problem, result))
    result.diagnostics["observability"] = report
    result.warnings.extend(w for w in report.warnings if w not in result.warnings)
    return result


def _map_state(problem: CalibrationProblem, result: Calibration) -> HandEyeState:
    if result.T_base_board is not None:
        return HandEyeState(result.T_flange_cam, T_base_board=result.T_base_board)
    corners = np.concatenate([result.landmarks_base[i] for i in problem.marker_ids])
    return HandEyeState(result.T_flange_cam, landmarks_base=corners)


def _account_for_learning(
    problem: CalibrationProblem, adjusted: CalibrationProblem, result: Calibration, learned: LearnedNoise
) -> None:
    """Residuals and counts of a result solved on the learned problem, over the whole problem
    (adjusted: with the camera and board the method solved with): the learning pass's outliers
    and the method's own rejections are not used. The fit check reads the declared problem."""
    state = _map_state(problem, result)
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
    fit = check_fit(problem, learned, len(rejected))
    result.diagnostics["noise"] = learned
    result.diagnostics["fit"] = fit
    result.warnings.extend(w for w in fit.warnings if w not in result.warnings)
