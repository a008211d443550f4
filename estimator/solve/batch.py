"""batch: the maximum-likelihood (maximum a posteriori with the wide prior) reference.

Jointly optimises T_flange_cam, the board pose (or landmarks), the optional depth
scale and every frame's flange pose error delta_i over all whitened reprojection
and depth residuals, the robot-noise prior of each delta_i, the user's prior on
T_flange_cam if given, and the same wide prior on the state the filters start from.
Parameters are perturbations of the starting state (estimator.geometry.lie convention), so the
result is comparable with the filters.
scipy.optimize.least_squares with an analytic Jacobian, assembled sparse (each
frame's residuals depend on the state and on its own delta only) and, when robust,
a Huber loss on the whitened residuals. The trust-region steps are solved exactly
on the dense matrix (a few hundred columns): scipy's sparse solver (LSMR) did not
converge in 300 evaluations on this badly scaled problem, the exact one does in ~12.
Covariance: the state block of inv(J^T J) at the optimum.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.stats import chi2

from estimator.geometry.lie import pose_plus_jacobian
from estimator.solve.calibration import Calibration, MethodOptions, Prior, calibration_from_state
from estimator.solve.filters import GATE_PROBABILITY, initial_covariance, marker_rows
from estimator.solve.initialise import initial_state
from estimator.solve.measurement_model import HandEyeState, predict_frame
from estimator.solve.problem import CalibrationProblem

# Whitened residuals beyond this many sigmas are down-weighted (Huber).
HUBER_SCALE = 3.0
TOLERANCE = 1e-12


class _Objective:
    """Residuals and sparse Jacobian over params = [state perturbation (n), delta_1 .. delta_N (6 each)]."""

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

    def jacobian(self, params: np.ndarray) -> sparse.csr_matrix:
        state = self.start.plus(params[: self.n])
        to_params = state.plus_jacobian(params[: self.n])
        n_frames = len(self.problem.frames)
        blocks = [[self.prior_sqrt_info] + [None] * n_frames]
        if self.prior is not None:
            J_prior = np.zeros((6, self.n))
            J_prior[:, :6] = self.prior.whitened_error(state.T_flange_cam)[1]
            blocks.append([J_prior @ to_params] + [None] * n_frames)
        for i, frame in enumerate(self.problem.frames):
            delta = self._delta(params, i)
            pred = predict_frame(self.problem, state, frame, delta)
            row = [pred.J_state @ to_params] + [None] * n_frames
            if self.with_robot:
                row[1 + i] = pred.J_flange @ pose_plus_jacobian(delta)
                prior_row = [sparse.csr_matrix((6, self.n))] + [None] * n_frames
                prior_row[1 + i] = self.robot_sqrt_info
                blocks += [row, prior_row]
            else:
                blocks.append(row[:1])
        if not self.with_robot:
            blocks = [row[:1] for row in blocks]
        return sparse.bmat(blocks, format="csr")

    def frame_residuals(self, params: np.ndarray) -> list[np.ndarray]:
        """Whitened measurement residual of each frame at params."""
        state = self.start.plus(params[: self.n])
        return [
            predict_frame(self.problem, state, frame, self._delta(params, i), jacobians=False).residual
            for i, frame in enumerate(self.problem.frames)
        ]


def batch(problem: CalibrationProblem, options: MethodOptions) -> Calibration:
    """The batch optimum over all frames (see the module doc)."""
    start_time = time.perf_counter()
    start_point = initial_state(problem, options)
    start, source = start_point.state, start_point.source
    objective = _Objective(problem, start, initial_covariance(start, options), options.prior)
    solution = least_squares(
        objective.residuals,
        np.zeros(objective.size),
        jac=lambda params: objective.jacobian(params).toarray(),
        loss="huber" if options.robust else "linear",
        f_scale=HUBER_SCALE,
        x_scale=1.0,
        ftol=TOLERANCE,
        xtol=TOLERANCE,
        gtol=TOLERANCE,
        method="trf",
        tr_solver="exact",
    )
    state = start.plus(solution.x[: objective.n])
    J = objective.jacobian(solution.x).toarray()
    # Covariance of the parameters, then of the local perturbation at the estimate.
    to_local = start.plus_jacobian(solution.x[: objective.n])
    cov = to_local @ np.linalg.inv(J.T @ J)[: objective.n, : objective.n] @ to_local.T
    rejected = _outliers(problem, objective.frame_residuals(solution.x)) if options.robust else set()
    return calibration_from_state(
        "batch",
        problem,
        state,
        0.5 * (cov + cov.T),
        rejected,
        {
            "iterations": int(solution.nfev),
            "time_s": time.perf_counter() - start_time,
            "initialisation": source,
            "optimizer": solution.message,
        },
    )


def _outliers(problem: CalibrationProblem, residuals: list[np.ndarray]) -> set[tuple[int, int]]:
    """(frame, marker_id) whose whitened residual fails the filters' chi-square gate at the optimum:
    the Huber loss down-weighted them."""
    out = set()
    for frame, residual in zip(problem.frames, residuals, strict=True):
        for m, rows in zip(frame.markers, marker_rows(frame), strict=True):
            if np.sum(residual[rows] ** 2) > chi2.ppf(GATE_PROBABILITY, rows.stop - rows.start):
                out.add((frame.frame, m.marker_id))
    return out
