"""ukf: an error-state unscented Kalman filter over T_flange_cam and the board (or landmarks).

The model, the start and the bookkeeping are those of estimator.solve.filters (ekf, iekf): the
state is static, each waypoint is one update with all of its markers, and the error
delta (6,) of that waypoint's reported flange pose joins the state for the update with
prior N(0, robot noise) and is marginalised after it. What differs is the update: no
Jacobians, the measurement statistics come from sigma points.

Update. a (n_a,) is the perturbation of the augmented state [state (dim); delta (6)]
(delta left out when the robot noise is zero), prior N(0, P_a), P_a = blockdiag(P, robot
covariance); a moves the state by HandEyeState.plus and the flange pose by lie.pose_plus.
The filter sees the whitened measurement W z, predicted as W h(a) = W z - r(a), where
r(a) is the whitened residual of measurement_model.predict_frame; its noise is I. Sigma
points a_0 = 0 and a_{+-j} = +-s L_j (columns of L, L L^T = P_a), with e_j = r(a_j) - r(0)
and the weight w = 1 / (2 s^2) of every point but the centre:

    predicted mean       W z - (r(0) + mu),   mu = w sum_j e_j
    innovation           nu = r(0) + mu
    innovation cov.      S = w sum_j e_j e_j^T + (beta - alpha^2) mu mu^T + I      (m, m)
    cross covariance     C = -w sum_j a_j e_j^T                                   (n_a, m)
    update               a+ = C S^-1 nu,   P_a+ = P_a - C S^-1 C^T

This is the scaled unscented transform (Julier 2002) with n_a + lambda = s^2 (alpha =
s / sqrt(n_a), kappa = 0) and beta = 2 (Gaussian prior), written about the centre point
instead of about the mean: the same numbers, but cancellation-free, and positive
semi-definite for any spread as long as beta >= alpha^2. The centre's mean weight
1 - 1 / s^2 is large and negative, yet S is at least the (positive) weighted scatter of
the e_j, so [[P_a, C], [C^T, S]] is positive semi-definite and so is P_a+, its Schur
complement.

The spread: the sigma points sit at s = 1e-3 standard deviations, whatever n_a (about 18
for the board, 108 for 8 markers' landmarks). The starting covariance (filters.
initial_covariance) stands for "no prior": 0.5 m and 1 rad. Sampled at the usual spread
(alpha = 1: +-sqrt(n_a) sigma, 4 to 10 rad), sigma points put the camera behind the board
and the filter diverges; on the default scenes (30 random mounts) every spread from about
0.005 sigma (landmarks) or 0.01 sigma (board) up diverged in some trials, 1e-3 and below
did not. With a starting covariance of centimetres and degrees every spread up to
alpha = 1 gives the ekf's result. At this spread the filter is the ekf with
derivative-free Jacobians plus the second-order terms of the unscented transform: the
mean shift mu (half the trace of the Hessian with P_a) and its covariance beta mu mu^T.
In the first waypoints, when P_a is still the wide start, these are large along a few
measurement directions and discount them; later, when P_a is small, they vanish and ukf
and ekf agree. The early shifts are not undone exactly: without noise the board model
ends 3e-7 m and 8e-7 rad from the truth, the landmark model 1e-5 m, and landmarks with a
depth scale 0.4 mm with the scale 0.06 % low (ekf, iekf: rounding). With noise (20 random
mounts) the landmark model reaches 1.07x its Cramer-Rao bound with NEES 6.6 (ekf 1.06x, 6.5).

Gating (options.robust): a marker whose normalised innovation nu_k^T inv(S_kk) nu_k
exceeds the chi-square quantile of filters.GATE_PROBABILITY is left out of the update.
The unscented S_kk is used rather than filters.gate_markers (a Jacobian's H P H^T + I) so
that the gate tests the same statistics the update uses, mean shift included.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.stats import chi2

from estimator.solve.calibration import Calibration, MethodOptions, calibration_from_state
from estimator.solve.filters import (
    GATE_PROBABILITY,
    apply_prior,
    initial_covariance,
    marker_rows,
    prior_first,
)
from estimator.solve.initialise import initial_state
from estimator.solve.measurement_model import HandEyeState, predict_frame
from estimator.solve.problem import CalibrationProblem, FrameMeasurements

# Sigma points at +-SPREAD standard deviations: n_a + lambda = SPREAD^2 (see the module doc).
SPREAD = 1e-3
# Gaussian prior: beta = 2 matches its fourth moment.
BETA = 2.0


def augmented_covariance(problem: CalibrationProblem, P: np.ndarray) -> np.ndarray:
    """(n_a, n_a) prior covariance of [state perturbation; flange pose error delta]:
    blockdiag(P, robot covariance), or P alone when the robot noise is zero."""
    if problem.robot_noise.is_zero:
        return P
    n = len(P)
    P_a = np.zeros((n + 6, n + 6))
    P_a[:n, :n] = P
    P_a[n:, n:] = problem.robot_noise.covariance()
    return P_a


def sigma_points(P_a: np.ndarray) -> np.ndarray:
    """(2 n_a, n_a) sigma points +-SPREAD L_j of N(0, P_a) (rows; the centre 0 is implied),
    each with the weight 1 / (2 SPREAD^2)."""
    columns = SPREAD * np.linalg.cholesky(P_a).T
    return np.concatenate([columns, -columns])


def whitened_residual(
    problem: CalibrationProblem, state: HandEyeState, frame: FrameMeasurements, a: np.ndarray
) -> np.ndarray:
    """(m,) whitened residual W (z - h) of one frame at the augmented perturbation a (n_a,):
    state.plus(a[:dim]), and the reported flange pose perturbed by a[dim:] when present."""
    n = state.dim
    delta = a[n:] if len(a) > n else None
    return predict_frame(problem, state.plus(a[:n]), frame, delta, jacobians=False).residual


def gate(frame: FrameMeasurements, innovation: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Boolean row mask (m,) of the markers whose normalised innovation passes the chi-square
    gate, and the IDs of those that fail it. innovation: (m,); S: (m, m) its covariance."""
    keep = np.ones(len(innovation), dtype=bool)
    failed = []
    for m, rows in zip(frame.markers, marker_rows(frame), strict=True):
        nis = float(innovation[rows] @ np.linalg.solve(S[rows, rows], innovation[rows]))
        if nis > chi2.ppf(GATE_PROBABILITY, rows.stop - rows.start):
            keep[rows] = False
            failed.append(m.marker_id)
    return keep, failed


