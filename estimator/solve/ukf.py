"""ukf: an error-state unscented Kalman filter over T_flange_cam and the board (or landmarks).

The model, the start and the bookkeeping are those of hec.estimator.solve.filters (ekf, iekf): the
state is static; the first update takes the frames the closed form came from together (before
they are all in, the mount is not determined), each later waypoint is one update with all of
its markers; the error delta (6,) of each of an update's reported flange poses joins the state
for the update with prior N(0, robot noise) and is marginalised after it. What differs is the
update: no Jacobians, the measurement statistics come from sigma points.

Update. a (n_a,) is the perturbation of the augmented state [state (dim); deltas (6 each)]
(deltas left out when the robot noise is zero), prior N(0, P_a), P_a = blockdiag(P, robot
covariances) = L_a L_a^T; a moves the state by HandEyeState.plus and the flange poses by
lie.pose_plus. The filter sees the whitened measurement W z, predicted as W h(a) = W z - r(a),
where r(a) is the stacked whitened residual of the measurement model (whitened_residuals); its noise is I.
Sigma points a_0 = 0 and a_{+-j} = +-s L_j (columns of L = L_a), with e_{+-j} = r(a_{+-j}) - r(0),
q_j = e_{+j} + e_{-j} and the weight w = 1 / (2 s^2) of every point but the centre:

    mean shift           mu = w sum_j q_j                     (predicted mean W z - (r(0) + mu))
    cross covariance     C = L D,   row j of D: -w s (e_{+j} - e_{-j})                 (n_a, m)
    innovation cov.      S = D^T D + Omega + I,   Omega = w/2 sum_j q_j q_j^T + (beta - alpha^2) mu mu^T
    innovation           nu = r(0) + mu
    update               a+ = C S^-1 nu,   P_a+ = P_a - C S^-1 C^T

This is the scaled unscented transform (Julier 2002) with n_a + lambda = s^2 (alpha =
s / sqrt(n_a), kappa = 0) and beta = 2 (Gaussian prior), written about the centre point
instead of about the mean: the same numbers (D^T D + Omega is the weighted scatter
w sum e e^T plus (beta - alpha^2) mu mu^T), but cancellation-free. The centre's mean weight
1 - 1 / s^2 is large and negative, yet Omega, the spread of the measurement that is not linear
in a, is positive semi-definite for any spread as long as beta >= alpha^2, so
[[P_a, C], [C^T, S]] is positive semi-definite and so is P_a+, its Schur complement.

The first update is iterated: posterior linearisation (Garcia-Fernandez et al. 2015), the
sigma-point counterpart of iekf. Iterate k takes the sigma points about a_k with the spread of
P_k = L_k L_k^T (a_0 = 0, P_0 = P_a, the update above): D_k, Omega_k and mu_k as above give the
statistical linear regression of W h about N(a_k, P_k), slope A_k = D_k^T L_k^-1 with residual
covariance Omega_k, and the update of the prior N(0, P_a) through it is

    F = L_a^T A_k^T,   C = L_a F,   S = F^T F + Omega_k + I,   nu = r(a_k) + mu_k + A_k a_k

giving a_{k+1} and P_{k+1}, until the step is below ITERATION_TOLERANCE, but at least once
relinearised (the first iterate's statistics are those of the prior, however small its step,
as on exact data where the closed form is the truth): 3 or 4 iterates on the default scenes.
Where the model is linear A_k = H, Omega_k = 0 and this is iekf's Gauss-Newton iteration. The
gate is decided at k = 0.

Why. The sigma points sit at s = 1e-3 standard deviations, whatever n_a (about 18 for the board,
108 for 8 markers' landmarks). At this spread the filter is the ekf with derivative-free
Jacobians plus the second-order terms of the unscented transform: the mean shift mu (half the
trace of the Hessian with P_a) and its covariance (Omega). They mean something only when the
Gaussian does: the starting covariance (filters.initial_covariance) stands for "no prior", 0.5 m
and 1 rad, and with it they are extrapolations far past where the camera still sees the board
(first update, default scenes: |mu| about 1.7e4 against |r(0)| of 20-40). Taken one waypoint at
a time from the start, the second view, still that wide along the 6 directions one view leaves
free, had |mu| about 730 against |r(0)| of 12-27 and its update moved the state along them, a
median 49 mm (max 350 mm) over 20 random mounts with views alternating between 0.9 and 1.25
times the distance (2.6 mm, max 6 mm with all at one distance: there its shift nearly repeats
the first's); the third update, linearised from there, ended up to 47 mm off with sigmas of
4 mm, and in 4 of the 20 mounts the gate then rejected nearly every later marker (82-112 of 136),
ending 5-47 mm off; without the gate (learned noise) errors up to 26 mm and a mean NEES of 2750.
Taking the closed form's frames together leaves no free direction (20 mounts: max 0.36 mm, yet
up to 4.7x the ekf's error: the wide start's shift still biases the first update, 1.11 mm median
after it, ekf 0.95 mm). Iterating it evaluates the second-order terms at the posterior
(millimetres; |mu| 0.014) and it ends where the ekf's first update does (0.96 mm). Later updates
are single: P is then small, and a second iterate would move the state a median 3e-7 (max 2e-5)
against sigmas of 0.3-2 mm. Started from a prior (no closed form), no update determines the
mount and none is iterated: a lone frame's posterior stays wide along the directions it leaves
free, where relinearising only chases the shift (the paper's trajectory, a prior 0.4 degrees and
2 mm off: 17.6 degrees off iterated, 0.08 single). With the iterated start the spread hardly
matters: on 30 mounts every spread from 1e-3 to alpha = 1 gave the ekf's result for the board;
for landmarks (10 mounts) so did 1e-3 to 0.1 and alpha = 1, at 1 one mount failed (S not
positive definite). One waypoint at a time and not iterated (before, on views all at one
distance), every spread from about 0.005 (landmarks) or 0.01 (board) up diverged in some trials.

Results. Without noise the board model ends 2e-7 m and 1e-7 rad from the truth, the landmark
model 3e-7 m, and landmarks with a depth scale 2e-6 m with the scale 5e-7 low (ekf, iekf:
rounding): the filter matches the mean of the prediction, not the prediction at the mean, and
the mean shift at the first posterior (|mu| 0.014 noise sigmas) leaves 8e-7 m there, less as P
shrinks. With noise (20 random mounts, declared noise or learned) the error is within 1.015x the
ekf's on every mount, nothing is rejected and the mean NEES is the ekf's (5.3 declared, 5.7
learned); over 3 x 30 mounts the board model reaches 0.85-0.90x its Cramer-Rao bound in
translation and 0.87-1.05x in rotation, the landmark model 0.87-0.91x and 0.88-1.03x, with NEES
4.9-5.5 and 5.0-5.7 (ekf: the same).

Gating (options.robust): a marker whose normalised innovation nu_k^T inv(S_kk) nu_k
exceeds the chi-square quantile of filters.GATE_PROBABILITY is left out of the update.
The unscented S_kk is used rather than filters.gate_markers (a Jacobian's H P H^T + I) so
that the gate tests the same statistics the update uses, mean shift included.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from hec.estimator.solve.calibration import Calibration, MethodOptions, calibration_from_state
from hec.estimator.solve.filters import (
    IEKF_MAX_ITERATIONS,
    apply_prior,
    gate_threshold,
    initial_covariance,
    marker_rows,
    prior_first,
    update_groups,
)
from hec.estimator.solve.initialise import initial_state
from hec.estimator.solve.measurement_model import HandEyeState, base_points, marker_points, measurements
from hec.estimator.solve.problem import CalibrationProblem, FrameMeasurements
from hec.estimator.solve.setup_roles import flange_plus

# Sigma points at +-SPREAD standard deviations: n_a + lambda = SPREAD^2 (see the module doc).
SPREAD = 1e-3
# Gaussian prior: beta = 2 matches its fourth moment.
BETA = 2.0
# The first update's iterations stop at a step below this (metres, radians): far below the posterior
# sigmas (0.1 mm and up), above the rounding floor of the sigma-point differences at SPREAD (steps of
# 1e-8 to 3e-7 once converged, board to landmarks).
ITERATION_TOLERANCE = 1e-6


def augmented_covariance(problem: CalibrationProblem, P: np.ndarray, frames: int = 1) -> np.ndarray:
    """(n_a, n_a) prior covariance of [state perturbation; one flange pose error delta per frame]:
    blockdiag(P, robot covariance, ...), or P alone when the robot noise is zero."""
    if problem.robot_noise.is_zero:
        return P
    n = len(P)
    P_a = np.zeros((n + 6 * frames, n + 6 * frames))
    P_a[:n, :n] = P
    for j in range(frames):
        P_a[n + 6 * j : n + 6 * j + 6, n + 6 * j : n + 6 * j + 6] = problem.robot_noise.covariance()
    return P_a


def whitened_residuals(
    problem: CalibrationProblem, state: HandEyeState, frames: list[FrameMeasurements], A: np.ndarray
) -> np.ndarray:
    """(S, m) whitened residuals W (z - h) of the frames' markers, stacked, at each augmented
    perturbation of A (S, n_a): state.plus(a[:dim]), and frame j's reported flange pose perturbed by
    a[dim + 6 j : dim + 6 j + 6] when the robot noise is not zero. Every sigma point's camera points
    go through the camera and the detector's bias in one call (measurement_model.measurements)."""
    n = state.dim
    with_robot = A.shape[1] > n
    moved = [state.plus(a[:n]) for a in A]
    scales = np.array([1.0 if m.depth_scale is None else m.depth_scale for m in moved])
    out = []
    for j, frame in enumerate(frames):
        points = marker_points(problem, frame.markers, state.T_base_board is not None)
        p_cam = np.empty((len(A), len(points), 3))
        for k, (m, a) in enumerate(zip(moved, A, strict=True)):
            T_F = (
                flange_plus(problem.setup, frame.T_base_flange, a[n + 6 * j : n + 6 * j + 6])
                if with_robot
                else frame.T_base_flange
            )
            p_flange = (base_points(problem, m, points)[2] - T_F[:3, 3]) @ T_F[:3, :3]
            p_cam[k] = (p_flange - m.T_flange_cam[:3, 3]) @ m.T_flange_cam[:3, :3]
        predicted = measurements(problem, p_cam.reshape(-1, 3), np.repeat(scales, len(points)))[0]
        stacked = frame.stacked
        out.append((stacked.measured - predicted.reshape(len(A), -1)[:, stacked.rows]) @ stacked.whitening.T)
    return np.concatenate(out, axis=1)


