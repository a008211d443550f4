"""Noise levels learned from the data: iterated variance-component estimation on the batch problem.

The measurements fall into four groups, each with a noise level the dataset declares: the corner
pixels (their covariance from the detector), the corner depths (the depth noise model), and the
reported flange pose's translation and rotation (RobotPoseNoise). At the batch optimum, a group g
with whitened residuals r_g has expected sum of squares equal to its redundancy
rho_g = n_g - trace(H_gg) (H the hat matrix of the whitened, linearised problem) when its level is
right. Each iteration rescales every group by its ratio ||r_g||^2 / rho_g and solves again
(Helmert / Foerstner variance-component estimation), until the levels stop changing
(LEVEL_TOLERANCE).

The declared level of each group is a prior worth PRIOR_DOF degrees of freedom (an inverse-gamma
prior: sigma^2 = (ratio * rho_g * sigma^2 + PRIOR_DOF * declared^2) / (rho_g + PRIOR_DOF)), so a
group with few residuals (the flange poses of a handful of frames) stays near what the cell file
says, and one with thousands (the pixels) follows the data. With the robust option, whitened
residuals beyond the batch's Huber scale count at that scale (corrected for what clipping removes
from a Gaussian), so a few outliers do not inflate a level, and the markers the robust optimum
down-weights are returned as outliers for the filters to leave out (gate after a first pass over
all frames, never against a start that saw a few).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2, norm

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.lie import pose_minus
from hec.estimator.solve.batch import (
    HUBER_SCALE,
    BatchObjective,
    gauss_newton,
    one_blas_thread,
    outliers,
    state_covariance,
    weighted_jacobian,
)
from hec.estimator.solve.block_arrow import hat_diagonal
from hec.estimator.solve.calibration import MethodOptions, Prior
from hec.estimator.solve.depth_check import DepthCheck, depth_check, has_depth, misfit, pixels_only
from hec.estimator.solve.filters import initial_covariance
from hec.estimator.solve.initialise import initial_state
from hec.estimator.solve.level_uncertainty import level_widening, row_groups
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.noise_levels import NoiseLevels, declared_levels, scaled_problem
from hec.estimator.solve.prior_scale import name_groups, updated_prior_scale
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import (
    NuisanceUncertainty,
    SelfCalibrationObjective,
    adjusted_problem,
    available_groups,
    droppable_groups,
    group_members,
    group_names,
    noteworthy_sizes,
    scales_confounded,
)
from hec.estimator.solve.stacked_prediction import StackedFrames

GROUPS = ("pixels", "depth", "robot_translation", "robot_rotation")
PRIOR_DOF = 3.0
MAX_ITERATIONS = 30
# Each pass's optimum to this relative cost change (the levels move by far more between passes).
VCE_COST_TOLERANCE = 1e-7
# The declared camera, board, depth (and arm) are replaced by self-calibration when the corners,
# the depths (or, with the arm's kinematics known, the flange poses) fit worse than this many
# times their noise (the learned level: a chi-square per degree of freedom above 2.25,
# hec.estimator.solve.fit_check.BAD_FIT). White noise above the declared level triggers it too; the
# significance test then fixes the groups it does not need.
MISFIT_SCALE = 1.5
# ... and the flange poses when, besides, their chi-square is this improbable.
ARM_MISFIT_PROBABILITY = 1e-3
# Learning stops when no level changes by more than this fraction in an iteration.
LEVEL_TOLERANCE = 0.003
# Where the declared robot pose noise is zero (exact poses), learning starts from this floor.
ROBOT_FLOOR = RobotPoseNoise(1e-5, float(np.radians(1e-3)))
# E[min(x^2, c^2)] for x ~ N(0, 1), c the Huber scale: a clipped residual's expected square.
_TAIL = 2 * norm.sf(HUBER_SCALE)
_CLIPPED_SQUARE = float(1 - _TAIL - 2 * HUBER_SCALE * norm.pdf(HUBER_SCALE) + HUBER_SCALE**2 * _TAIL)


@dataclass
class LearnedNoise:
    """What the data say about the noise. declared: the problem's levels; learned: the converged
    ones. ratios: per group, the sum of squared whitened residuals at the declared levels over its
    redundancy at the learned optimum (the chi-square per degree of freedom the declared model
    gives: 1 when it fits). redundancy: per group. chi2_dof: all measurement groups together at the
    declared levels. state: the batch optimum at the learned levels. outliers: (frame, marker_id)
    the robust optimum down-weighted. residuals: per frame the whitened measurement residual at
    the optimum under the learned levels. prior_distance: with a user prior, the squared
    Mahalanobis distance between it and the estimate from the data alone (fit_check).
    With self-calibration (the declared model fits worse than MISFIT_SCALE times its noise):
    theta and theta_covariance over theta_names (the groups kept after the significance test),
    groups_tried (every group freed at first) and groups_kept
    (hec.estimator.solve.self_calibration.NUISANCE_GROUPS), consider_covariance (6, 6) that
    T_flange_cam's covariance gains from theta's uncertainty, and ratios_after, chi2_dof_after: as
    ratios and chi2_dof, with the adjusted model. mount_covariance: (6, 6) T_flange_cam's covariance at
    the optimum, theta free. theta_prior_scale: per theta name, its prior's sigma learned from the
    corrections over the declared one (hec.estimator.solve.prior_scale). level_widening: (6, 6) what
    T_flange_cam's covariance gains from the levels being learned (hec.estimator.solve.level_uncertainty;
    not in mount_covariance). depth: with depths, whether
    they agree with the pixels (hec.estimator.solve.depth_check); when they do not, everything here
    is learned from the pixels alone (measured(problem) gives that problem)."""

    declared: NoiseLevels
    learned: NoiseLevels
    ratios: dict[str, float]
    redundancy: dict[str, float]
    chi2_dof: float
    iterations: int
    state: HandEyeState
    outliers: set[tuple[int, int]]
    residuals: list[np.ndarray]
    prior_distance: float | None = None
    time_s: float = 0.0
    theta: np.ndarray | None = None
    theta_covariance: np.ndarray | None = None
    theta_names: tuple[str, ...] = ()
    groups_tried: tuple[str, ...] = ()
    groups_kept: tuple[str, ...] = ()
    consider_covariance: np.ndarray | None = None
    ratios_after: dict[str, float] | None = None
    chi2_dof_after: float | None = None
    mount_covariance: np.ndarray | None = None
    depth: DepthCheck | None = None
    theta_prior_scale: np.ndarray | None = None
    level_widening: np.ndarray | None = None

    @property
    def theta_sigma(self) -> np.ndarray | None:
        """theta's 1-sigmas (theta_names), None without self-calibration."""
        return None if self.theta_covariance is None else np.sqrt(np.diag(self.theta_covariance))

    def measured(self, problem: CalibrationProblem) -> CalibrationProblem:
        """The problem's measurements the learning used: without the depths when they disagreed
        with the pixels (hec.estimator.solve.depth_check), else all of them."""
        return problem if self.depth is None or self.depth.used else pixels_only(problem)

    def adjusted(self, problem: CalibrationProblem) -> CalibrationProblem:
        """The measured problem with the self-calibrated camera, board, depth and arm (unchanged
        without)."""
        problem = self.measured(problem)
        return problem if self.theta is None else adjusted_problem(problem, self.theta, self.theta_names)

    def to_dict(self) -> dict:
        return {
            "declared": self.declared.to_dict(),
            "learned": self.learned.to_dict(),
            "chi2_per_dof_declared": {**self.ratios, "all measurements": self.chi2_dof},
            "redundancy": self.redundancy,
            "iterations": self.iterations,
            "outliers": len(self.outliers),
            "time_s": self.time_s,
            "depth_check": None if self.depth is None else self.depth.to_dict(),
            "self_calibration": None
            if self.theta is None
            else {
                "groups_tried": list(self.groups_tried),
                "groups_kept": list(self.groups_kept),
                "prior_scale": {
                    name: float(s) for name, s in zip(self.theta_names, self.theta_prior_scale, strict=True)
                },
                "values": {
                    name: {"value": float(v), "sigma": float(s)}
                    for name, v, s in zip(self.theta_names, self.theta, self.theta_sigma, strict=True)
                },
            },
        }