def update_frame(
    problem: CalibrationProblem, state: HandEyeState, P: np.ndarray, frame: FrameMeasurements, robust: bool
) -> tuple[HandEyeState, np.ndarray, list[int]]:
    """One waypoint's unscented update (see the module doc). P: (dim, dim) covariance of the
    state perturbation. Returns the new state, its (dim, dim) covariance (delta marginalised)
    and the marker IDs rejected by the gate."""
    P_a = augmented_covariance(problem, P)
    points = sigma_points(P_a)
    weight = 0.5 / SPREAD**2
    r_centre = whitened_residual(problem, state, frame, np.zeros(len(P_a)))
    E = np.array([whitened_residual(problem, state, frame, a) for a in points]) - r_centre  # (2 n_a, m)
    mu = weight * E.sum(axis=0)
    innovation = r_centre + mu
    alpha_squared = SPREAD**2 / len(P_a)
    S = weight * E.T @ E + (BETA - alpha_squared) * np.outer(mu, mu) + np.eye(len(mu))
    C = -weight * points.T @ E
    keep, rejected = gate(frame, innovation, S) if robust else (np.ones(len(mu), dtype=bool), [])
    gain_T = cho_solve(cho_factor(S[np.ix_(keep, keep)]), C[:, keep].T)  # (m_kept, n_a): S^-1 C^T
    a = gain_T.T @ innovation[keep]
    P_post = P_a - C[:, keep] @ gain_T
    n = state.dim
    return state.plus(a[:n]), 0.5 * (P_post[:n, :n] + P_post[:n, :n].T), rejected


def ukf(problem: CalibrationProblem, options: MethodOptions) -> Calibration:
    """Unscented Kalman filter over all frames in order; starts where ekf and iekf start.
    Returns method 'ukf', T_flange_cam with its (6, 6) covariance (estimator.geometry.lie convention)."""
    start = time.perf_counter()
    start_point = initial_state(problem, options)
    state, source = start_point.state, start_point.source
    P = initial_covariance(state, options)
    if prior_first(options, start_point):
        state, P = apply_prior(state, P, options.prior)
    rejected: set[tuple[int, int]] = set()
    for frame in problem.frames:
        state, P, failed = update_frame(problem, state, P, frame, options.robust)
        rejected |= {(frame.frame, marker_id) for marker_id in failed}
    if options.prior is not None and not prior_first(options, start_point):
        state, P = apply_prior(state, P, options.prior)
    elapsed = time.perf_counter() - start
    return calibration_from_state(
        "ukf",
        problem,
        state,
        P,
        rejected,
        {"iterations": len(problem.frames), "time_s": elapsed, "initialisation": source},
    )