def gate(
    frames: list[FrameMeasurements], innovation: np.ndarray, S: np.ndarray
) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Boolean row mask (m,) of the markers whose normalised innovation passes the chi-square
    gate, and the (frame, marker_id) pairs that fail it. innovation: (m,); S: (m, m) its covariance."""
    keep = np.ones(len(innovation), dtype=bool)
    failed = []
    offset = 0
    for f in frames:
        for m, local in zip(f.markers, marker_rows(f), strict=True):
            rows = slice(offset + local.start, offset + local.stop)
            nis = float(innovation[rows] @ np.linalg.solve(S[rows, rows], innovation[rows]))
            if nis > gate_threshold(rows.stop - rows.start):
                keep[rows] = False
                failed.append((f.frame, m.marker_id))
        offset += sum(m.whitening.shape[0] for m in f.markers)
    return keep, failed


def update(
    problem: CalibrationProblem,
    state: HandEyeState,
    P: np.ndarray,
    frames: list[FrameMeasurements],
    robust: bool,
    max_iterations: int = 1,
) -> tuple[HandEyeState, np.ndarray, int, list[tuple[int, int]]]:
    """One unscented update with the markers of one or more waypoints, each with its own flange
    pose error, iterated (posterior linearisation) up to max_iterations (see the module doc).
    P: (dim, dim) covariance of the state perturbation. Returns the new state, its (dim, dim)
    covariance (the deltas marginalised), the iterations run and the (frame, marker_id) pairs
    rejected by the gate (decided at the first iteration)."""
    P_a = augmented_covariance(problem, P, len(frames))
    n_a, n = len(P_a), state.dim
    weight = 0.5 / SPREAD**2
    alpha_squared = SPREAD**2 / n_a
    L_prior = np.linalg.cholesky(P_a)
    a, L = np.zeros(n_a), L_prior
    for iteration in range(1, max_iterations + 1):
        columns = SPREAD * L.T  # (n_a, n_a): the sigma points a +- columns (rows)
        residuals = whitened_residuals(problem, state, frames, np.vstack([a, a + columns, a - columns]))
        r_centre = residuals[0]
        E_plus, E_minus = residuals[1 : n_a + 1] - r_centre, residuals[n_a + 1 :] - r_centre
        Q = E_plus + E_minus  # (n_a, m) second differences
        mu = weight * Q.sum(axis=0)
        D = -weight * SPREAD * (E_plus - E_minus)  # (n_a, m): cross covariance L D, regression A^T = L^-T D
        Omega = 0.5 * weight * Q.T @ Q + (BETA - alpha_squared) * np.outer(mu, mu)
        if iteration == 1:
            F = D
            innovation = r_centre + mu
        else:
            A_T = solve_triangular(L, D, lower=True, trans="T")
            F = L_prior.T @ A_T
            innovation = r_centre + mu + A_T.T @ a
        S = F.T @ F + Omega + np.eye(len(mu))
        C = L_prior @ F
        if iteration == 1:
            keep, rejected = gate(frames, innovation, S) if robust else (np.ones(len(mu), dtype=bool), [])
        gain_T = cho_solve(cho_factor(S[np.ix_(keep, keep)]), C[:, keep].T)  # (m_kept, n_a): S^-1 C^T
        a_next = gain_T.T @ innovation[keep]
        P_post = P_a - C[:, keep] @ gain_T
        P_post = 0.5 * (P_post + P_post.T)
        step = np.linalg.norm(a_next - a)
        a = a_next
        if iteration == max_iterations or (iteration > 1 and step < ITERATION_TOLERANCE):
            break
        L = np.linalg.cholesky(P_post)
    return state.plus(a[:n]), P_post[:n, :n], iteration, rejected


def update_frame(
    problem: CalibrationProblem, state: HandEyeState, P: np.ndarray, frame: FrameMeasurements, robust: bool
) -> tuple[HandEyeState, np.ndarray, list[int]]:
    """One waypoint's unscented update, not iterated (see the module doc). P: (dim, dim) covariance
    of the state perturbation. Returns the new state, its (dim, dim) covariance (delta marginalised)
    and the marker IDs rejected by the gate."""
    new, P_new, _, rejected = update(problem, state, P, [frame], robust)
    return new, P_new, [marker_id for _, marker_id in rejected]


def ukf(problem: CalibrationProblem, options: MethodOptions) -> Calibration:
    """Unscented Kalman filter over all frames in order; starts where ekf and iekf start and,
    like them, takes the closed form's frames together in its first update, which it iterates (not
    when started from a prior).
    Returns method 'ukf', T_flange_cam with its (6, 6) covariance (hec.estimator.geometry.lie convention)."""
    start = time.perf_counter()
    start_point = initial_state(problem, options)
    state, source = start_point.state, start_point.source
    P = initial_covariance(state, options)
    if prior_first(options, start_point):
        state, P = apply_prior(state, P, options.prior)
    rejected: set[tuple[int, int]] = set()
    iterations = 0
    for k, frames in enumerate(update_groups(problem, start_point)):
        iterated = k == 0 and start_point.frames_used > 0
        state, P, used, failed = update(
            problem, state, P, frames, options.robust, IEKF_MAX_ITERATIONS if iterated else 1
        )
        iterations += used
        rejected |= set(failed)
    if options.prior is not None and not prior_first(options, start_point):
        state, P = apply_prior(state, P, options.prior)
    elapsed = time.perf_counter() - start
    return calibration_from_state(
        "ukf",
        problem,
        state,
        P,
        rejected,
        {"iterations": iterations, "time_s": elapsed, "initialisation": source},
    )
