"""What every calibration method returns, and the options every method takes.

The result is T_flange_cam: the camera's optical frame (OpenCV: x right, y down,
z forward) in the flange (tool0) frame, OpenCV's ``cam2gripper``. Use it as
T_base_cam = T_base_flange @ T_flange_cam. Its covariance is over the perturbation
(dt, dtheta) of hec.estimator.geometry.lie: dt in metres along the flange axes, dtheta in
radians about the camera axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hec.estimator.common.setups import EYE_IN_HAND, HAND_EYE_NAMES
from hec.estimator.geometry.lie import pose_minus, so3_right_jacobian_inverse
from hec.estimator.geometry.transforms import transform_points
from hec.estimator.solve.measurement_model import HandEyeState, marker_points, predict_points
from hec.estimator.solve.problem import CalibrationProblem

# Prior used when the caller gives none: so wide it adds no information.
DEFAULT_PRIOR_SIGMA_M = 0.5
DEFAULT_PRIOR_SIGMA_RAD = 1.0
# The depth at a marker (a plane fit to its depth pixels) is unbiased to about this share of the
# depth, beyond what its noise model accounts for: on the default rendered cell with the depth noise
# and quantisation off, --depth-scale came out 8.4e-5 off the true 1 (seed 7). The depth scale's
# reported sigma is never below it.
DEPTH_SCALE_FLOOR = 1e-4


@dataclass(frozen=True)
class Prior:
    """A guess of T_flange_cam (4, 4) with its (6, 6) covariance (hec.estimator.geometry.lie convention):
    the true mount is pose_plus(T_flange_cam, e), e ~ N(0, covariance). Estimators treat it
    as one more measurement (the filters fuse it after the frames); they start from the closed
    form when the frames give one, so a wrong guess with an honest (wide) covariance does no harm."""

    T_flange_cam: np.ndarray
    covariance: np.ndarray = field(
        default_factory=lambda: np.diag([DEFAULT_PRIOR_SIGMA_M**2] * 3 + [DEFAULT_PRIOR_SIGMA_RAD**2] * 3)
    )

    def whitened_error(self, T_flange_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """L e (6,) with e = pose_minus(T_flange_cam, self.T_flange_cam), L^T L = inv(covariance),
        and its (6, 6) Jacobian with respect to the local perturbation of T_flange_cam."""
        L = np.linalg.cholesky(np.linalg.inv(self.covariance)).T
        e = pose_minus(T_flange_cam, self.T_flange_cam)
        J = np.eye(6)
        J[3:, 3:] = so3_right_jacobian_inverse(e[3:])
        return L @ e, L @ J


@dataclass(frozen=True)
class MethodOptions:
    """prior: None = no prior, initialise in closed form. map_model: 'board' (the board pose,
    geometry known) or 'landmarks' (every corner a free point). estimate_depth_scale: add
    a depth scale factor to the state. robust: down-weight outliers (batch: Huber loss,
    filters: gate markers whose innovation fails a chi-square test). learn_noise: hec's methods
    first learn the noise levels from all frames (hec.estimator.solve.noise_learning) and run with
    them, the outliers of that pass left out instead of gated; False: the declared levels."""

    prior: Prior | None = None
    map_model: str = "board"
    estimate_depth_scale: bool = False
    robust: bool = True
    learn_noise: bool = True

    def __post_init__(self) -> None:
        if self.map_model not in ("board", "landmarks"):
            raise ValueError(f"map_model must be 'board' or 'landmarks', got {self.map_model!r}")


@dataclass(frozen=True)
class MarkerResidual:
    """Residual of one marker in one frame at the estimate, with the reported flange pose.
    rms_px: RMS over its corners of the pixel distance. depth_rms_mm: RMS corner depth
    difference, None without depth. used: False if the method rejected it."""

    frame: int
    marker_id: int
    rms_px: float
    depth_rms_mm: float | None
    used: bool = True


@dataclass
class Calibration:
    """A method's result (see the module doc for the frames and the covariance convention).

    covariance: (6, 6), or None when the method gives no uncertainty (the OpenCV baselines).
    T_base_board: (4, 4) board pose in the base frame (board model), landmarks_base:
    {marker_id: (C, 3) points in the base frame} (landmark model), one of them or both.
    observations_used / observations_rejected: markers over all frames that the method used / left
    out (frames without markers are in CalibrationProblem.rejected). diagnostics: at
    least 'iterations' and 'time_s'; 'observability' when computed. warnings: plain words.
    setup: the problem's; 'eye-to-hand' swaps the unknowns' roles (hec.estimator.solve.setup_roles):
    T_flange_cam then holds T_base_cam (its covariance's dt along the base axes) and T_base_board
    T_flange_board.
    """

    method: str
    T_flange_cam: np.ndarray
    covariance: np.ndarray | None
    T_base_board: np.ndarray | None
    landmarks_base: dict[int, np.ndarray] | None
    residuals: list[MarkerResidual]
    observations_used: int
    observations_rejected: int
    depth_scale: float | None = None
    depth_scale_sigma: float | None = None
    diagnostics: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    setup: str = EYE_IN_HAND

    @property
    def hand_eye_name(self) -> str:
        """What T_flange_cam holds: 'T_flange_cam', or 'T_base_cam' eye-to-hand."""
        return HAND_EYE_NAMES[self.setup]

    @property
    def sigma_translation_mm(self) -> np.ndarray | None:
        """(3,) 1-sigma along the flange axes, mm."""
        return None if self.covariance is None else 1e3 * np.sqrt(np.diag(self.covariance)[:3])

    @property
    def sigma_rotation_deg(self) -> np.ndarray | None:
        """(3,) 1-sigma about the camera axes, degrees."""
        return None if self.covariance is None else np.degrees(np.sqrt(np.diag(self.covariance)[3:]))

    @property
    def residual_rms_px(self) -> float:
        used = [r.rms_px for r in self.residuals if r.used]
        return float(np.sqrt(np.mean(np.square(used)))) if used else float("nan")

    @property
    def residual_depth_rms_mm(self) -> float | None:
        used = [r.depth_rms_mm for r in self.residuals if r.used and r.depth_rms_mm is not None]
        return float(np.sqrt(np.mean(np.square(used)))) if used else None

    def frame_residuals(self) -> dict[int, float]:
        """RMS pixel residual per frame over its used markers."""
        frames: dict[int, list[float]] = {}
        for r in self.residuals:
            if r.used:
                frames.setdefault(r.frame, []).append(r.rms_px)
        return {f: float(np.sqrt(np.mean(np.square(v)))) for f, v in frames.items()}


def marker_residuals(
    problem: CalibrationProblem, state: HandEyeState, rejected: set[tuple[int, int]] | None = None
) -> list[MarkerResidual]:
    """Per-marker residuals at a state, with the reported flange poses, every frame in one prediction.
    rejected: (frame, marker_id) pairs the method left out."""
    rejected = rejected or set()
    markers = [(f.frame, m) for f in problem.frames for m in f.markers]
    if not markers:
        return []
    C = problem.points_per_marker
    frame_of_point = np.repeat([i for i, f in enumerate(problem.frames) for _ in f.markers], C)
    T_F = np.array([f.T_base_flange for f in problem.frames])[frame_of_point]
    points = marker_points(problem, [m for _, m in markers], state.T_base_board is not None)
    pred = predict_points(problem, state, points, T_F[:, :3, :3], T_F[:, :3, 3], jacobians=False)
    corners_px = np.concatenate([m.corners_px for _, m in markers])
    rms_px = np.sqrt(np.mean(np.sum((pred.pixels - corners_px) ** 2, axis=1).reshape(-1, C), axis=1))
    depth_m = np.array([np.full(C, np.nan) if m.depth_m is None else m.depth_m for _, m in markers])
    depth_mm = 1e3 * np.sqrt(np.mean((pred.depth.reshape(-1, C) - depth_m) ** 2, axis=1))
    return [
        MarkerResidual(
            frame,
            m.marker_id,
            float(rms_px[k]),
            None if m.depth_m is None else float(depth_mm[k]),
            (frame, m.marker_id) not in rejected,
        )
        for k, (frame, m) in enumerate(markers)
    ]


def calibration_state(problem: CalibrationProblem, cal: Calibration) -> HandEyeState:
    """The HandEyeState a calibration of this problem ended at (its mount, board or landmarks, and
    depth scale if it estimated one)."""
    if cal.T_base_board is not None:
        return HandEyeState(cal.T_flange_cam, T_base_board=cal.T_base_board, depth_scale=cal.depth_scale)
    corners = np.concatenate([cal.landmarks_base[i] for i in problem.marker_ids])
    return HandEyeState(cal.T_flange_cam, landmarks_base=corners, depth_scale=cal.depth_scale)


def landmarks_by_marker(problem: CalibrationProblem, state: HandEyeState) -> dict[int, np.ndarray]:
    """{marker_id: (C, 3) points in the base frame} from either map model."""
    if state.landmarks_base is not None:
        C = problem.points_per_marker
        return {i: state.landmarks_base[C * k : C * k + C].copy() for k, i in enumerate(problem.marker_ids)}
    return {
        i: transform_points(state.T_base_board, problem.board.marker_corners(i)) for i in problem.marker_ids
    }


def calibration_from_state(
    method: str,
    problem: CalibrationProblem,
    state: HandEyeState,
    covariance: np.ndarray,
    rejected: set[tuple[int, int]],
    diagnostics: dict,
) -> Calibration:
    """The Calibration of a method that estimates a HandEyeState: covariance (dim, dim) of the state
    perturbation (its [:6, :6] is T_flange_cam's), rejected (frame, marker_id) pairs, and the method's
    diagnostics (the state covariance is added as 'state_covariance')."""
    return Calibration(
        method=method,
        T_flange_cam=state.T_flange_cam,
        covariance=covariance[:6, :6],
        T_base_board=state.T_base_board,
        landmarks_base=landmarks_by_marker(problem, state) if state.landmarks_base is not None else None,
        residuals=marker_residuals(problem, state, rejected),
        observations_used=problem.observation_count - len(rejected),
        observations_rejected=len(rejected),
        depth_scale=state.depth_scale,
        depth_scale_sigma=None
        if state.depth_scale is None
        else float(np.hypot(np.sqrt(covariance[-1, -1]), DEPTH_SCALE_FLOOR)),
        diagnostics={**diagnostics, "state_covariance": covariance},
    )
