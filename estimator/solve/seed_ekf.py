"""seed-ekf: the paper's EKF (camera pose and marker-centre landmarks in the base frame), made correct.

State, in this order (perturbations in the convention of hec.estimator.geometry.lie):

    T_base_cam       camera pose of the current frame          (dt base frame, dtheta camera axes), 6
    delta_flange     error of the current reported flange pose (true F = pose_plus(reported F, delta)), 6
    landmarks_base   centre of marker problem.marker_ids[k]    (base frame, metres), 3 per marker

Prediction moves the camera with the reported flange motion, T_base_cam_i = F_i inv(F_{i-1})
T_base_cam_{i-1}, which is exact for true flange poses (T_base_cam = F X). The errors of both
reported poses enter it (first order, Jacobians in ``motion``). Consecutive motions share a pose,
so its error is carried in the state (delta_flange) instead of being drawn twice as independent
process noise: the motion from F_{i-1} uses the current estimate of F_{i-1}'s error, with its
covariance and cross-covariance, and F_i's error joins the state with prior N(0, robot noise).
Landmarks are static.

Update, all markers of a frame at once: the marker centre in the camera frame from depth,
p_cam = inv(T_base_cam) m, with its (3, 3) covariance from the observation (markers without
depth are skipped and counted as rejected). A landmark seen for the first time is initialised
from its measurement and the updated camera pose, m = T_base_cam p_cam, with the full first-order
cross-covariance to the rest of the state (EKF-SLAM augmentation), after the frame's update with
the known landmarks. The update uses the Joseph form; the covariance is not transported to the
corrected pose (the correction is small).

The camera pose starts at F_0 X0: X0 from options.prior (with its covariance) or else from the
closed-form initialisation, with sigma INITIAL_SIGMA_M per flange axis and INITIAL_SIGMA_RAD per
camera axis. The result is X = T_flange_cam = inv(F_N) T_base_cam_N at the last frame, F_N the
reported pose corrected by the estimated delta_flange, with its (6, 6) covariance propagated to
first order from the joint covariance of (T_base_cam_N, delta_flange_N). The board pose of the
result is fitted to the landmarks (Kabsch) and only serves the residuals.

Like any single-pass EKF it needs a good start: from an X0 several degrees off (a prior instead
of the closed form) the first updates linearise far from the truth, the covariance becomes
overconfident and the chi-square gate (robust option) then rejects good markers.

What the paper's code got wrong and this does right: the state and covariance carry over between
steps, the Jacobians have the right signs (tested against finite differences), rotations stay
rotations (det +1), standard deviations are squared into variances, and new landmarks get a
non-zero covariance.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from hec.estimator.geometry.lie import pose_plus, pose_plus_jacobian, skew, skew_rows
from hec.estimator.geometry.transforms import invert, make_transform
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.calibration import Calibration, MethodOptions, marker_residuals
from hec.estimator.solve.filters import GATE_PROBABILITY
from hec.estimator.solve.initialise import initial_state
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.problem import CalibrationInputError, CalibrationProblem
from hec.estimator.solve.setup_roles import model_pose_covariance

INITIAL_SIGMA_M = 0.05
INITIAL_SIGMA_RAD = float(np.radians(5.0))
# A marker whose innovation exceeds the filters' chi-square quantile (3 dof) is rejected (robust option).
GATE_NIS = float(chi2.ppf(GATE_PROBABILITY, 3))
POSE = slice(0, 6)
DELTA = slice(6, 12)
LANDMARKS = 12


@dataclass
class SeedEkfState:
    """The filter after a frame (see the module doc for the state order).

    T_base_cam: (4, 4). delta_flange: (6,). landmarks_base: (k, 3), rows of problem.marker_ids,
    zero until known. known: (k,) bool. covariance: (12 + 3k, 12 + 3k); rows of unknown
    landmarks are zero.
    """

    T_base_cam: np.ndarray
    delta_flange: np.ndarray
    landmarks_base: np.ndarray
    known: np.ndarray
    covariance: np.ndarray


@dataclass
class FrameStep:
    """One processed frame: the state after it, and the marker IDs used and rejected."""

    frame: int
    state: SeedEkfState
    used: list[int]
    rejected: list[int]


def motion(
    T_base_cam: np.ndarray, T_base_flange_prev: np.ndarray, T_base_flange: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The camera moved with the flange: T_base_flange inv(T_base_flange_prev) T_base_cam.

    All (4, 4). Returns the new camera pose and the (6, 6) Jacobians of its perturbation with
    respect to the perturbations of T_base_cam, T_base_flange_prev and T_base_flange.
    """
    R_prev, R_cur = T_base_flange_prev[:3, :3], T_base_flange[:3, :3]
    T_flange_cam = invert(T_base_flange_prev) @ T_base_cam
    R_M = R_cur @ R_prev.T
    R_D_t = T_flange_cam[:3, :3].T
    lever = R_cur @ skew(T_flange_cam[:3, 3])
    G, J_prev, J_cur = np.eye(6), np.zeros((6, 6)), np.eye(6)
    G[:3, :3] = R_M
    J_cur[:3, 3:], J_cur[3:, 3:] = -lever, R_D_t
    J_prev[:3, :3], J_prev[:3, 3:], J_prev[3:, 3:] = -R_M, lever, -R_D_t
    return T_base_flange @ T_flange_cam, G, J_prev, J_cur


