"""batch: the maximum-likelihood (maximum a posteriori with the wide prior) reference.

Jointly optimises T_flange_cam, the board pose (or landmarks), the optional depth
scale and every frame's flange pose error delta_i over all whitened reprojection
and depth residuals, the robot-noise prior of each delta_i, the user's prior on
T_flange_cam if given, and the same wide prior on the state the filters start from.
Parameters are perturbations of the starting state (estimator.geometry.lie convention), so the
result is comparable with the filters.
Gauss-Newton with step halving (iteratively reweighted for a Huber loss on the whitened
residuals when robust) on the dense normal equations of the analytic Jacobian (each frame's
residuals depend on the state and on its own delta only): a few hundred parameters. (scipy's
least_squares reached the same optimum: its exact trust-region solver took ~10x longer, its
sparse one, LSMR, did not converge in 300 evaluations.) Dense solves run on one BLAS thread:
OpenBLAS threads made them 10x slower on a busy 2-core machine.
Covariance: the state block of inv(J^T W J) at the optimum (W the Huber weights).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.stats import chi2
from threadpoolctl import threadpool_limits

from estimator.geometry.lie import pose_plus_jacobian
from estimator.solve.calibration import Calibration, MethodOptions, Prior, calibration_from_state
from estimator.solve.filters import GATE_PROBABILITY, initial_covariance, marker_rows
from estimator.solve.initialise import initial_state
from estimator.solve.measurement_model import HandEyeState, predict_frame
from estimator.solve.problem import CalibrationProblem

# Whitened residuals beyond this many sigmas are down-weighted (Huber).
HUBER_SCALE = 3.0
GN_MAX_ITERATIONS = 50
GN_STEP_TOLERANCE = 1e-12
GN_COST_TOLERANCE = 1e-10
LINE_SEARCH_HALVINGS = 10


class BatchObjective:
    """Residuals and Jacobian over params = [state perturbation (n), delta_1 .. delta_N (6 each)]."""

    def __init__(
        self, problem: CalibrationProblem, start: HandEyeState, P0: np.ndarray, prior: Prior | None
    ) -> None:
        self.problem, self.start, self.prior = problem, start, prior
        self.n = start.dim
        self.with_robot = not problem.robot_noise.is_zero
        self.prior_sqrt_info = np.linalg.cholesky(np.linalg.inv(P0)).T
        self.robot_sqrt_info = (
            np.diag(1.0 / np.sqrt(np.diag(problem.robot_noise.covariance()))) if self.with_robot else None
        )

    @property
    def size(self) -> int:
        return self.n + (6 * len(self.problem.frames) if self.with_robot else 0)

    def _delta(self, params: np.ndarray, i: int) -> np.ndarray | None:
        return params[self.n + 6 * i : self.n + 6 * i + 6] if self.with_robot else None

    def residuals(self, params: np.ndarray) -> np.ndarray:
        state = self.start.plus(params[: self.n])
        parts = [self.prior_sqrt_info @ params[: self.n]]
        if self.prior is not None:
            parts.append(self.prior.whitened_error(state.T_flange_cam)[0])
        for i, frame in enumerate(self.problem.frames):
            delta = self._delta(params, i)
            parts.append(-predict_frame(self.problem, state, frame, delta, jacobians=False).residual)
            if self.with_robot:
                parts.append(self.robot_sqrt_info @ delta)
        return np.concatenate(parts)

    def jacobian(self, params: np.ndarray) -> np.ndarray:
        """(rows, size) dense Jacobian of residuals(params); each frame's rows depend on the state
        and on that frame's delta only (the rest of the row is zero)."""
        state = self.start.plus(params[: self.n])
        to_params = state.plus_jacobian(params[: self.n])
        preds = [
            predict_frame(self.problem, state, frame, self._delta(params, i))
            for i, frame in enumerate(self.problem.frames)
        ]
        robot_rows = 6 if self.with_robot else 0
        rows = self.n + (6 if self.prior is not None else 0)
        J = np.zeros((rows + sum(len(p.residual) + robot_rows for p in preds), self.size))
        J[: self.n, : self.n] = self.prior_sqrt_info
        if self.prior is not None:
            J[self.n : rows, :6] = self.prior.whitened_error(state.T_flange_cam)[1] @ to_params[:6, :6]
        for i, pred in enumerate(preds):
            m = len(pred.residual)
            J[rows : rows + m, : self.n] = pred.J_state @ to_params
            if self.with_robot:
                cols = slice(self.n + 6 * i, self.n + 6 * i + 6)
                J[rows : rows + m, cols] = pred.J_flange @ pose_plus_jacobian(self._delta(params, i))
                J[rows + m : rows + m + 6, cols] = self.robot_sqrt_info
            rows += m + robot_rows
        return J

    def frame_residuals(self, params: np.ndarray) -> list[np.ndarray]:
        """Whitened measurement residual of each frame at params."""
        state = self.start.plus(params[: self.n])
        return [
            predict_frame(self.problem, state, frame, self._delta(params, i), jacobians=False).residual
            for i, frame in enumerate(self.problem.frames)
        ]


