"""batch: the maximum-likelihood (maximum a posteriori with the wide prior) reference.

Jointly optimises T_flange_cam, the board pose (or landmarks), the optional depth
scale and every frame's flange pose error delta_i over all whitened reprojection
and depth residuals, the robot-noise prior of each delta_i, the user's prior on
T_flange_cam if given, and the same wide prior on the state the filters start from.
Parameters are perturbations of the starting state (hec.estimator.geometry.lie convention), so the
result is comparable with the filters.
Gauss-Newton with step halving (iteratively reweighted for a Huber loss on the whitened
residuals when robust) on the normal equations of the analytic Jacobian, solved by the Schur
complement over the per-frame deltas (each frame's residuals depend on the state and on its own
delta only: hec.estimator.solve.block_arrow). (scipy's least_squares reached the same optimum: its exact
trust-region solver took ~10x longer, its sparse one, LSMR, did not converge in 300 evaluations.)
Solves run on one BLAS thread: OpenBLAS threads made them 10x slower on a busy 2-core machine.
Covariance: the state block of inv(J^T W J) at the optimum (W the Huber weights).
"""

from __future__ import annotations

import functools
import time
from contextlib import AbstractContextManager
from dataclasses import dataclass

import numpy as np
from threadpoolctl import ThreadpoolController

from hec.estimator.geometry.lie import pose_plus_jacobian_rows
from hec.estimator.solve.block_arrow import BlockLayout, global_inverse, normal_solve
from hec.estimator.solve.calibration import Calibration, MethodOptions, Prior, calibration_from_state
from hec.estimator.solve.filters import gate_threshold, initial_covariance, marker_rows
from hec.estimator.solve.initialise import initial_state
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.noise_levels import NoiseLevels
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.stacked_prediction import (
    StackedFrames,
    StackedPrediction,
    predict_frames,
    stacked_frames,
)

# Whitened residuals beyond this many sigmas are down-weighted (Huber).
HUBER_SCALE = 3.0
GN_MAX_ITERATIONS = 50
GN_STEP_TOLERANCE = 1e-12
GN_COST_TOLERANCE = 1e-10
LINE_SEARCH_HALVINGS = 10


class OutsideModel(Exception):
    """Parameters the model cannot take (a self-calibrated focal length at or below zero): the
    line search counts them as infinitely costly and halves the step."""


@functools.cache
def _threadpools() -> ThreadpoolController:
    return ThreadpoolController()


def one_blas_thread() -> AbstractContextManager:
    """A context limiting BLAS to one thread (the controller, slow to build, is built once)."""
    return _threadpools().limit(limits=1, user_api="blas")