def prior_conflict(data_only: HandEyeState, data_covariance: np.ndarray, prior: Prior) -> float:
    """Squared Mahalanobis distance of the prior's mean from the data-only estimate of
    T_flange_cam, with both covariances (6, 6) (hec.estimator.geometry.lie convention)."""
    e = pose_minus(prior.T_flange_cam, data_only.T_flange_cam)
    return float(e @ np.linalg.solve(data_covariance[:6, :6] + prior.covariance, e))


def learn_noise(problem: CalibrationProblem, options: MethodOptions) -> LearnedNoise:
    """Iterated variance-component estimation (see the module doc). The state is the batch
    optimum's map model and depth-scale choice (options). With depths, learned twice, with them and
    from the pixels alone: the pixels' result when the depths disagree (hec.estimator.solve.depth_check)."""
    started = time.perf_counter()
    with one_blas_thread():
        learned = _learn_noise(problem, options)
        if has_depth(problem):
            pixels = _learn_noise(pixels_only(problem), options)
            robot = problem.robot_noise if not problem.robot_noise.is_zero else ROBOT_FLOOR
            check = depth_check(
                learned.state.T_flange_cam,
                learned.mount_covariance,
                pixels.state.T_flange_cam,
                pixels.mount_covariance,
                (misfit(learned.learned, robot), misfit(pixels.learned, robot)),
            )
            learned = replace(learned if check.used else pixels, depth=check)
    learned.time_s = time.perf_counter() - started
    return learned


