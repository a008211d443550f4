"""Self-calibration: the camera, the board, the depth and the arm's kinematics estimated with the
mount, for when the model the dataset declares does not fit.

The nuisance parameters theta (CAMERA_NUISANCE, KINEMATIC_NUISANCE, the marker shifts) are
corrections to what the problem declares:
focal lengths and principal point (pixels), the radial distortion k1, k2 (added to the declared
coefficients), the printed board's scale along its x and y (log scales, so about the
fractions: corners scaled by exp(theta) about the board frame's origin), the depth bias
(CalibrationProblem.depth_bias: measured depth = exp(depth_scale) (z + depth_offset_m), z the
true depth) and the board's sag out of its plane (CalibrationProblem.board_bend_m: a sheet on
foam sags by a millimetre; unmodelled, self-calibration bent the focal length and the
distortion instead) and the depth's tilt (CalibrationProblem.depth_tilt: a depth-to-colour
registration turned by a tenth of a degree tilts every depth by as much; unmodelled, it turned the
mount by 0.1 deg). Each has a Gaussian prior (PRIOR_SIGMA: factory intrinsics are a few tenths of
a percent and a few pixels off, a print a few tenths of a percent, a stereo camera's depth a
percent or two and a few millimetres, a sag 2 mm, a registration a few tenths of a degree), so
theta stays determined when the views do not separate it from the mount. From views at one
distance a print scale and a depth scale look alike (either explains a board that looks nearer in
the image than in the depth): the priors then share the difference out, and the covariance of
T_flange_cam carries what that leaves unknown; views at two distances separate them.

Where the problem knows the arm (its nominal kinematics and each frame's joints), the arm's
kinematic model joins theta (KINEMATIC_NUISANCE: every joint's zero offset, d, a and twist
alpha, corrections to UR's nominal DH table; priors from UR calibration files): a real arm's
nominal-model pose error is the same from view to view, which white pose noise does not describe
(its estimate then was 5x too confident). Corrections that only move the base or the tool (joint
1's, joint 6's) the board pose or the mount absorb; their priors then carry into the mount's
covariance, which is measured against the true flange.

Each marker may also sit a little off its definition in the board's plane (MARKER_SHIFTS, prior
0.1 mm): unmodelled, the 0.05 mm of an office print turned the mount by 0.04 deg once the depth's
tilt was free.

theta covers the names given (group_names: NUISANCE_GROUPS' order; the noise learning frees or
fixes a group's names together). The batch objective gains theta as parameters
(their Jacobian analytic, from the measurement model's, and the kinematics' by finite differences once) and
its prior rows; the noise learning runs on it when the declared model fits badly, and every
method then solves the adjusted problem.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from hec.estimator.geometry.kinematics import URKinematics, forward
from hec.estimator.geometry.lie import pose_minus, so3_exp, so3_right_jacobian
from hec.estimator.solve.batch import BatchObjective, OutsideModel
from hec.estimator.solve.block_arrow import BlockLayout
from hec.estimator.solve.measurement_model import camera_jacobian_rows
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.setup_roles import flange_minus, flange_plus

# The camera, board and depth corrections, in the order of predict_frame's J_camera columns.
CAMERA_NUISANCE = (
    "fx_px",
    "fy_px",
    "cx_px",
    "cy_px",
    "k1",
    "k2",
    "board_scale_x",
    "board_scale_y",
    "depth_scale",
    "depth_offset_m",
    "board_bend_x_m",
    "board_bend_y_m",
    "depth_tilt_x",
    "depth_tilt_y",
)
_DH = ("zero_rad", "d_m", "a_m", "alpha_rad")
KINEMATIC_NUISANCE = tuple(f"joint{j}_{kind}" for kind in _DH for j in range(1, 7))
# Each board marker's shift in the board's plane: names marker{ID}_x_m, marker{ID}_y_m.
MARKER_SHIFTS = "marker_shifts"
NUISANCE_GROUPS = {
    "intrinsics": ("fx_px", "fy_px", "cx_px", "cy_px"),
    "distortion": ("k1", "k2"),
    "board_scale": ("board_scale_x", "board_scale_y"),
    "depth_bias": ("depth_scale", "depth_offset_m"),
    "board_bend": ("board_bend_x_m", "board_bend_y_m"),
    "depth_tilt": ("depth_tilt_x", "depth_tilt_y"),
    "kinematics": KINEMATIC_NUISANCE,
    MARKER_SHIFTS: (),  # the problem's markers: group_members
}
# The groups freed when only the depths misfit (the corners and the flange poses fit their noise):
# the depth's own, and the print scale, which from one distance looks like a depth scale to the
# corners and the flange poses alike. The camera's other errors show in the corners or, through
# the board pose, in the flange poses; freed without that, they took up depth errors the model
# cannot describe (a rendered cell with the depth alone 2x off, 29 trials: median 0.156 mm with
# every group freed, 0.135 mm with the depth's alone, OpenCV's best 0.136 mm).
DEPTH_GROUPS = ("board_scale", "depth_bias", "depth_tilt")
# The print scale and the depth scale are "not told apart" above this correlation of their
# estimates (print_depth_scale_correlation). Below it, with only the depths misfitting, the print
# scale is fixed: the depths alone would decide it, and on an exact print their errors the model
# cannot describe made it significant in 5 of those 29 trials (0.24-0.41 mm off).
SCALE_CORRELATION = 0.9
# Prior sigmas: focal lengths as a fraction of the declared one, the rest as they are. The arm's:
# UR calibration files show zero offsets of 0.006-0.07 deg, a and d deltas of 0.02-0.9 mm and
# twist deltas of 0.02-0.4 deg against the nominal table.
FOCAL_PRIOR_FRACTION = 0.05
PRIOR_SIGMA = {
    "cx_px": 20.0,
    "cy_px": 20.0,
    "k1": 0.5,
    "k2": 0.5,
    "board_scale_x": 0.03,
    "board_scale_y": 0.03,
    "depth_scale": 0.02,
    "depth_offset_m": 0.005,
    "board_bend_x_m": 0.002,
    "board_bend_y_m": 0.002,
    "depth_tilt_x": 0.005,
    "depth_tilt_y": 0.005,
    **{f"joint{j}_zero_rad": float(np.radians(0.1)) for j in range(1, 7)},
    **{f"joint{j}_{kind}": 0.0005 for kind in ("d_m", "a_m") for j in range(1, 7)},
    **{f"joint{j}_alpha_rad": float(np.radians(0.1)) for j in range(1, 7)},
}
# An office print places each marker within about a tenth of a millimetre of its definition.
MARKER_SHIFT_PRIOR_M = 1e-4
# Self-calibration first frees every group the problem can estimate (NUISANCE_GROUPS), then solves
# again with the groups fixed whose corrections, together, do not differ from zero at this
# significance (their chi-square with their covariance): each group freed costs accuracy (1.6x the
# bound with all of them when only the depth was biased).
GROUP_SIGNIFICANCE = 1e-3
# ... unless fixing them moves the mount by more than this many of its sigmas with them fixed
# (Mahalanobis): 10 for a print scale the views cannot tell from the depth's, 2.6 for a depth bias
# at one distance (p = 0.23 alone); the arm's kinematics on an exact arm moved it 0.5-1.2.
DROP_SHIFT = 2.0
# A correction is noteworthy from this size (below it changes the mount by well under 0.1 mm): the
# fit check reports only those, and ...
NOTEWORTHY = {
    "fx_px": 1.0,
    "fy_px": 1.0,
    "cx_px": 1.0,
    "cy_px": 1.0,
    "k1": 0.01,
    "k2": 0.01,
    "board_scale_x": 0.001,
    "board_scale_y": 0.001,
    "depth_scale": 0.001,
    "depth_offset_m": 0.0005,
    "board_bend_x_m": 0.0003,
    "board_bend_y_m": 0.0003,
    "depth_tilt_x": 0.0005,
    "depth_tilt_y": 0.0005,
}
# A marker's self-calibrated shift is reported from this size.
NOTEWORTHY_MARKER_SHIFT_M = 0.00005
# ... groups whose corrections are all below it are fixed too, significant or not, where that
# lowers the mount's expected squared error (in its sigmas with them fixed) and moves it by less
# than MSE_SHIFT sigmas: a rendered board's texture makes its marker layout and aspect significant
# at 10 um and 0.03 %, and estimating them cost the mount 1.2x with a depth bias (0.161 against
# 0.132 mm) and 1.4x with a 2 % print (0.218 against 0.153 mm). A 1 % print scale is noteworthy:
# fixed, the focal lengths took it and the warning named them. The arm's kinematics have no such
# size here: estimated, they stay (fixed, they moved the realistic cell's mount by 6-40 sigmas).
MSE_SHIFT = 4.0
# Finite-difference step of the kinematic Jacobian (radians or metres).
_KINEMATIC_STEP = 1e-7


def available_groups(
    problem: CalibrationProblem, arm_misfit: bool, depth_only: bool = False
) -> tuple[str, ...]:
    """The NUISANCE_GROUPS to free: the arm's kinematics only when the problem knows them and the
    flange poses fit worse than their noise (arm_misfit; freed for a misfit of the pixels alone,
    the 24 corrections moved a 5-view mount by 0.8 mm on an exact arm); the marker shifts only on
    a board whose markers are placed one by one (Target.markers_placed_one_by_one); with
    depth_only (the depths misfit, the corners and flange poses do not) DEPTH_GROUPS alone."""
    arm = problem.kinematics is not None and arm_misfit
    placed = problem.board.markers_placed_one_by_one
    groups = tuple(
        g for g in NUISANCE_GROUPS if (g != "kinematics" or arm) and (g != MARKER_SHIFTS or placed)
    )
    return tuple(g for g in groups if g in DEPTH_GROUPS) if depth_only else groups


def print_depth_scale_correlation(names: Sequence[str], theta_covariance: np.ndarray) -> float | None:
    """The correlation of the print scale (the mean of its x and y) with the depth scale in
    theta_covariance (len(names), len(names)); None unless both are among names."""
    names = list(names)
    if not {"board_scale_x", "board_scale_y", "depth_scale"} <= set(names):
        return None
    board = np.zeros(len(names))
    board[[names.index("board_scale_x"), names.index("board_scale_y")]] = 0.5
    depth = np.zeros(len(names))
    depth[names.index("depth_scale")] = 1.0
    C = theta_covariance
    return float(board @ C @ depth / np.sqrt((board @ C @ board) * (depth @ C @ depth)))


def scales_confounded(
    problem: CalibrationProblem, groups: Sequence[str], theta_covariance: np.ndarray
) -> bool:
    """Whether the views cannot tell the print scale from the depth's scale: their estimates in
    theta_covariance (over group_names(problem, groups)) correlated beyond SCALE_CORRELATION."""
    correlation = print_depth_scale_correlation(group_names(problem, groups), theta_covariance)
    return correlation is not None and abs(correlation) >= SCALE_CORRELATION


def group_members(problem: CalibrationProblem, group: str) -> tuple[str, ...]:
    """The theta names of one group (the marker shifts: two for each of the problem's markers)."""
    if group == MARKER_SHIFTS:
        return tuple(f"marker{i}_{axis}_m" for i in problem.marker_ids for axis in "xy")
    return NUISANCE_GROUPS[group]


def group_names(problem: CalibrationProblem, groups: Sequence[str]) -> tuple[str, ...]:
    """The theta names of these groups, in NUISANCE_GROUPS order."""
    return tuple(n for g in NUISANCE_GROUPS if g in groups for n in group_members(problem, g))


def prior_sigma(problem: CalibrationProblem, names: Sequence[str] = CAMERA_NUISANCE) -> np.ndarray:
    """(len(names),) prior sigmas of theta for this problem's camera."""
    k = problem.intrinsics
    known = {**PRIOR_SIGMA, "fx_px": FOCAL_PRIOR_FRACTION * k.fx, "fy_px": FOCAL_PRIOR_FRACTION * k.fy}
    return np.array([known.get(name, MARKER_SHIFT_PRIOR_M) for name in names])


def adjusted_kinematics(kinematics: URKinematics, values: dict[str, float]) -> URKinematics:
    """The DH table corrected by the KINEMATIC_NUISANCE values given (the others zero)."""

    def corrected(table: tuple[float, ...], kind: str) -> tuple[float, ...]:
        return tuple(v + values.get(f"joint{j + 1}_{kind}", 0.0) for j, v in enumerate(table))

    return replace(
        kinematics,
        theta_offset=corrected(kinematics.theta_offset, "zero_rad"),
        d=corrected(kinematics.d, "d_m"),
        a=corrected(kinematics.a, "a_m"),
        alpha=corrected(kinematics.alpha, "alpha_rad"),
    )


def adjusted_problem(
    problem: CalibrationProblem, theta: np.ndarray, names: Sequence[str] = CAMERA_NUISANCE
) -> CalibrationProblem:
    """The problem with the camera, the board (its scale, then each marker's shift), the depth
    bias, the board's bend and the arm's kinematics corrected by theta (values of names; the rest
    zero; the depth bias and the bend replaced: the declared problem has none). Kinematic
    corrections move each reported flange pose by what the corrected model computes from its
    joints minus what the nominal one does. Raises OutsideModel for a focal length at or below 0."""
    t = {n: float(v) for n, v in zip(names, theta, strict=True)}
    k = problem.intrinsics
    dist = list(k.dist) + [0.0] * (5 - len(k.dist))
    dist[0] += t.get("k1", 0.0)
    dist[1] += t.get("k2", 0.0)
    fx, fy = k.fx + t.get("fx_px", 0.0), k.fy + t.get("fy_px", 0.0)
    if not (fx > 0 and fy > 0):
        raise OutsideModel(f"focal lengths fx={fx:g}, fy={fy:g} px")
    intrinsics = replace(
        k,
        fx=fx,
        fy=fy,
        cx=k.cx + t.get("cx_px", 0.0),
        cy=k.cy + t.get("cy_px", 0.0),
        dist=tuple(dist),
    )
    scale = np.array([np.exp(t.get("board_scale_x", 0.0)), np.exp(t.get("board_scale_y", 0.0)), 1.0])
    corrected = (
        adjusted_kinematics(problem.kinematics, t)
        if problem.kinematics is not None and any(n in t for n in KINEMATIC_NUISANCE)
        else None
    )
    frames = []
    for f in problem.frames:
        markers = [
            replace(
                m,
                corners_board=m.corners_board * scale
                + [t.get(f"marker{m.marker_id}_x_m", 0.0), t.get(f"marker{m.marker_id}_y_m", 0.0), 0.0],
            )
            for m in f.markers
        ]
        T = f.T_base_flange
        if corrected is not None:
            correction = pose_minus(forward(corrected, f.joints), forward(problem.kinematics, f.joints))
            T = flange_plus(problem.setup, T, correction)
        frames.append(replace(f, markers=markers, T_base_flange=T))
    depth_bias = (t.get("depth_scale", 0.0), t.get("depth_offset_m", 0.0))
    bend = (t.get("board_bend_x_m", 0.0), t.get("board_bend_y_m", 0.0))
    tilt = (t.get("depth_tilt_x", 0.0), t.get("depth_tilt_y", 0.0))
    return replace(
        problem,
        intrinsics=intrinsics,
        frames=frames,
        depth_bias=depth_bias,
        board_bend_m=bend,
        depth_tilt=tilt,
    )


def kinematic_jacobian(kinematics: URKinematics, joints: np.ndarray) -> np.ndarray:
    """(6, 24) d(the flange pose's correction, hec.estimator.geometry.lie perturbation) / d(the
    KINEMATIC_NUISANCE values) at the nominal model, by central differences. Read-only: one noise
    learning asks for the same frames' many times, so each is computed once."""
    return _kinematic_jacobian(kinematics, tuple(np.asarray(joints, dtype=float)))


@functools.lru_cache(maxsize=1024)
def _kinematic_jacobian(kinematics: URKinematics, joints: tuple[float, ...]) -> np.ndarray:
    joints = np.array(joints)
    T_nominal = forward(kinematics, joints)
    G = np.empty((6, len(KINEMATIC_NUISANCE)))
    for i, name in enumerate(KINEMATIC_NUISANCE):
        ahead = forward(adjusted_kinematics(kinematics, {name: _KINEMATIC_STEP}), joints)
        behind = forward(adjusted_kinematics(kinematics, {name: -_KINEMATIC_STEP}), joints)
        G[:, i] = (pose_minus(ahead, T_nominal) - pose_minus(behind, T_nominal)) / (2 * _KINEMATIC_STEP)
    G.flags.writeable = False
    return G


@dataclass
class NuisanceUncertainty:
    """At a self-calibrated optimum: theta's covariance (p, p), the mount's (6, 6) and their
    cross-covariance (6, p) (the mount in hec.estimator.geometry.lie's local perturbation), and consider
    (6, 6): what the mount's covariance gains from theta being estimated (a method that solves the
    adjusted problem with theta fixed adds it)."""

    theta: np.ndarray
    mount: np.ndarray
    mount_theta: np.ndarray
    consider: np.ndarray


def noteworthy_sizes(names: Sequence[str]) -> np.ndarray:
    """(len(names),) the NOTEWORTHY size of each theta name (the marker shifts':
    NOTEWORTHY_MARKER_SHIFT_M; 0 for the kinematics, which have none)."""
    return np.array(
        [NOTEWORTHY.get(n, NOTEWORTHY_MARKER_SHIFT_M if n.startswith("marker") else 0.0) for n in names]
    )


def droppable_groups(
    rows_of: dict[str, list[int]], theta: np.ndarray, uncertainty: NuisanceUncertainty, noteworthy: np.ndarray
) -> list[str]:
    """The groups to fix at the declared model, added least significant first. A group joins when,
    with those before it, either
    - each alone and all together are insignificant (their chi-square with their covariance,
      GROUP_SIGNIFICANCE; alone too, so that the kinematics' 24 degrees of freedom do not hide a
      distortion) and fixing them moves the mount by less than DROP_SHIFT sigmas of its covariance
      with them fixed (a depth bias the print scale could absorb is insignificant alone, yet fixing
      it moves the mount, and its covariance would no longer say so); or
    - every correction in the group is below its noteworthy size (NOTEWORTHY; noteworthy: (p,) per
      theta row) and fixing them lowers the mount's expected squared error and moves it by less
      than MSE_SHIFT sigmas. The move s estimates the bias b that fixing makes, with the covariance K that
      estimating them adds to the mount's: E[s s^T] = b b^T + K, so fixing trades b b^T ~ s s^T - K
      for K, and gains where s^T F^-1 s < 2 tr(F^-1 K) (F: the mount's covariance with them fixed).
    rows_of: each group's rows in theta."""
    groups = tuple(rows_of)

    def statistic(rows: list[int]) -> float:
        C = uncertainty.theta[np.ix_(rows, rows)]
        return float(theta[rows] @ np.linalg.solve(C, theta[rows]))

    alone = {g: chi2.sf(statistic(rows_of[g]), len(rows_of[g])) for g in groups}
    dropped: list[str] = []
    for g in sorted(groups, key=lambda g: -alone[g]):
        rows = [r for d in [*dropped, g] for r in rows_of[d]]
        C, cross = uncertainty.theta[np.ix_(rows, rows)], uncertainty.mount_theta[:, rows]
        shift = cross @ np.linalg.solve(C, theta[rows])
        added = cross @ np.linalg.solve(C, cross.T)
        fixed = uncertainty.mount - added
        moved = float(shift @ np.linalg.solve(fixed, shift))
        insignificant = (
            alone[g] >= GROUP_SIGNIFICANCE
            and chi2.sf(statistic(rows), len(rows)) >= GROUP_SIGNIFICANCE
            and moved <= DROP_SHIFT**2
        )
        immaterial = bool(np.all(np.abs(theta[rows_of[g]]) < noteworthy[rows_of[g]]))
        lower_error = moved < min(2.0 * float(np.trace(np.linalg.solve(fixed, added))), MSE_SHIFT**2)
        if insignificant or (immaterial and lower_error):
            dropped.append(g)
    return dropped


class SelfCalibrationObjective:
    """The batch objective over params = [BatchObjective's params, theta (names)], with theta's
    prior rows last. base: the problem as declared (its whitening and robot noise as learned)."""

    def __init__(
        self,
        base: CalibrationProblem,
        make: Callable[[CalibrationProblem], BatchObjective],
        names: Sequence[str] = CAMERA_NUISANCE,
    ) -> None:
        self.base, self.make, self.names = base, make, tuple(names)
        self.sqrt_info = 1.0 / prior_sigma(base, self.names)
        self.camera_columns = [CAMERA_NUISANCE.index(n) for n in self.names if n in CAMERA_NUISANCE]
        shifts = [n for n in group_members(base, MARKER_SHIFTS) if n in self.names]
        self.shift_columns = (
            {i: (shifts.index(f"marker{i}_x_m"), shifts.index(f"marker{i}_y_m")) for i in base.marker_ids}
            if shifts
            else None
        )
        kinematic = [KINEMATIC_NUISANCE.index(n) for n in self.names if n in KINEMATIC_NUISANCE]
        self.kinematic = (
            [kinematic_jacobian(base.kinematics, f.joints)[:, kinematic] for f in base.frames]
            if kinematic
            else None
        )
        # the marker of every whitened row, every frame's markers in order (_shift_block)
        self.marker_of_row = np.concatenate(
            [np.full(len(m.whitening), m.marker_id) for f in base.frames for m in f.markers]
        )
        self.inner = make(base)
        self._key, self._inner_at = None, self.inner
        self.n = self.inner.n
        self.prior = self.inner.prior
        self.with_robot = self.inner.with_robot

    @property
    def size(self) -> int:
        return self.inner.size + len(self.names)

    @property
    def layout(self) -> BlockLayout:
        """The batch layout, theta's columns global too (its prior rows touch only them)."""
        inner = self.inner.layout
        theta = self.inner.size + np.arange(len(self.names))
        return BlockLayout(np.concatenate([inner.global_columns, theta]), inner.local)

    def _objective(self, theta: np.ndarray) -> BatchObjective:
        key = theta.tobytes()
        if key != self._key:
            self._key, self._inner_at = key, self.make(adjusted_problem(self.base, theta, self.names))
        return self._inner_at

    def residuals(self, params: np.ndarray) -> np.ndarray:
        theta = params[self.inner.size :]
        inner = self._objective(theta).residuals(params[: self.inner.size])
        return np.concatenate([inner, self.sqrt_info * theta])

    def jacobian(self, params: np.ndarray) -> np.ndarray:
        return self.linearise(params)[1]

    def linearise(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """residuals(params) and the Jacobian: the batch's (both from one batch linearisation),
        theta's columns (analytic: every frame's camera Jacobian in one call, camera_jacobian_rows;
        the kinematics' through the flange pose) and theta's prior rows."""
        x, theta = params[: self.inner.size], params[self.inner.size :]
        objective = self._objective(theta)
        camera = bool(self.camera_columns) or self.shift_columns is not None
        r_inner, J_inner, state, pred = objective.linearise_with_prediction(x, camera)
        deltas = objective._deltas(x)
        stacked = objective.stacked
        columns = []
        if camera:
            board = stacked.points if state.T_base_board is not None else None
            J_camera, J_shift = camera_jacobian_rows(
                objective.problem, state, board, stacked.whitening, stacked.selected, pred.points
            )
            if self.camera_columns:
                columns.append(J_camera[:, self.camera_columns])
        if self.kinematic is not None:
            steps = np.array(
                [
                    self._flange_step(i, f.T_base_flange, None if deltas is None else deltas[i])
                    @ self.kinematic[i]
                    for i, f in enumerate(objective.problem.frames)
                ]
            )
            columns.append(np.einsum("rj,rjk->rk", pred.J_flange, steps[stacked.frame_of_row]))
        if self.shift_columns is not None:
            columns.append(self._shift_block(J_shift))
        theta_block = np.zeros((len(r_inner), len(theta)))
        theta_block[objective.measurement_rows] = np.hstack(columns)
        top = np.hstack([J_inner, theta_block])
        bottom = np.hstack([np.zeros((len(theta), self.inner.size)), np.diag(self.sqrt_info)])
        return np.concatenate([r_inner, self.sqrt_info * theta]), np.vstack([top, bottom])

    def _flange_step(self, i: int, T_adjusted: np.ndarray, delta: np.ndarray | None) -> np.ndarray:
        """(6, 6) d(local perturbation of frame i's flange pose, pose_plus(T_adjusted, delta)) / d(its
        kinematic correction a, T_adjusted = pose_plus(reported, a))."""
        a = flange_minus(self.base.setup, T_adjusted, self.base.frames[i].T_base_flange)
        step = np.eye(6)
        rotation = so3_right_jacobian(a[3:])
        step[3:, 3:] = rotation if delta is None else so3_exp(delta[3:]).T @ rotation
        return step

    def _shift_block(self, J_shift: np.ndarray) -> np.ndarray:
        """(R, 2 per marker) the marker-shift columns of every frame's rows (J_shift (R, 2)): each
        marker's rows in its own two columns."""
        block = np.zeros((len(J_shift), 2 * len(self.shift_columns)))
        columns = np.array([self.shift_columns[i] for i in self.marker_of_row])
        rows = np.arange(len(J_shift))[:, None]
        block[rows, columns] = J_shift
        return block

    def frame_residuals(self, params: np.ndarray) -> list[np.ndarray]:
        theta = params[self.inner.size :]
        return self._objective(theta).frame_residuals(params[: self.inner.size])