class BatchObjective:
    """Residuals and Jacobian over params = [state perturbation (n), delta_1 .. delta_N (6 each)]:
    rows [the state's prior (n), the user's prior (6, if given), per frame its whitened
    measurements and its delta's prior (6, with robot noise)], all frames predicted at once
    (hec.estimator.solve.stacked_prediction). With levels, the objective of
    noise_levels.scaled_problem(problem, levels) without building that problem: the stacked
    whitening scaled, the robot noise levels'; problem keeps the declared whitening (use stacked's)."""

    def __init__(
        self,
        problem: CalibrationProblem,
        start: HandEyeState,
        P0: np.ndarray,
        prior: Prior | None,
        levels: NoiseLevels | None = None,
        declared: StackedFrames | None = None,
    ) -> None:
        self.problem, self.start, self.P0, self.prior, self.levels = problem, start, P0, prior, levels
        self.n = start.dim
        robot_noise = problem.robot_noise if levels is None else levels.robot
        self.with_robot = not robot_noise.is_zero
        self.prior_sqrt_info = np.linalg.cholesky(np.linalg.inv(P0)).T
        self.robot_sqrt_info = (
            np.diag(1.0 / np.sqrt(np.diag(robot_noise.covariance()))) if self.with_robot else None
        )
        self.declared = declared or stacked_frames(problem, start.T_base_board is not None)
        self.stacked = (
            self.declared if levels is None else self.declared.scaled(levels.pixel_scale, levels.depth_scale)
        )
        self._rows()

    def at_levels(self, levels: NoiseLevels) -> BatchObjective:
        """This objective's problem at noise levels (see the class doc), its stack reused."""
        return BatchObjective(self.problem, self.start, self.P0, self.prior, levels, self.declared)

    def _rows(self) -> None:
        """Where each frame's rows sit: measurement_rows (R,) the stacked rows' places, robot_rows
        (N, 6) the deltas' prior rows (empty without robot noise), and the block layout."""
        counts = self.stacked.frame_row_counts
        robot = 6 if self.with_robot else 0
        head = self.n + (6 if self.prior is not None else 0)
        first = head + np.concatenate([[0], np.cumsum(counts + robot)[:-1]]).astype(int)
        offsets = np.cumsum(counts) - counts  # each frame's first row in the stack
        frame = self.stacked.frame_of_row
        self.measurement_rows = first[frame] + np.arange(len(frame)) - offsets[frame]
        self.robot_rows = (first + counts)[:, None] + np.arange(robot)
        self.row_count = head + int(counts.sum()) + robot * len(counts)
        local = [
            (slice(f, f + c + 6), slice(self.n + 6 * i, self.n + 6 * i + 6))
            for i, (f, c) in enumerate(zip(first, counts, strict=True))
        ]
        self.layout = BlockLayout(np.arange(self.n), local if self.with_robot else [])

    @property
    def size(self) -> int:
        return self.n + (6 * len(self.problem.frames) if self.with_robot else 0)

    def _deltas(self, params: np.ndarray) -> np.ndarray | None:
        """(N, 6) the frames' flange pose perturbations, None without robot noise."""
        return params[self.n :].reshape(-1, 6) if self.with_robot else None

    def _predict(
        self, params: np.ndarray, jacobians: bool, camera: bool = False
    ) -> tuple[HandEyeState, StackedPrediction]:
        state = self.start.plus(params[: self.n])
        return state, predict_frames(
            self.problem, self.stacked, state, self._deltas(params), jacobians, camera
        )

    def residuals(self, params: np.ndarray) -> np.ndarray:
        state, pred = self._predict(params, jacobians=False)
        return self._residuals(params, state, pred)

    def _residuals(self, params: np.ndarray, state: HandEyeState, pred: StackedPrediction) -> np.ndarray:
        r = np.empty(self.row_count)
        r[: self.n] = self.prior_sqrt_info @ params[: self.n]
        if self.prior is not None:
            r[self.n : self.n + 6] = self.prior.whitened_error(state.T_flange_cam)[0]
        r[self.measurement_rows] = -pred.residual
        if self.with_robot:
            r[self.robot_rows] = self._deltas(params) @ self.robot_sqrt_info.T
        return r

    def jacobian(self, params: np.ndarray) -> np.ndarray:
        """(rows, size) dense Jacobian of residuals(params); each frame's rows depend on the state
        and on that frame's delta only (the rest of the row is zero)."""
        return self.linearise(params)[1]

    def linearise(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """residuals(params) and jacobian(params) from one prediction (the same numbers)."""
        r, J, _, _ = self.linearise_with_prediction(params)
        return r, J

    def linearise_with_prediction(
        self, params: np.ndarray, camera: bool = False
    ) -> tuple[np.ndarray, np.ndarray, HandEyeState, StackedPrediction]:
        """linearise's residuals and Jacobian, and the state and prediction they come from (with
        camera, what measurement_model.camera_jacobian_rows needs)."""
        state, pred = self._predict(params, jacobians=True, camera=camera)
        r = self._residuals(params, state, pred)
        to_params = state.plus_jacobian(params[: self.n])
        J = np.zeros((self.row_count, self.size))
        J[: self.n, : self.n] = self.prior_sqrt_info
        if self.prior is not None:
            J[self.n : self.n + 6, :6] = self.prior.whitened_error(state.T_flange_cam)[1] @ to_params[:6, :6]
        rows = self.measurement_rows
        J[rows, : self.n] = pred.J_state @ to_params
        if self.with_robot:
            frame = self.stacked.frame_of_row
            steps = pose_plus_jacobian_rows(self._deltas(params))
            columns = self.n + 6 * frame[:, None] + np.arange(6)
            J[rows[:, None], columns] = np.einsum("rk,rkl->rl", pred.J_flange, steps[frame])
            delta_columns = self.n + 6 * np.arange(len(self.robot_rows))[:, None, None] + np.arange(6)
            J[self.robot_rows[:, :, None], delta_columns] = self.robot_sqrt_info
        return r, J, state, pred

    def frame_residuals(self, params: np.ndarray) -> list[np.ndarray]:
        """Whitened measurement residual of each frame at params."""
        _, pred = self._predict(params, jacobians=False)
        return np.split(pred.residual, np.cumsum(self.stacked.frame_row_counts)[:-1])


def huber_weights(r: np.ndarray) -> np.ndarray:
    """Per-residual IRLS weights of the Huber loss at HUBER_SCALE (whitened units)."""
    a = np.abs(r)
    return np.where(a <= HUBER_SCALE, 1.0, HUBER_SCALE / np.maximum(a, 1e-300))


def robust_cost(r: np.ndarray, robust: bool) -> float:
    """The least-squares cost of whitened residuals r, Huber's with robust."""
    if not robust:
        return float(r @ r)
    a = np.abs(r)
    return float(np.sum(np.where(a <= HUBER_SCALE, a * a, 2 * HUBER_SCALE * a - HUBER_SCALE**2)))


@dataclass
class GaussNewton:
    """gauss_newton's result: the parameters, the iterations run, and the residuals and Jacobian
    (unweighted) at the parameters."""

    params: np.ndarray
    iterations: int
    residuals: np.ndarray
    jacobian: np.ndarray


def gauss_newton(
    objective: BatchObjective, x0: np.ndarray, robust: bool, cost_tolerance: float = GN_COST_TOLERANCE
) -> GaussNewton:
    """The (Huber-weighted, with robust) least-squares optimum of the batch objective from x0:
    Gauss-Newton with step halving on the normal equations (block_arrow.normal_solve).
    Stops when a step lowers the cost by less than cost_tolerance of it (or cannot lower it).
    Each point tried is linearised at once (objective.linearise): the Jacobian of an accepted point
    is the next step's, and the last one's is returned."""
    layout = objective.layout
    x, (r, J) = x0, objective.linearise(x0)
    current = robust_cost(r, robust)
    iterations = 0
    while iterations < GN_MAX_ITERATIONS:
        iterations += 1
        root_w = np.sqrt(huber_weights(r)) if robust else np.ones_like(r)
        step = -normal_solve(J * root_w[:, None], r * root_w, layout)
        for _ in range(LINE_SEARCH_HALVINGS):
            moved = x + step
            try:
                r_moved, J_moved = objective.linearise(moved)
            except OutsideModel:
                step = 0.5 * step
                continue
            trial = robust_cost(r_moved, robust)
            if trial <= current:
                break
            step = 0.5 * step
        else:
            break
        x, r, J, previous, current = moved, r_moved, J_moved, current, trial
        if np.max(np.abs(step)) < GN_STEP_TOLERANCE or previous - current < cost_tolerance * previous:
            break
    return GaussNewton(x, iterations, r, J)


def weighted_jacobian(
    objective: BatchObjective, params: np.ndarray, robust: bool, at: GaussNewton | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The residuals at params and the Jacobian whose rows carry the square root of their Huber
    weights (robust) or are as they are: J^T J is then the information of the optimum. at: a
    Gauss-Newton result at params, whose residuals and Jacobian are used."""
    r, J = objective.linearise(params) if at is None else (at.residuals, at.jacobian)
    return r, J * np.sqrt(huber_weights(r))[:, None] if robust else J


def state_covariance(
    objective: BatchObjective, params: np.ndarray, robust: bool, at: GaussNewton | None = None
) -> np.ndarray:
    """(n, n) covariance of the state's local perturbation at params: the state block of
    inv(J^T W J) (the Schur complement's inverse), carried from the parameters to the perturbation
    at the estimate. at: as weighted_jacobian's."""
    _, J = weighted_jacobian(objective, params, robust, at)
    to_local = objective.start.plus_jacobian(params[: objective.n])
    n = objective.n  # the state: the first of the global columns
    cov = to_local @ global_inverse(J, objective.layout)[:n, :n] @ to_local.T
    return 0.5 * (cov + cov.T)


def batch(problem: CalibrationProblem, options: MethodOptions) -> Calibration:
    """The batch optimum over all frames (see the module doc)."""
    start_time = time.perf_counter()
    start_point = initial_state(problem, options)
    start, source = start_point.state, start_point.source
    objective = BatchObjective(problem, start, initial_covariance(start, options), options.prior)
    with one_blas_thread():
        optimum = gauss_newton(objective, np.zeros(objective.size), options.robust)
        params, iterations = optimum.params, optimum.iterations
        state = start.plus(params[: objective.n])
        cov = state_covariance(objective, params, options.robust, optimum)
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
            if np.sum(residual[rows] ** 2) > gate_threshold(rows.stop - rows.start):
                out.add((frame.frame, m.marker_id))
    return out