def _objective(
    plain: BatchObjective, levels: NoiseLevels, names: tuple[str, ...], prior_scale: np.ndarray | None = None
) -> BatchObjective | SelfCalibrationObjective:
    """The batch objective of plain's problem at levels, with the self-calibration of names (none:
    the plain batch's), their priors widened by prior_scale (hec.estimator.solve.prior_scale)."""
    if not names:
        return plain.at_levels(levels)

    def make(p: CalibrationProblem) -> BatchObjective:
        return BatchObjective(p, plain.start, plain.P0, plain.prior)

    objective = SelfCalibrationObjective(scaled_problem(plain.problem, levels), make, names)
    if prior_scale is not None:
        objective.sqrt_info = objective.sqrt_info / prior_scale
    return objective


@dataclass
class _Pass:
    """One variance-component estimation to convergence: the levels, the parameters at the
    optimum, each group's (squares, redundancy), the iterations run, the problem's stacked frames
    (at the declared noise, for objectives of the same problem to reuse) and the self-calibration
    priors' learned scales (hec.estimator.solve.prior_scale; None without self-calibration)."""

    levels: NoiseLevels
    params: np.ndarray
    factors: dict[str, tuple[float, float]]
    iterations: int
    declared: StackedFrames
    prior_scale: np.ndarray | None = None


