"""ekf and iekf: error-state Kalman filters over T_flange_cam and the board (or landmarks).

The state is static, so there is no prediction; each waypoint is one update with
all of its markers (the filter can run online as frames arrive). The reported
flange pose of that waypoint is a measurement too: its error delta (6,) joins the
state for the update with prior N(0, robot noise) and is marginalised out after
it, which is exact for the linearised model and lets iekf relinearise it. Updates
use the information form with whitened measurements (R = I):

    P+ = inv(inv(P_a) + H^T H),   a_{j+1} = P+ H^T (r_j + H a_j)

with a the perturbation of the augmented state, r_j the whitened residual and H
its Jacobian at the j-th iterate (ekf: one iterate, iekf: until the step is below
tolerance). The state is then moved to the estimate (hec.estimator.geometry.lie convention).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from hec.estimator.geometry.lie import pose_plus_jacobian
from hec.estimator.solve.calibration import (
    DEFAULT_PRIOR_SIGMA_M,
    DEFAULT_PRIOR_SIGMA_RAD,
    Calibration,
    MethodOptions,
    Prior,
    calibration_from_state,
)
from hec.estimator.solve.initialise import Start, initial_state
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.problem import CalibrationProblem, FrameMeasurements

IEKF_MAX_ITERATIONS = 10
IEKF_TOLERANCE = 1e-10
LINE_SEARCH_HALVINGS = 20
# A marker whose innovation exceeds this chi-square quantile is rejected (robust option).
GATE_PROBABILITY = 1.0 - 1e-4
DEPTH_SCALE_PRIOR_SIGMA = 0.05
# Landmarks start at the closed-form board corners (a few mm off) with this sigma. A single
# linearisation about landmarks 0.5 m uncertain is far off after the first frame: ekf then
# ended 34x the Cramer-Rao bound (NEES 250); with 1 cm it reaches 0.84x (NEES 5.8).
DEFAULT_LANDMARK_SIGMA_M = 0.01


@functools.cache
def gate_threshold(dof: int) -> float:
    """The chi-square gate on a whitened innovation of dof rows (GATE_PROBABILITY quantile)."""
    return float(chi2.ppf(GATE_PROBABILITY, dof))


def initial_covariance(state: HandEyeState, options: MethodOptions) -> np.ndarray:
    """(dim, dim) starting covariance: wide for T_flange_cam and the board pose (a user's prior is
    fused by apply_prior), DEFAULT_LANDMARK_SIGMA_M for landmarks, DEPTH_SCALE_PRIOR_SIGMA for the
    depth scale."""
    wide_pose = np.array([DEFAULT_PRIOR_SIGMA_M**2] * 3 + [DEFAULT_PRIOR_SIGMA_RAD**2] * 3)
    diag = np.full(state.dim, DEFAULT_LANDMARK_SIGMA_M**2)
    diag[6:12] = wide_pose if state.T_base_board is not None else diag[6:12]
    if state.depth_scale is not None:
        diag[-1] = DEPTH_SCALE_PRIOR_SIGMA**2
    diag[:6] = wide_pose
    return np.diag(diag)


def prior_first(options: MethodOptions, start: Start) -> bool:
    """Whether a filter fuses the user's prior before the frames. Started at the prior's mean (no
    closed form), the prior is its initial belief: without it the unobservable directions wander.
    Started at the closed form, the prior joins last: a wide prior far from that start would drag
    the linearisation point away before the data pin the mount down."""
    return options.prior is not None and start.frames_used == 0


def apply_prior(state: HandEyeState, P: np.ndarray, prior: Prior) -> tuple[HandEyeState, np.ndarray]:
    """Fuse a prior on T_flange_cam as a measurement (iterated to convergence, it is nearly linear)."""
    n = state.dim
    info = np.linalg.inv(P)
    a = np.zeros(n)
    for _ in range(IEKF_MAX_ITERATIONS):
        error, J = prior.whitened_error(state.plus(a).T_flange_cam)
        H = np.zeros((6, n))
        H[:, :6] = J @ pose_plus_jacobian(a[:6])
        P_post = np.linalg.inv(info + H.T @ H)
        a_next = P_post @ (H.T @ (H @ a - error))
        step = np.linalg.norm(a_next - a)
        a = a_next
        if step < IEKF_TOLERANCE:
            break
    return state.plus(a), 0.5 * (P_post + P_post.T)


def marker_rows(frame: FrameMeasurements) -> list[slice]:
    """The rows of each marker of a frame in its stacked whitened residual."""
    rows, start = [], 0
    for m in frame.markers:
        rows.append(slice(start, start + m.whitening.shape[0]))
        start += m.whitening.shape[0]
    return rows


def gate_markers(
    frame: FrameMeasurements, residual: np.ndarray, H: np.ndarray, P_a: np.ndarray
) -> tuple[np.ndarray, list[int]]:
    """Boolean row mask (m,) keeping markers whose innovation passes the chi-square gate,
    and the marker IDs that fail it. H: (m, n_a) Jacobian of the whitened prediction."""
    keep = np.ones(len(residual), dtype=bool)
    failed = []
    HP = H @ P_a
    for m, rows in zip(frame.markers, marker_rows(frame), strict=True):
        Hk = H[rows]
        S = HP[rows] @ Hk.T + np.eye(len(Hk))
        nis = float(residual[rows] @ np.linalg.solve(S, residual[rows]))
        if nis > gate_threshold(len(Hk)):
            keep[rows] = False
            failed.append(m.marker_id)
    return keep, failed


def update(
    problem: CalibrationProblem,
    state: HandEyeState,
    P: np.ndarray,
    frames: list[FrameMeasurements],
    max_iterations: int,
    robust: bool,
) -> tuple[HandEyeState, np.ndarray, int, set[tuple[int, int]]]:
    """One (iterated) update with the markers of one or more waypoints, each with its own
    flange pose error. Returns the new state, its covariance, the iterations run and the
    (frame, marker_id) pairs rejected by the gate."""
    n = state.dim
    with_robot = not problem.robot_noise.is_zero
    k = 6 if with_robot else 0
    n_a = n + k * len(frames)
    P_a = np.zeros((n_a, n_a))
    P_a[:n, :n] = P
    for j in range(len(frames) if with_robot else 0):
        P_a[n + 6 * j : n + 6 * j + 6, n + 6 * j : n + 6 * j + 6] = problem.robot_noise.covariance()
    info_prior = np.linalg.inv(P_a)

    def predictions(a: np.ndarray, jacobians: bool) -> list:
        moved = state.plus(a[:n])
        return [
            predict_frame(problem, moved, f, a[n + 6 * j : n + 6 * j + 6] if with_robot else None, jacobians)
            for j, f in enumerate(frames)
        ]

    def linearise(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residual and its Jacobian with respect to a (the perturbation at the prior)."""
        preds = predictions(a, True)
        H = np.zeros((sum(len(p.residual) for p in preds), n_a))
        to_a = state.plus_jacobian(a[:n])
        row = 0
        for j, pred in enumerate(preds):
            rows = slice(row, row + len(pred.residual))
            H[rows, :n] = pred.J_state @ to_a
            if with_robot:
                H[rows, n + 6 * j : n + 6 * j + 6] = pred.J_flange @ pose_plus_jacobian(
                    a[n + 6 * j : n + 6 * j + 6]
                )
            row = rows.stop
        return np.concatenate([p.residual for p in preds]), H

    def cost(a: np.ndarray) -> float:
        residual = np.concatenate([p.residual for p in predictions(a, False)])
        return float(a @ info_prior @ a + np.sum(residual[keep] ** 2))

    a = np.zeros(n_a)
    r, H = linearise(a)
    keep, rejected = np.ones(len(r), dtype=bool), set()
    if robust:
        row = 0
        for f in frames:
            rows = slice(row, row + sum(m.whitening.shape[0] for m in f.markers))
            keep[rows], failed = gate_markers(f, r[rows], H[rows], P_a)
            rejected |= {(f.frame, marker_id) for marker_id in failed}
            row = rows.stop
    for iteration in range(1, max_iterations + 1):
        H, r = H[keep], r[keep]
        P_post = np.linalg.inv(info_prior + H.T @ H)
        a_next = P_post @ (H.T @ (r + H @ a))
        if max_iterations > 1:
            a_next = _backtrack(cost, a, a_next)
        step = np.linalg.norm(a_next - a)
        a = a_next
        if iteration == max_iterations or step < IEKF_TOLERANCE:
            break
        r, H = linearise(a)
    P_post = 0.5 * (P_post + P_post.T)
    return state.plus(a[:n]), P_post[:n, :n], iteration, rejected


