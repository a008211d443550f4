"""The calibration problem every method solves: validated, whitened measurements.

Input is what the detector gives (hec.estimator.observe.observations.FrameObservations): per
frame the reported flange pose T_base_flange and, per marker, its P points' pixels
(P = board.points_per_marker: 4 corners of a QR code or tag, 1 chessboard corner)
with their (2P, 2P) covariance and the depth at the points with its covariance.
A marker's measurement vector is (u0, v0, ..., u_P-1, v_P-1, z0, ..., z_P-1) (the depths
only when the marker has depth). Its covariance can be singular (the four corner
depths of a QR code come from one plane: rank 3), so each marker carries a whitening matrix W
with W @ cov @ W.T = I over the covariance's non-null space; estimators work with
whitened residuals W @ (measured - predicted), which are N(0, I) at the truth.

The reported flange poses are measurements too (errors in variables): the true
pose is pose_plus(reported, delta), delta ~ N(0, RobotPoseNoise.covariance()),
in the convention of hec.estimator.geometry.lie. Where the dataset names the arm and records its
joints (ReportedArm), each frame keeps its joints and the problem the nominal kinematics the
reported poses were computed with, so self-calibration can correct that model (its errors are the
same from view to view, not white).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.common.setups import EYE_IN_HAND, SETUPS
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import ARMS, URKinematics, arm_from_dict
from hec.estimator.observe.frames import UR_JOINTS, Dataset, DatasetError
from hec.estimator.observe.observations import FrameObservations, MarkerObservation
from hec.estimator.solve.setup_roles import check_setup, model_pose
from hec.estimator.targets.target import Target

MIN_FRAMES = 3
# Eigenvalues below this fraction of the largest are the covariance's null space.
NULL_EIGENVALUE_FRACTION = 1e-9


class CalibrationInputError(ValueError):
    """The observations cannot be calibrated from; the message names what is missing."""


@dataclass(frozen=True)
class ReportedArm:
    """The arm behind the reported flange poses: its nominal kinematics and each frame's reported
    joints (6,), radians, by frame index."""

    kinematics: URKinematics
    joints: dict[int, np.ndarray]


def dataset_arm(dataset: Dataset) -> ReportedArm | None:
    """The dataset's arm: its model (dataset.json 'robot_model', or a simulation's scenario robot)
    and the joints of frames.csv; None when the model is not named or not known, the frames do not
    all have its six joints, or the poses are the controller's TCP rather than the flange
    (kinematics to tool0 then miss the TCP offset)."""
    meta = dataset.metadata
    name = dataset_arm_name(dataset)
    if meta.get("pose_frame", "flange") != "flange":
        return None
    if "robot_dh" in meta:  # an arm imported with its own DH table
        try:
            kinematics = arm_from_dict(str(name), meta["robot_dh"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(
                f"{dataset.root / 'dataset.json'}: field 'robot_dh' is malformed ({exc})"
            ) from None
    elif name in ARMS:
        kinematics = ARMS[name]
    else:
        return None
    if any(len(row["joints"]) != UR_JOINTS for row in dataset.rows):
        return None  # the joints are not the UR arm's six
    return ReportedArm(
        kinematics, {i: np.asarray(row["joints"], float) for i, row in enumerate(dataset.rows)}
    )


def dataset_arm_name(dataset: Dataset) -> str | None:
    """The arm the dataset declares (dataset.json 'robot_model', or a simulation's scenario robot),
    known to hec or not; None when it names none."""
    meta = dataset.metadata
    name = meta.get("robot_model") or (meta.get("simulation") or {}).get("scenario", {}).get("robot")
    return None if name is None else str(name)


def dataset_setup(dataset: Dataset) -> str:
    """The dataset's set-up (dataset.json 'setup'): 'eye-in-hand' when not given, or 'eye-to-hand'."""
    setup = dataset.metadata.get("setup", EYE_IN_HAND)
    if setup not in SETUPS:
        raise DatasetError(
            f"{dataset.root / 'dataset.json'}: field 'setup' should be one of {', '.join(SETUPS)}, "
            f"got {setup!r}"
        )
    return setup


def dataset_robot_noise(dataset: Dataset) -> RobotPoseNoise:
    """The dataset's robot pose noise (dataset.json 'robot_pose_noise'), else RobotPoseNoise()."""
    spec = dataset.metadata.get("robot_pose_noise")
    if spec is None:
        return RobotPoseNoise()
    try:
        return RobotPoseNoise(float(spec["translation_sigma_m"]), float(spec["rotation_sigma_rad"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(
            f"{dataset.root / 'dataset.json'}: field 'robot_pose_noise' is malformed ({exc})"
        ) from None


@dataclass
class MarkerMeasurement:
    """One marker of P points in one frame. corners_board: (P, 3) metres in the board frame.
    corners_px: (P, 2). depth_m: (P,) at the points, or None. whitening: (m, 2P) or (m, 3P),
    block-diagonal: its first pixel_rows rows whiten the pixels, the others the depths."""

    marker_id: int
    corners_board: np.ndarray
    corners_px: np.ndarray
    depth_m: np.ndarray | None
    whitening: np.ndarray
    pixel_rows: int

    @property
    def measured(self) -> np.ndarray:
        """(2P,) or (3P,): point pixels, then point depths."""
        z = self.corners_px.reshape(-1)
        return z if self.depth_m is None else np.concatenate([z, self.depth_m])


@dataclass
class FrameMeasurements:
    """The usable markers of one frame. T_base_flange: (4, 4) the model pose, as the robot reported
    it (eye-in-hand) or its inverse T_flange_base (eye-to-hand: hec.estimator.solve.setup_roles).
    joints: (6,) the reported joint angles (radians) it was computed from, when known."""

    frame: int
    T_base_flange: np.ndarray
    markers: list[MarkerMeasurement]
    joints: np.ndarray | None = None

    @functools.cached_property
    def stacked(self) -> StackedMeasurements:
        """The frame's markers as one measurement (see StackedMeasurements)."""
        P = len(self.markers[0].corners_px)
        rows = np.concatenate(
            [3 * P * k + np.arange(2 * P if m.depth_m is None else 3 * P) for k, m in enumerate(self.markers)]
        )
        return StackedMeasurements(
            rows,
            _block_diagonal([m.whitening for m in self.markers]),
            np.concatenate([m.measured for m in self.markers]),
        )


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    """The (sum of rows, sum of columns) matrix with the (rows, columns) blocks on its diagonal
    (scipy.linalg.block_diag's answer at a fraction of its cost for a few small blocks)."""
    matrix = np.zeros((sum(len(b) for b in blocks), sum(b.shape[1] for b in blocks)))
    row = column = 0
    for block in blocks:
        height, width = block.shape
        matrix[row : row + height, column : column + width] = block
        row, column = row + height, column + width
    return matrix


@dataclass(frozen=True)
class StackedMeasurements:
    """A frame's K markers as one measurement. rows: (r,) which entries of the per-marker layout
    (3 P K,: each marker's 2P point pixels, then its P depths) are measured; whitening: (R, r)
    the markers' whitenings block-diagonally; measured: (r,) the measured values."""

    rows: np.ndarray
    whitening: np.ndarray
    measured: np.ndarray


@dataclass
class CalibrationProblem:
    """Everything an estimator needs. marker_ids: the observed board markers, sorted; the
    landmark of point c of marker marker_ids[k] has index P * k + c (P points_per_marker). rejected: one line
    per frame or marker left out, with the reason. depth_bias: (log scale s, offset o metres) of
    the measured depth, measured = exp(s) (z + o) for a true depth z (self-calibration sets it;
    none by default). board_bend_m: (bx, by) sag of the board out of its plane, corner z +=
    bx (1 - u^2) + by (1 - v^2), u = 2 x / width, v = 2 y / height (board frame, size_m; none by
    default). depth_tilt: (tx, ty) the depth's error that grows across the image, measured +=
    exp(s) (tx x + ty y) for a point (x, y, z) in the camera frame (a depth-to-colour
    registration turned by about (ty, -tx) radians about the camera's x and y; none by
    default). kinematics: the nominal model the reported poses were computed with (every
    frame then has its joints), or None. arm_name: the arm the dataset declares (named in
    warnings), or None. setup: 'eye-in-hand', or 'eye-to-hand', whose frames hold the inverted
    flange poses and whose unknowns T_flange_cam and T_base_board are T_base_cam and
    T_flange_board (hec.estimator.solve.setup_roles)."""

    intrinsics: CameraIntrinsics
    board: Target
    frames: list[FrameMeasurements]
    robot_noise: RobotPoseNoise
    marker_ids: list[int]
    rejected: list[str] = field(default_factory=list)
    depth_bias: tuple[float, float] = (0.0, 0.0)
    board_bend_m: tuple[float, float] = (0.0, 0.0)
    depth_tilt: tuple[float, float] = (0.0, 0.0)
    kinematics: URKinematics | None = None
    arm_name: str | None = None
    setup: str = EYE_IN_HAND

    @property
    def points_per_marker(self) -> int:
        """P: the points of each marker (the board's)."""
        return self.board.points_per_marker

    @property
    def observation_count(self) -> int:
        """Markers used, summed over frames."""
        return sum(len(f.markers) for f in self.frames)

    def marker_index(self, marker_id: int) -> int:
        return self.marker_ids.index(marker_id)


def whitening_matrices(covariances: list[np.ndarray], whats: list[str]) -> list[np.ndarray]:
    """(m_i, n) W_i with W_i @ cov_i @ W_i.T = I over the non-null space of each (n, n) covariance
    (the ones of one size decomposed together); whats: what each is, for the errors."""
    whitenings: list[np.ndarray | None] = [None] * len(covariances)
    by_size: dict[tuple, list[int]] = {}
    for i, cov in enumerate(covariances):
        if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
            raise CalibrationInputError(f"{whats[i]}: covariance must be square, got shape {cov.shape}")
        by_size.setdefault(cov.shape, []).append(i)
    for shape, indices in by_size.items():
        covs = np.array([covariances[i] for i in indices])
        finite = np.isfinite(covs).all(axis=(1, 2))
        if not finite.all():
            raise CalibrationInputError(
                f"{whats[indices[np.argmin(finite)]]}: covariance has NaN or infinite entries"
            )
        sym = 0.5 * (covs + np.swapaxes(covs, 1, 2))
        diagonals = np.diagonal(sym, axis1=1, axis2=2)
        if np.count_nonzero(sym) == np.count_nonzero(diagonals):
            # Diagonal: eigh's rows (up to the order of equal variances) without LAPACK.
            order = np.argsort(diagonals, axis=1, kind="stable")
            values = np.take_along_axis(diagonals, order, axis=1)
            vectors = np.swapaxes(np.eye(shape[0])[order], 1, 2)
        else:
            values, vectors = np.linalg.eigh(sym)
        bad = (values[:, -1] <= 0.0) | (values[:, 0] < -1e-6 * values[:, -1])
        if bad.any():
            raise CalibrationInputError(
                f"{whats[indices[np.argmax(bad)]]}: covariance is not positive semi-definite"
            )
        keep = values > NULL_EIGENVALUE_FRACTION * values[:, -1:]
        if keep.all():
            full = np.swapaxes(vectors / np.sqrt(values)[:, None, :], 1, 2)
            for i, W in zip(indices, full, strict=True):
                whitenings[i] = W
        else:
            for i, V, v, k in zip(indices, vectors, values, keep, strict=True):
                whitenings[i] = (V[:, k] / np.sqrt(v[k])).T
    return whitenings


def _check_pose(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise CalibrationInputError(f"{what}: expected a (4, 4) pose, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise CalibrationInputError(f"{what}: pose has NaN or infinite entries")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise CalibrationInputError(f"{what}: rotation part is not a rotation matrix")
    return T


def dataset_problem(
    dataset: Dataset,
    observations: list[FrameObservations],
    robot_noise: RobotPoseNoise | None = None,
    use_depth: bool = True,
) -> CalibrationProblem:
    """build_problem with what the dataset declares: its board, camera, arm (dataset_arm,
    dataset_arm_name), set-up (dataset_setup) and, unless robot_noise is given, its robot pose
    noise (dataset_robot_noise)."""
    return build_problem(
        observations,
        dataset.board,
        dataset.intrinsics,
        dataset_robot_noise(dataset) if robot_noise is None else robot_noise,
        use_depth,
        dataset_arm(dataset),
        arm_name=dataset_arm_name(dataset),
        setup=dataset_setup(dataset),
    )


def build_problem(
    observations: list[FrameObservations],
    board: Target,
    intrinsics: CameraIntrinsics,
    robot_noise: RobotPoseNoise | None = None,
    use_depth: bool = True,
    arm: ReportedArm | None = None,
    arm_name: str | None = None,
    setup: str = EYE_IN_HAND,
) -> CalibrationProblem:
    """Validate observations and turn them into whitened measurements.

    Frames with a problem or without markers are left out (listed in ``rejected``). With arm, the
    frames keep their joints and the problem the arm's kinematics (unless a frame's joints are
    missing or not finite). arm_name: the arm the dataset declares (dataset_arm_name; default
    arm's). setup 'eye-to-hand': the frames hold the inverted reported poses
    (hec.estimator.solve.setup_roles).
    Raises CalibrationInputError for NaNs, markers that are not on the board, or
    fewer than MIN_FRAMES usable frames.
    """
    board_ids = set(board.marker_ids)
    foreign = sorted({m.marker_id for o in observations for m in o.markers} - board_ids)
    if foreign:
        raise CalibrationInputError(
            f"the board definition '{board.name}' does not match the observations: marker IDs "
            f"{foreign} were observed but the board has IDs {sorted(board_ids)}"
        )
    usable, rejected = [], []
    for obs in observations:
        if obs.problem is not None or not obs.markers:
            rejected.append(f"frame {obs.frame}: {obs.problem or 'no marker observed'}")
            continue
        usable.append((obs, _check_pose(obs.T_base_flange, f"frame {obs.frame} T_base_flange")))
    if len(usable) < MIN_FRAMES:
        raise CalibrationInputError(
            f"too few frames: {len(usable)} usable of {len(observations)}, need at least {MIN_FRAMES}"
            + (f" ({'; '.join(rejected[:3])})" if rejected else "")
        )
    markers = iter(_markers([(obs.frame, m) for obs, _ in usable for m in obs.markers], board, use_depth))
    check_setup(setup)
    frames = [
        FrameMeasurements(obs.frame, model_pose(setup, T), [next(markers) for _ in obs.markers])
        for obs, T in usable
    ]
    marker_ids = sorted({m.marker_id for f in frames for m in f.markers})
    kinematics = None
    if arm is not None:
        joints = [arm.joints.get(f.frame) for f in frames]
        if all(q is not None and q.shape == (6,) and np.all(np.isfinite(q)) for q in joints):
            frames = [replace(f, joints=q) for f, q in zip(frames, joints, strict=True)]
            kinematics = arm.kinematics
    return CalibrationProblem(
        intrinsics,
        board,
        frames,
        robot_noise or RobotPoseNoise(),
        marker_ids,
        rejected,
        kinematics=kinematics,
        arm_name=arm_name or (None if arm is None else arm.kinematics.name),
        setup=setup,
    )


def _markers(
    observed: list[tuple[int, MarkerObservation]], board: Target, use_depth: bool
) -> list[MarkerMeasurement]:
    """The measurements of (frame, MarkerObservation) pairs, validated, with their whitenings."""
    P = board.points_per_marker
    whats = [f"frame {frame} marker {m.marker_id}" for frame, m in observed]
    corners = [np.asarray(m.corners_px, dtype=np.float64) for _, m in observed]
    for what, c in zip(whats, corners, strict=True):
        if c.shape != (P, 2):
            raise CalibrationInputError(f"{what}: corners_px must be ({P}, 2) finite pixels")
    finite = np.isfinite(np.array(corners).reshape(len(corners), 2 * P)).all(axis=1)
    if not finite.all():
        raise CalibrationInputError(f"{whats[np.argmin(finite)]}: corners_px must be ({P}, 2) finite pixels")
    W_pixels = whitening_matrices([np.asarray(m.corners_cov, dtype=np.float64) for _, m in observed], whats)
    with_depth = [i for i, (_, m) in enumerate(observed) if use_depth and m.depth_m is not None]
    depths = [np.asarray(observed[i][1].depth_m, dtype=np.float64) for i in with_depth]
    for i, z in zip(with_depth, depths, strict=True):
        if z.shape != (1 + P,):
            raise CalibrationInputError(
                f"{whats[i]}: depth_m must hold {1 + P} depths (centre, points 0..{P - 1})"
            )
    valid = np.array([np.isfinite(z[1:]).all() and (z[1:] > 0).all() for z in depths], dtype=bool)
    if not valid.all():
        raise CalibrationInputError(
            f"{whats[with_depth[np.argmin(valid)]]}: depth_m must be finite and positive"
        )
    W_depths = whitening_matrices(
        [np.asarray(observed[i][1].depth_cov, dtype=np.float64)[1:, 1:] for i in with_depth],
        [f"{whats[i]} depth" for i in with_depth],
    )
    depth_of = dict(zip(with_depth, zip(depths, W_depths, strict=True), strict=True))
    corners_board = {marker_id: board.marker_corners(marker_id) for marker_id in board.marker_ids}
    measurements = []
    for i, (_, m) in enumerate(observed):
        W, depth = W_pixels[i], None
        if i in depth_of:
            z, W_depth = depth_of[i]
            depth, W = z[1:], _block_diagonal([W_pixels[i], W_depth])
        measurements.append(
            MarkerMeasurement(m.marker_id, corners_board[m.marker_id], corners[i], depth, W, len(W_pixels[i]))
        )
    return measurements