def _vce(
    problem: CalibrationProblem,
    options: MethodOptions,
    start: HandEyeState,
    P0: np.ndarray,
    levels: NoiseLevels,
    params: np.ndarray | None,
    names: tuple[str, ...],
    prior_scale: np.ndarray | None = None,
) -> _Pass:
    declared = declared_levels(problem)
    robot_start = levels.robot if problem.robot_noise.is_zero else problem.robot_noise
    iterations = 0
    plain = BatchObjective(problem, start, P0, options.prior)
    if names:
        theta_groups = name_groups(problem, names)
        prior_scale = np.ones(len(names)) if prior_scale is None else prior_scale
    while iterations < MAX_ITERATIONS:
        iterations += 1
        objective = _objective(plain, levels, names, prior_scale)
        x0 = np.zeros(objective.size) if params is None else params
        optimum = gauss_newton(objective, x0, options.robust, VCE_COST_TOLERANCE)
        params = optimum.params
        r, J = weighted_jacobian(objective, params, options.robust, optimum)
        hat = hat_diagonal(J, objective.layout)
        if iterations == 1:  # the rows and their groups are the same at every level
            groups = row_groups(objective, problem)
        squares = np.minimum(r**2, HUBER_SCALE**2) / _CLIPPED_SQUARE if options.robust else r**2
        factors = {}
        for g, name in enumerate(GROUPS):
            rows = groups == g
            redundancy = float(np.sum(1.0 - hat[rows]))
            if rows.any() and redundancy > 0.5:
                factors[name] = (float(np.sum(squares[rows])), redundancy)
        new_levels = _updated(levels, declared, robot_start, factors)
        change = max(abs(_sigma(new_levels, g) / _sigma(levels, g) - 1.0) for g in GROUPS)
        levels = new_levels
        if names:  # theta's prior rows are the last ones
            p = len(names)
            new_scale = updated_prior_scale(prior_scale, theta_groups, r[-p:], 1.0 - hat[-p:])
            change = max(change, float(np.max(np.abs(new_scale / prior_scale - 1.0))))
            prior_scale = new_scale
        if change < LEVEL_TOLERANCE:
            break
    return _Pass(levels, params, factors, iterations, plain.declared, prior_scale if names else None)


def _learn_noise(problem: CalibrationProblem, options: MethodOptions) -> LearnedNoise:
    declared = declared_levels(problem)
    robot = problem.robot_noise if not problem.robot_noise.is_zero else ROBOT_FLOOR
    start = initial_state(problem, options).state
    P0 = initial_covariance(start, options)
    first = _vce(problem, options, start, P0, NoiseLevels(1.0, 1.0, robot), None, ())
    declared_ratios, chi2_dof = _declared_fit(first.levels, declared, robot, first.factors)
    final, kept, tried, uncertainty = first, (), (), None
    ratios_after, chi2_dof_after = None, None
    corners_misfit, depths_misfit, flange_misfit = _misfits(problem, first, declared_ratios, robot)
    arm_misfit = problem.kinematics is not None and flange_misfit
    if corners_misfit or depths_misfit:
        depth_only = not (corners_misfit or flange_misfit)
        tried = available_groups(problem, arm_misfit=False, depth_only=depth_only)
        final, kept, uncertainty = _self_calibrate(problem, options, start, P0, first, tried)
        if depth_only and "board_scale" in kept and not scales_confounded(problem, kept, uncertainty.theta):
            tried = tuple(g for g in tried if g != "board_scale")
            final, kept, uncertainty = _self_calibrate(problem, options, start, P0, first, tried)
        # The camera's errors (a depth bias above all) push the flange poses too: the arm misfits
        # only if its poses still do with the camera, board and depth calibrated.
        arm_misfit = arm_misfit and _arm_misfits_still(problem, final, declared, robot)
    if arm_misfit:
        tried = available_groups(problem, arm_misfit=True)
        final, kept, uncertainty = _self_calibrate(problem, options, start, P0, first, tried)
    if kept:
        ratios_after, chi2_dof_after = _declared_fit(final.levels, declared, robot, final.factors)
    names = group_names(problem, kept)
    theta = final.params[len(final.params) - len(names) :] if names else None
    adjusted = problem if theta is None else adjusted_problem(problem, theta, names)
    stack = first.declared if theta is None else None  # adjusted is the problem itself
    objective = BatchObjective(adjusted, start, P0, options.prior, final.levels, stack)
    params = final.params[: objective.size]
    frame_residuals = objective.frame_residuals(params)
    if uncertainty is None:
        mount_covariance = state_covariance(objective, params, options.robust)[:6, :6]
    else:
        mount_covariance = uncertainty.mount
    widening = _level_widening(problem, options, final, names, start, P0)
    prior_distance = None if options.prior is None else _prior_distance(objective, params, options)
    return LearnedNoise(
        declared,
        final.levels,
        declared_ratios,
        {name: red for name, (_, red) in first.factors.items()},
        chi2_dof,
        first.iterations + (final.iterations if final is not first else 0),
        start.plus(params[: objective.n]),
        outliers(adjusted, frame_residuals) if options.robust else set(),
        frame_residuals,
        prior_distance,
        theta=theta,
        theta_covariance=None if uncertainty is None else uncertainty.theta,
        theta_names=names,
        groups_tried=tried,
        groups_kept=kept,
        consider_covariance=None if uncertainty is None else uncertainty.consider,
        ratios_after=ratios_after,
        chi2_dof_after=chi2_dof_after,
        mount_covariance=mount_covariance,
        theta_prior_scale=final.prior_scale if names else None,
        level_widening=widening,
    )