def huber_weights(r: np.ndarray) -> np.ndarray:
    """Per-residual IRLS weights of the Huber loss at HUBER_SCALE (whitened units)."""
    a = np.abs(r)
    return np.where(a <= HUBER_SCALE, 1.0, HUBER_SCALE / np.maximum(a, 1e-300))


def gauss_newton(
    objective: BatchObjective, x0: np.ndarray, robust: bool, cost_tolerance: float = GN_COST_TOLERANCE
) -> tuple[np.ndarray, int]:
    """The (Huber-weighted, with robust) least-squares optimum of the batch objective from x0:
    Gauss-Newton with step halving on the dense normal equations (a few hundred parameters).
    Stops when a step lowers the cost by less than cost_tolerance of it (or cannot lower it).
    Returns the parameters and the iterations run."""

    def cost(x: np.ndarray) -> float:
        r = objective.residuals(x)
        if not robust:
            return float(r @ r)
        a = np.abs(r)
        return float(np.sum(np.where(a <= HUBER_SCALE, a * a, 2 * HUBER_SCALE * a - HUBER_SCALE**2)))

    x, current = x0, cost(x0)
    iterations = 0
    while iterations < GN_MAX_ITERATIONS:
        iterations += 1
        r = objective.residuals(x)
        J = objective.jacobian(x)
        w = huber_weights(r) if robust else np.ones_like(r)
        Jw = J * w[:, None]
        step = -np.linalg.solve(J.T @ Jw, Jw.T @ r)
        for _ in range(LINE_SEARCH_HALVINGS):
            trial = cost(x + step)
            if trial <= current:
                break
            step = 0.5 * step
        else:
            break
        x, previous, current = x + step, current, trial
        if np.max(np.abs(step)) < GN_STEP_TOLERANCE or previous - current < cost_tolerance * previous:
            break
    return x, iterations


def weighted_jacobian(
    objective: BatchObjective, params: np.ndarray, robust: bool
) -> tuple[np.ndarray, np.ndarray]:
    """The residuals at params and the Jacobian whose rows carry the square root of their Huber
    weights (robust) or are as they are: J^T J is then the information of the optimum."""
    r = objective.residuals(params)
    J = objective.jacobian(params)
    return r, J * np.sqrt(huber_weights(r))[:, None] if robust else J


def state_covariance(objective: BatchObjective, params: np.ndarray, robust: bool) -> np.ndarray:
    """(n, n) covariance of the state's local perturbation at params: the state block of
    inv(J^T W J), carried from the parameters to the perturbation at the estimate."""
    _, J = weighted_jacobian(objective, params, robust)
    to_local = objective.start.plus_jacobian(params[: objective.n])
    cov = to_local @ np.linalg.inv(J.T @ J)[: objective.n, : objective.n] @ to_local.T
    return 0.5 * (cov + cov.T)


def batch(problem: CalibrationProblem, options: MethodOptions) -> Calibration:
    """The batch optimum over all frames (see the module doc)."""
    start_time = time.perf_counter()
    start_point = initial_state(problem, options)
    start, source = start_point.state, start_point.source
    objective = BatchObjective(problem, start, initial_covariance(start, options), options.prior)
    with threadpool_limits(limits=1, user_api="blas"):
        params, iterations = gauss_newton(objective, np.zeros(objective.size), options.robust)
        state = start.plus(params[: objective.n])
        cov = state_covariance(objective, params, options.robust)
    rejected = outliers(problem, objective.frame_residuals(params)) if options.robust else set()
    return calibration_from_state(
        "batch",
        problem,
        state,
        cov,
        rejected,
        {
            "iterations": iterations,
            "time_s": time.perf_counter() - start_time,
            "initialisation": source,
        },
    )


def outliers(problem: CalibrationProblem, residuals: list[np.ndarray]) -> set[tuple[int, int]]:
    """(frame, marker_id) whose whitened residual fails the filters' chi-square gate at the optimum:
    the Huber loss down-weighted them."""
    out = set()
    for frame, residual in zip(problem.frames, residuals, strict=True):
        for m, rows in zip(frame.markers, marker_rows(frame), strict=True):
            if np.sum(residual[rows] ** 2) > chi2.ppf(GATE_PROBABILITY, rows.stop - rows.start):
                out.add((frame.frame, m.marker_id))
    return out