def predict(
    state: SeedEkfState,
    T_base_flange_prev: np.ndarray,
    T_base_flange: np.ndarray,
    robot_covariance: np.ndarray,
) -> SeedEkfState:
    """Move the camera from the previous frame (reported pose T_base_flange_prev, its error in the
    state) to the next (reported pose T_base_flange, new error with prior robot_covariance (6, 6))."""
    flange_prev = pose_plus(T_base_flange_prev, state.delta_flange)
    T_base_cam, G, J_prev, J_cur = motion(state.T_base_cam, flange_prev, T_base_flange)
    n = len(state.covariance)
    A = np.eye(n)
    A[POSE, POSE] = G
    A[POSE, DELTA] = J_prev @ pose_plus_jacobian(state.delta_flange)
    A[DELTA, DELTA] = 0.0
    B = np.zeros((n, 6))
    B[POSE] = J_cur
    B[DELTA] = np.eye(6)
    P = A @ state.covariance @ A.T + B @ robot_covariance @ B.T
    return SeedEkfState(T_base_cam, np.zeros(6), state.landmarks_base, state.known, 0.5 * (P + P.T))


def measure(T_base_cam: np.ndarray, landmarks_base: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmarks (n, 3, base frame) seen from the camera: p_cam = inv(T_base_cam) m, (n, 3), with
    its Jacobians (n, 3, 6) with respect to the camera pose perturbation and (3, 3) with respect to
    each landmark (the same for all)."""
    R = T_base_cam[:3, :3]
    p_cam = (landmarks_base - T_base_cam[:3, 3]) @ R
    H_pose = np.concatenate([np.broadcast_to(-R.T, (len(p_cam), 3, 3)), skew_rows(p_cam)], axis=2)
    return p_cam, H_pose, R.T


def _landmark_columns(rows: np.ndarray) -> np.ndarray:
    """State indices (3n,) of the landmarks in rows (n,)."""
    return (LANDMARKS + 3 * rows[:, None] + np.arange(3)).reshape(-1)


def _block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """(n, 3, 3) -> (3n, 3n)."""
    n = len(blocks)
    out = np.zeros((n, 3, n, 3))
    out[np.arange(n), :, np.arange(n), :] = blocks
    return out.reshape(3 * n, 3 * n)


def update(
    state: SeedEkfState, rows: np.ndarray, points_cam: np.ndarray, points_cov: np.ndarray, gate: bool
) -> tuple[SeedEkfState, np.ndarray]:
    """Update with known landmarks rows (n,) measured at points_cam (n, 3), covariances (n, 3, 3).
    gate: reject markers whose innovation fails the chi-square test. Returns the state and the
    (n,) mask of markers used."""
    predicted, H_pose, H_landmark = measure(state.T_base_cam, state.landmarks_base[rows])
    n, dim = len(rows), len(state.covariance)
    H = np.zeros((n, 3, dim))
    H[:, :, POSE] = H_pose
    columns = _landmark_columns(rows).reshape(n, 1, 3)
    H[np.arange(n)[:, None, None], np.arange(3)[None, :, None], columns] = H_landmark
    H = H.reshape(3 * n, dim)
    R = _block_diagonal(points_cov)
    innovation = (points_cam - predicted).reshape(-1)
    S = H @ state.covariance @ H.T + R
    keep = np.ones(n, dtype=bool)
    if gate:
        S_blocks = S.reshape(n, 3, n, 3)[np.arange(n), :, np.arange(n), :]
        r = innovation.reshape(n, 3)
        nis = np.einsum("ni,ni->n", r, np.linalg.solve(S_blocks, r[:, :, None])[:, :, 0])
        keep = nis <= GATE_NIS
        kept = np.repeat(keep, 3)
        H, R, innovation, S = H[kept], R[np.ix_(kept, kept)], innovation[kept], S[np.ix_(kept, kept)]
    if not keep.any():
        return state, keep
    K = np.linalg.solve(S, H @ state.covariance).T
    I_KH = np.eye(dim) - K @ H
    P = I_KH @ state.covariance @ I_KH.T + K @ R @ K.T
    dx = K @ innovation
    corrected = SeedEkfState(
        pose_plus(state.T_base_cam, dx[POSE]),
        state.delta_flange + dx[DELTA],
        state.landmarks_base + dx[LANDMARKS:].reshape(-1, 3),
        state.known,
        0.5 * (P + P.T),
    )
    return corrected, keep


def add_landmarks(
    state: SeedEkfState, rows: np.ndarray, points_cam: np.ndarray, points_cov: np.ndarray
) -> SeedEkfState:
    """Initialise unknown landmarks rows (n,) from their measurements points_cam (n, 3) with
    covariances (n, 3, 3): m = T_base_cam p_cam, with the cross-covariance to the state."""
    R, t = state.T_base_cam[:3, :3], state.T_base_cam[:3, 3]
    n, dim = len(rows), len(state.covariance)
    L = np.zeros((n, 3, dim))
    L[:, :, :3] = np.eye(3)
    L[:, :, 3:6] = -R @ skew_rows(points_cam)
    L = L.reshape(3 * n, dim)
    columns = _landmark_columns(rows)
    P = state.covariance.copy()
    cross = L @ P
    P[columns, :] = cross
    P[:, columns] = cross.T
    P[np.ix_(columns, columns)] = cross @ L.T + _block_diagonal(R @ points_cov @ R.T)
    landmarks = state.landmarks_base.copy()
    landmarks[rows] = points_cam @ R.T + t
    known = state.known.copy()
    known[rows] = True
    return SeedEkfState(state.T_base_cam, state.delta_flange, landmarks, known, 0.5 * (P + P.T))


def flange_cam(state: SeedEkfState, T_base_flange: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T_flange_cam = inv(F) T_base_cam with F the reported flange pose (4, 4) corrected by the
    state's delta_flange, and its (6, 6) covariance (dt flange axes, dtheta camera axes)."""
    F = pose_plus(T_base_flange, state.delta_flange)
    X = invert(F) @ state.T_base_cam
    R_F_t = F[:3, :3].T
    J_cam = np.eye(6)
    J_cam[:3, :3] = R_F_t
    J_flange = np.zeros((6, 6))
    J_flange[:3, :3], J_flange[:3, 3:], J_flange[3:, 3:] = -R_F_t, skew(X[:3, 3]), -X[:3, :3].T
    J = np.hstack([J_cam, J_flange @ pose_plus_jacobian(state.delta_flange)])
    P = state.covariance[:12, :12]
    return X, J @ P @ J.T


def fit_board(board_points: np.ndarray, base_points: np.ndarray) -> np.ndarray:
    """T_base_board (4, 4) that best maps board_points (n, 3) onto base_points (n, 3) (Kabsch)."""
    board_mean, base_mean = board_points.mean(axis=0), base_points.mean(axis=0)
    U, _, Vt = np.linalg.svd((base_points - base_mean).T @ (board_points - board_mean))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return make_transform(R, base_mean - R @ board_mean)


def initial_filter_state(problem: CalibrationProblem, options: MethodOptions) -> SeedEkfState:
    """The camera at F_0 X0 (module doc), no landmark known."""
    if options.prior is not None:
        X0, P_X = options.prior.T_flange_cam, options.prior.covariance
    else:
        X0 = initial_state(problem, options).state.T_flange_cam
        P_X = np.diag([INITIAL_SIGMA_M**2] * 3 + [INITIAL_SIGMA_RAD**2] * 3)
    k = len(problem.marker_ids)
    P = np.zeros((LANDMARKS + 3 * k, LANDMARKS + 3 * k))
    P[POSE, POSE] = P_X
    # X0 is the camera pose with the flange at the identity; moving the flange to F_0 gives F_0 X0.
    at_identity = SeedEkfState(X0, np.zeros(6), np.zeros((k, 3)), np.zeros(k, dtype=bool), P)
    F_0 = problem.frames[0].T_base_flange
    return predict(at_identity, np.eye(4), F_0, _robot_covariance(problem, F_0))


def _robot_covariance(problem: CalibrationProblem, T_model: np.ndarray) -> np.ndarray:
    """(6, 6) the covariance of the error of a frame's model pose T_model (4, 4), the error this
    filter carries (hec.estimator.solve.setup_roles.model_pose_covariance)."""
    return model_pose_covariance(problem.setup, T_model, problem.robot_noise.covariance())


def _depth_points(
    problem: CalibrationProblem, observations: list[FrameObservations]
) -> list[tuple[list[int], np.ndarray, np.ndarray, list[int]]]:
    """Per problem frame: marker IDs with depth, their centres (n, 3) in the camera frame and
    covariances (n, 3, 3), and the marker IDs without depth."""
    by_frame = {o.frame: o for o in observations}
    out = []
    for frame in problem.frames:
        obs = by_frame.get(frame.frame)
        ids, points, covs, no_depth = [], [], [], []
        for m in frame.markers:
            raw = None if obs is None else obs.marker(m.marker_id)
            if raw is None:
                raise CalibrationInputError(
                    f"frame {frame.frame} marker {m.marker_id}: not in the observations the problem was "
                    "built from"
                )
            if raw.points_cam is None:
                no_depth.append(m.marker_id)
                continue
            ids.append(m.marker_id)
            points.append(raw.points_cam[0])
            covs.append(raw.points_cov[0])
        out.append((ids, np.reshape(points, (-1, 3)), np.reshape(covs, (-1, 3, 3)), no_depth))
    return out


def filter_steps(
    problem: CalibrationProblem, options: MethodOptions, observations: list[FrameObservations]
) -> Iterator[FrameStep]:
    """Run the filter over problem.frames in order, yielding after each frame."""
    state = initial_filter_state(problem, options)
    previous = None
    for frame, (ids, points, covs, no_depth) in zip(
        problem.frames, _depth_points(problem, observations), strict=True
    ):
        if previous is not None:
            robot_cov = _robot_covariance(problem, frame.T_base_flange)
            state = predict(state, previous.T_base_flange, frame.T_base_flange, robot_cov)
        previous = frame
        rows = np.array([problem.marker_index(i) for i in ids], dtype=int)
        known = state.known[rows]
        used = np.ones(len(rows), dtype=bool)
        if known.any():
            state, used[known] = update(state, rows[known], points[known], covs[known], options.robust)
        if (~known).any():
            state = add_landmarks(state, rows[~known], points[~known], covs[~known])
        rejected = [i for i, u in zip(ids, used, strict=True) if not u] + no_depth
        yield FrameStep(frame.frame, state, [i for i, u in zip(ids, used, strict=True) if u], rejected)


def check_depth(observations: list[FrameObservations]) -> None:
    """CalibrationInputError unless some marker has depth (seed-ekf maps the centres from it)."""
    if not any(m.depth_m is not None for obs in observations for m in obs.markers):
        raise CalibrationInputError(
            "seed-ekf needs depth and no marker has any (image-only data or --no-depth; use ekf, iekf, "
            "ukf or batch)"
        )


def seed_ekf(
    problem: CalibrationProblem, options: MethodOptions, observations: list[FrameObservations]
) -> Calibration:
    """The paper's EKF made correct (module doc). observations: the raw observations the problem
    was built from (for the marker centres from depth), matched by frame index and marker ID.
    options.map_model does not apply (the map is always the marker centres)."""
    start = time.perf_counter()
    check_depth(observations)
    steps = list(filter_steps(problem, options, observations))
    state = steps[-1].state
    if state.known.sum() < 3:
        raise CalibrationInputError(
            f"seed-ekf needs the centres of at least 3 markers with depth, got {int(state.known.sum())}"
        )
    X, covariance = flange_cam(state, problem.frames[-1].T_base_flange)
    ids = [i for i, k in zip(problem.marker_ids, state.known, strict=True) if k]
    T_base_board = fit_board(
        np.array([problem.board.marker_center(i) for i in ids]), state.landmarks_base[state.known]
    )
    rejected = {(s.frame, i) for s in steps for i in s.rejected}
    warnings = []
    if options.estimate_depth_scale:
        warnings.append("seed-ekf has no depth scale in its state; estimate_depth_scale was ignored")
    return Calibration(
        method="seed-ekf",
        T_flange_cam=X,
        covariance=covariance,
        T_base_board=T_base_board,
        landmarks_base=None,
        residuals=marker_residuals(problem, HandEyeState(X, T_base_board=T_base_board), rejected),
        observations_used=sum(len(s.used) for s in steps),
        observations_rejected=len(rejected),
        diagnostics={"iterations": len(steps), "time_s": time.perf_counter() - start},
        warnings=warnings,
    )