def _level_widening(
    problem: CalibrationProblem,
    options: MethodOptions,
    final: _Pass,
    names: tuple[str, ...],
    start: HandEyeState,
    P0: np.ndarray,
) -> np.ndarray:
    """(6, 6) level_widening at final's optimum, each group's level worth its redundancy and PRIOR_DOF."""
    plain = BatchObjective(problem, start, P0, options.prior, declared=final.declared)
    objective = _objective(plain, final.levels, names, final.prior_scale)
    _, J = weighted_jacobian(objective, final.params, options.robust)
    to_local = start.plus_jacobian(final.params[: start.dim])[:6, :6]
    dof = {g: final.factors[n][1] + PRIOR_DOF for g, n in enumerate(GROUPS) if n in final.factors}
    return level_widening(J, row_groups(objective, problem), dof, to_local)


def _misfits(
    problem: CalibrationProblem, first: _Pass, ratios: dict[str, float], robot: RobotPoseNoise
) -> tuple[bool, bool, bool]:
    """Whether the corners, the depths and the flange poses fit worse than MISFIT_SCALE times their
    noise, the flange poses only where their chi-square at the level learning started from (ratios,
    _declared_fit's; robot) is beyond ARM_MISFIT_PROBABILITY (few views have few flange residuals)."""
    levels = first.levels
    flange = False
    for name, start in (
        ("robot_translation", robot.translation_sigma_m),
        ("robot_rotation", robot.rotation_sigma_rad),
    ):
        if name in ratios:
            redundancy = first.factors[name][1]
            unlikely = chi2.sf(ratios[name] * redundancy, redundancy) < ARM_MISFIT_PROBABILITY
            flange |= _sigma(levels, name) > MISFIT_SCALE * start and unlikely
    return levels.pixel_scale > MISFIT_SCALE, levels.depth_scale > MISFIT_SCALE, flange


def _arm_misfits_still(
    problem: CalibrationProblem, calibrated: _Pass, declared: NoiseLevels, robot: RobotPoseNoise
) -> bool:
    """_misfits' verdict on the flange poses (of a known arm) at a pass with the camera calibrated."""
    ratios, _ = _declared_fit(calibrated.levels, declared, robot, calibrated.factors)
    return problem.kinematics is not None and _misfits(problem, calibrated, ratios, robot)[2]


def _self_calibrate(
    problem: CalibrationProblem,
    options: MethodOptions,
    start: HandEyeState,
    P0: np.ndarray,
    first: _Pass,
    groups: tuple[str, ...],
) -> tuple[_Pass, tuple[str, ...], NuisanceUncertainty | None]:
    """Self-calibration of groups, then again without the groups droppable_groups finds. Returns the
    final pass, the groups kept and the uncertainty at its optimum (the first pass, no groups and
    None when every group is dropped)."""
    names = group_names(problem, groups)
    x0 = np.concatenate([first.params, np.zeros(len(names))])
    full = _vce(problem, options, start, P0, first.levels, x0, names)
    uncertainty = _nuisance_uncertainty(problem, full, names, start, P0, options)
    index = {n: i for i, n in enumerate(names)}
    rows_of = {g: [index[n] for n in group_members(problem, g)] for g in groups}
    dropped = droppable_groups(rows_of, full.params[-len(names) :], uncertainty, noteworthy_sizes(names))
    if not dropped:
        return full, groups, uncertainty
    kept = tuple(g for g in groups if g not in dropped)
    if not kept:
        return first, (), None
    theta = dict(zip(names, full.params[-len(names) :], strict=True))
    names = group_names(problem, kept)
    x0 = np.concatenate([first.params, [theta[n] for n in names]])
    scale = dict(zip(group_names(problem, groups), full.prior_scale, strict=True))
    final = _vce(problem, options, start, P0, full.levels, x0, names, np.array([scale[n] for n in names]))
    return final, kept, _nuisance_uncertainty(problem, final, names, start, P0, options)