def _backtrack(cost: Callable[[np.ndarray], float], a: np.ndarray, a_next: np.ndarray) -> np.ndarray:
    """Halve the Gauss-Newton step until the posterior cost does not increase (damped IEKF):
    far from the estimate, in directions one frame barely constrains, full steps overshoot."""
    current = cost(a)
    for _ in range(LINE_SEARCH_HALVINGS):
        if cost(a_next) <= current:
            return a_next
        a_next = a + 0.5 * (a_next - a)
    return a


@dataclass
class FilterStep:
    """The filter after one update: the last frame it took in, the state and its covariance
    (dim, dim), the iterations this update ran and the (frame, marker_id) pairs it rejected."""

    frame: int
    state: HandEyeState
    covariance: np.ndarray
    iterations: int
    rejected: set[tuple[int, int]]


def update_groups(problem: CalibrationProblem, start: Start) -> list[list[FrameMeasurements]]:
    """The frames of each filter update, in order: the frames the closed form came from together
    (before they are all in, the mount is not determined and a step would follow unconstrained
    directions), then one frame at a time."""
    first = max(start.frames_used, 1)
    return [problem.frames[:first]] + [[f] for f in problem.frames[first:]]


def filter_steps(
    problem: CalibrationProblem, options: MethodOptions, iterated: bool, start: Start | None = None
) -> Iterator[FilterStep]:
    """ekf (iterated=False) or iekf over the frames in order, one step per update (update_groups).
    A prior fused after the frames (see prior_first) comes as a last step with frame -1."""
    start = start or initial_state(problem, options)
    state = start.state
    P = initial_covariance(state, options)
    if prior_first(options, start):
        state, P = apply_prior(state, P, options.prior)
    max_iterations = IEKF_MAX_ITERATIONS if iterated else 1
    for frames in update_groups(problem, start):
        state, P, used, rejected = update(problem, state, P, frames, max_iterations, options.robust)
        yield FilterStep(frames[-1].frame, state, P, used, rejected)
    if options.prior is not None and not prior_first(options, start):
        state, P = apply_prior(state, P, options.prior)
        yield FilterStep(-1, state, P, 0, set())


def run_filter(problem: CalibrationProblem, options: MethodOptions, iterated: bool) -> Calibration:
    """ekf (iterated=False) or iekf over all frames in order."""
    start = time.perf_counter()
    start_point = initial_state(problem, options)
    iterations, rejected = 0, set()
    for step in filter_steps(problem, options, iterated, start_point):
        iterations += step.iterations
        rejected |= step.rejected
    return calibration_from_state(
        "iekf" if iterated else "ekf",
        problem,
        step.state,
        step.covariance,
        rejected,
        {
            "iterations": iterations,
            "time_s": time.perf_counter() - start,
            "initialisation": start_point.source,
        },
    )