def _nuisance_uncertainty(
    problem: CalibrationProblem,
    final: _Pass,
    names: tuple[str, ...],
    start: HandEyeState,
    P0: np.ndarray,
    options: MethodOptions,
) -> NuisanceUncertainty:
    """The covariances at final's optimum (the inverse of the normal matrix; with theta fixed, its
    state block without theta's rows and columns)."""
    plain = BatchObjective(problem, start, P0, options.prior, declared=final.declared)
    objective = _objective(plain, final.levels, names, final.prior_scale)
    _, J = weighted_jacobian(objective, final.params, options.robust)
    N = J.T @ J
    p = len(names)
    free = np.linalg.inv(N)
    fixed = np.linalg.inv(N[:-p, :-p])
    to_local = start.plus_jacobian(final.params[: start.dim])[:6, :6]
    extra = to_local @ (free[:6, :6] - fixed[:6, :6]) @ to_local.T
    mount = to_local @ free[:6, :6] @ to_local.T
    return NuisanceUncertainty(
        free[-p:, -p:], 0.5 * (mount + mount.T), to_local @ free[:6, -p:], 0.5 * (extra + extra.T)
    )


def _prior_distance(with_prior: BatchObjective, params: np.ndarray, options: MethodOptions) -> float:
    """Squared Mahalanobis distance of the user's prior from the data-only batch optimum (with_prior:
    the objective at the learned levels)."""
    p = with_prior
    objective = BatchObjective(p.problem, p.start, p.P0, None, p.levels, p.declared)
    optimum = gauss_newton(objective, params, options.robust)
    x = optimum.params
    return prior_conflict(
        p.start.plus(x[: objective.n]), state_covariance(objective, x, options.robust, optimum), options.prior
    )


def _sigma(levels: NoiseLevels, name: str) -> float:
    return {
        "pixels": levels.pixel_scale,
        "depth": levels.depth_scale,
        "robot_translation": levels.robot.translation_sigma_m,
        "robot_rotation": levels.robot.rotation_sigma_rad,
    }[name]


def _updated(
    levels: NoiseLevels, declared: NoiseLevels, robot_start: RobotPoseNoise, factors: dict
) -> NoiseLevels:
    """Each group's level rescaled by its ratio, shrunk toward the declared level (PRIOR_DOF)."""
    base = replace(declared, robot=robot_start)
    new = {}
    for name in GROUPS:
        current = _sigma(levels, name)
        if name not in factors:
            new[name] = current
            continue
        squares, redundancy = factors[name]
        prior = _sigma(base, name)
        new[name] = float(np.sqrt((squares * current**2 + PRIOR_DOF * prior**2) / (redundancy + PRIOR_DOF)))
    return NoiseLevels(
        new["pixels"], new["depth"], RobotPoseNoise(new["robot_translation"], new["robot_rotation"])
    )


def _declared_fit(
    levels: NoiseLevels, declared: NoiseLevels, robot_start: RobotPoseNoise, factors: dict
) -> tuple[dict[str, float], float]:
    """The chi-square per degree of freedom each group (and the measurements together) would show
    at the declared levels: the squares at the learned levels times (learned / declared)^2."""
    base = replace(declared, robot=robot_start)
    ratios, total, total_red = {}, 0.0, 0.0
    for name, (squares, redundancy) in factors.items():
        at_declared = squares * (_sigma(levels, name) / _sigma(base, name)) ** 2
        ratios[name] = at_declared / redundancy
        if name in ("pixels", "depth"):
            total, total_red = total + at_declared, total_red + redundancy
    return ratios, total / total_red if total_red > 0 else float("nan")
