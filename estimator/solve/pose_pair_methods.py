"""Calibrating from pose pairs (hec.estimator.observe.pose_pairs): a robot pose A_i = T_base_flange and
the board pose Z_i = T_cam_board another tool measured, without images.

The OpenCV methods take the pairs as they are (cv2.calibrateHandEye: gripper2base = A_i,
target2cam = Z_i). hec's methods use the pose-pair measurement model: the state is the mount
X = T_flange_cam and the board B = T_base_board, fixed in the base frame; each pair measures

    Z_i = P_i(X, B) = inv(X) inv(A_i) B,   r_i = pose_minus(Z_i, P_i)   (6,)

in the perturbation convention of hec.estimator.geometry.lie, with the covariance of Z_i (the pair's,
or learned) plus the reported flange pose's noise carried through. ``batch`` is the Gauss-Newton
optimum over all pairs; ``ekf`` and ``iekf`` fuse the pairs one at a time (iekf iterating each
update) from the Park solution with a wide prior. When the pairs carry no covariance (as
easy_handeye2 writes them), the board pose's noise is learned from the residuals as six variance
components, one per axis of its perturbation (translation along and rotation about the camera's
and the board's axes: a PnP pose is far less certain along the line of sight), by Foerstner's
variance component estimation with the redundancies of the fit, and the result says so. A level
learned from few pairs is itself uncertain: each of the six has its redundancy as degrees of
freedom (on average n - 2: 6 n residuals, 12 parameters), and the part of the mount's error its
noise carries follows Student's t rather than the normal, whose variance is nu / (nu - 2) times
larger; each component's part of the mount's covariance is widened by its factor
(level_widening; on average 1.33 for 10 pairs, 1.13 for 20).
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from scipy.stats import norm as normal
from scipy.stats import t as student_t

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.lie import pose_minus, pose_plus, skew, so3_right_jacobian_inverse
from hec.estimator.geometry.transforms import invert, make_transform
from hec.estimator.observe.pose_pairs import PosePair
from hec.estimator.solve.baselines import OPENCV_METHODS, ROBOT_WORLD_METHODS
from hec.estimator.solve.calibration import Calibration, MethodOptions
from hec.estimator.solve.initialise import MIN_AXIS_SPREAD, mean_pose, rotation_spread
from hec.estimator.solve.level_uncertainty import student_t_factor
from hec.estimator.solve.misfit import FRAMES_NAMED, MISFIT_RATIO
from hec.estimator.solve.problem import MIN_FRAMES, CalibrationInputError

POSE_PAIR_MODEL_METHODS = ("ekf", "iekf", "batch")
# A robot that reports its pose exactly (for pairs whose board poses carry all the noise).
PAIR_NOISE_FREE = RobotPoseNoise(0.0, 0.0)
# The board pose noise learning starts from these (a PnP pose at half a metre) and stops when a
# component changes by less than this factor.
START_SIGMAS = np.array([1e-3] * 3 + [np.radians(0.1)] * 3)
VCE_TOLERANCE = 1e-4
VCE_ITERATIONS = 50
# A learned component never goes below this fraction of its start (an axis whose scatter the robot
# noise carried through already explains would otherwise shrink to zero and stop the iteration; and
# exact pairs at a floor far below this leave the filters' innovation covariance, against their wide
# prior, singular to working precision).
VCE_FLOOR = 1e-4
# A tracking pose's noise, as a fraction of the viewing distance (a PnP pose along its line of sight
# from ordinary corners), for the misfit check.
TRACKING_NOISE_FRACTION = 0.005
# A scale common to every tracking pose's translation (its camera's focal length, the board's printed
# scale) moves the mount; the robot's motions measure it (tracking_scale). It is reported when it is
# more than SCALE_SIGNIFICANT sigmas and SCALE_NOTEWORTHY from 1 (0.01 %: 0.05 mm at half a metre).
SCALE_SIGNIFICANT = 3.0
SCALE_NOTEWORTHY = 1e-4
# A scale the views leave this uncertain (1-sigma) is not measured (views at one distance).
SCALE_UNRESOLVED = 0.01
GN_ITERATIONS = 50
# The filters' prior around the Park solution: wide, it adds no information.
FILTER_PRIOR_SIGMA = (0.1, 0.5)  # metres, radians


def learned_noise_factor(pairs: int) -> float:
    """The variance factor of a mount whose board pose noise was learned from pairs pairs: Student's t's
    nu / (nu - 2) with nu = pairs - 2 (module doc)."""
    return student_t_factor(pairs - 2)


def scale_threshold(pairs: int, learned: bool) -> float:
    """How many (learned-level) sigmas a tracking scale must be from 1 to be named: SCALE_SIGNIFICANT,
    or with the levels learned from pairs pairs the quantile of Student's t (nu = pairs - 2) that is
    exceeded as rarely as the normal's SCALE_SIGNIFICANT (a level from 10 pairs is often too small)."""
    if not learned:
        return SCALE_SIGNIFICANT
    return float(student_t.isf(normal.sf(SCALE_SIGNIFICANT), max(pairs - 2, 1)))


def solve_pose_pairs(
    name: str, pairs: list[PosePair], options: MethodOptions, robot_noise: RobotPoseNoise | None = None
) -> Calibration:
    """T_flange_cam from pose pairs with one method (module doc): an OpenCV name of
    baselines.OPENCV_METHODS or one of POSE_PAIR_MODEL_METHODS. options: its prior (if any) is
    fused by hec's methods. CalibrationInputError for too few pairs or motions without two rotation
    axes."""
    if name not in OPENCV_METHODS and name not in POSE_PAIR_MODEL_METHODS:
        raise ValueError(
            f"method {name!r} cannot use pose pairs; choose one of "
            f"{', '.join([*POSE_PAIR_MODEL_METHODS, *OPENCV_METHODS])}"
        )
    if len(pairs) < MIN_FRAMES:
        raise CalibrationInputError(f"too few pose pairs: {len(pairs)} (at least {MIN_FRAMES} needed)")
    A = np.array([p.T_base_flange for p in pairs])
    if rotation_spread(list(A))[1] < MIN_AXIS_SPREAD:
        raise CalibrationInputError(
            "the robot's rotations between the pairs do not span two axes: the mount cannot be determined "
            "(rotate the flange about at least two different axes between samples)"
        )
    start = time.perf_counter()
    X, B = opencv_pose_pairs(pairs, name if name in OPENCV_METHODS else "opencv-park")
    if name in OPENCV_METHODS:
        result = Calibration(name, X, None, B, None, [], len(pairs), 0)
    else:
        model = PosePairModel(pairs, robot_noise or RobotPoseNoise())
        result = model.batch(X, B) if name == "batch" else model.filter(X, B, iterated=name == "iekf")
        result.method = name
        if options.prior is not None:
            result.warnings.append("the prior is not used with pose pairs")
    bias = tracking_bias_warning(pairs, robot_noise or RobotPoseNoise())
    if bias is not None:
        result.warnings.append(bias)
    result.diagnostics["time_s"] = time.perf_counter() - start
    result.diagnostics["pose_pair_rms"] = PosePairModel(pairs, PAIR_NOISE_FREE).rms(
        result.T_flange_cam, result.T_base_board
    )
    misfit = pose_pair_misfit(pairs, result, robot_noise or RobotPoseNoise())
    if misfit is not None:
        result.diagnostics["misfit"] = misfit
        result.warnings.append(misfit)
    return result


def pose_pair_misfit(pairs: list[PosePair], result: Calibration, robot_noise: RobotPoseNoise) -> str | None:
    """The warning of a result whose board pose spread over the pairs is more than MISFIT_RATIO times
    their noise (the robot's declared noise and TRACKING_NOISE_FRACTION of the viewing distance for
    the tracking poses, in quadrature), naming the pairs that disagree most; None when it fits."""
    distance = float(np.median([np.linalg.norm(p.T_cam_board[:3, 3]) for p in pairs]))
    robot_m = robot_noise.translation_sigma_m + robot_noise.rotation_sigma_rad * distance
    noise_m = float(np.hypot(robot_m, TRACKING_NOISE_FRACTION * distance))
    r = PosePairModel(pairs, PAIR_NOISE_FREE).stacked(result.T_flange_cam, result.T_base_board)[0]
    off_m = np.linalg.norm(r[:, :3], axis=1)
    rms_m = float(np.sqrt(np.mean(off_m**2)))
    if not rms_m > MISFIT_RATIO * noise_m:
        return None
    worst = np.argsort(-off_m)[:FRAMES_NAMED]
    named = ", ".join(f"pair {pairs[i].frame} ({1e3 * off_m[i]:.0f} mm)" for i in worst)
    return (
        f"{result.method}'s result does not fit its data: the board pose's spread over the pairs is "
        f"{1e3 * rms_m:.3g} mm RMS, {rms_m / noise_m:.0f} times their noise ({1e3 * noise_m:.2g} mm: the "
        f"declared arm noise and {100 * TRACKING_NOISE_FRACTION:g} % of the viewing distance for the "
        f"tracking poses); the pairs that disagree most: {named}; check the pose directions (hec import's "
        "check), that each pair's poses belong together and the units; do not use this result"
    )


def tracking_bias_warning(pairs: list[PosePair], robot_noise: RobotPoseNoise) -> str | None:
    """A warning when the tracking poses' translations read a scale off what the robot's motions give
    (PosePairModel.tracking_scale, beyond scale_threshold sigmas and SCALE_NOTEWORTHY), sized at the
    pairs' median viewing distance (its sigma widened as the mount's for learned levels); None when
    the data show none."""
    model = PosePairModel(pairs, robot_noise)
    X, B = opencv_pose_pairs(pairs, "opencv-park")
    optimum = model.batch(X, B)
    levels = optimum.diagnostics.get("learned_pose_sigma")
    scale, sigma = model.tracking_scale(optimum.T_flange_cam, optimum.T_base_board, levels)
    threshold = scale_threshold(len(pairs), levels is not None)
    distance = float(np.median([np.linalg.norm(p.T_cam_board[:3, 3]) for p in pairs]))
    if sigma > SCALE_UNRESOLVED:
        return (
            "these pairs cannot measure a scale common to the tracking poses' translations (their "
            "camera's focal length, the board's printed scale): these views leave it "
            + ("undetermined" if not np.isfinite(sigma) else f"+-{100 * sigma:.1f} %")
            + " (views at one distance), and such a scale moves the mount along the line of sight "
            "unseen; add views nearer to and farther from the board to measure it"
        )
    if abs(scale - 1.0) <= max(threshold * sigma, SCALE_NOTEWORTHY):
        return None
    sigma *= np.sqrt(learned_noise_factor(len(pairs))) if levels is not None else 1.0
    return (
        f"the tracking poses' translations read {100 * (scale - 1.0):+.2f} % (+-{100 * sigma:.2f} %) off "
        "what the robot's motions give: a bias common to them (their camera's focal length, the board's "
        f"printed scale) that moves the mount by about {1e3 * abs(scale - 1.0) * distance:.1f} mm at these "
        f"pairs' {distance:.2f} m and that no uncertainty here covers: correct the tracking camera's "
        "intrinsics or the board file, or calibrate from the images to model them"
    )


def opencv_pose_pairs(pairs: list[PosePair], method: str) -> tuple[np.ndarray, np.ndarray]:
    """(T_flange_cam, T_base_board) by an OpenCV method on the pairs; B the mean of A_i X Z_i."""
    A = [p.T_base_flange for p in pairs]
    Z = [p.T_cam_board for p in pairs]
    try:
        if method in ROBOT_WORLD_METHODS:
            A_inv = [invert(a) for a in A]
            R_board_base, t_board_base, R_cam_flange, t_cam_flange = cv2.calibrateRobotWorldHandEye(
                [z[:3, :3] for z in Z],
                [z[:3, 3] for z in Z],
                [a[:3, :3] for a in A_inv],
                [a[:3, 3] for a in A_inv],
                method=OPENCV_METHODS[method],
            )
            X = invert(make_transform(R_cam_flange, t_cam_flange.ravel()))
        else:
            R, t = cv2.calibrateHandEye(
                [a[:3, :3] for a in A],
                [a[:3, 3] for a in A],
                [z[:3, :3] for z in Z],
                [z[:3, 3] for z in Z],
                method=OPENCV_METHODS[method],
            )
            X = make_transform(R, t.ravel())
    except cv2.error as exc:
        raise CalibrationInputError(
            f"{method} found no solution ({str(exc).strip().splitlines()[-1]})"
        ) from None
    if not np.all(np.isfinite(X)) or np.linalg.det(X[:3, :3]) <= 0.0:
        raise CalibrationInputError(f"{method} found no solution (its rotation is not a rotation)")
    return X, mean_pose([a @ X @ z for a, z in zip(A, Z, strict=True)])


class PosePairModel:
    """The measurement model of the module doc over a list of pairs."""

    def __init__(self, pairs: list[PosePair], robot_noise: RobotPoseNoise) -> None:
        self.pairs = pairs
        self.robot_cov = np.diag(
            [robot_noise.translation_sigma_m**2] * 3 + [robot_noise.rotation_sigma_rad**2] * 3
        )

    def residual(self, X: np.ndarray, B: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """r_i (6,), its Jacobian (6, 12) with respect to the perturbations of (X, B), and with
        respect to the perturbation of A_i (6, 6)."""
        pair = self.pairs[i]
        A = pair.T_base_flange
        C = invert(X) @ invert(A)  # base -> camera
        P = C @ B
        r = pose_minus(pair.T_cam_board, P)
        R_X, R_A, R_P = X[:3, :3], A[:3, :3], P[:3, :3]
        Q = invert(A) @ B  # the board in the flange frame
        # d(perturbation of P) / d(perturbations), rows (dt_P, dtheta_P).
        dP = np.zeros((6, 18))
        dP[:3, 0:3] = -R_X.T  # dt_X
        dP[:3, 3:6] = skew(P[:3, 3])  # dtheta_X
        dP[3:, 3:6] = -R_P.T
        dP[:3, 6:9] = C[:3, :3]  # dt_B
        dP[3:, 9:12] = np.eye(3)  # dtheta_B
        dP[:3, 12:15] = -R_X.T @ R_A.T  # dt_A
        dP[:3, 15:18] = R_X.T @ skew(Q[:3, 3])  # dtheta_A
        dP[3:, 15:18] = -Q[:3, :3].T
        # d r / d(perturbation of P): translation -I; rotation -J_r^-1(-e) (residual e = r[3:]).
        dr = np.zeros((6, 6))
        dr[:3, :3] = -np.eye(3)
        dr[3:, 3:] = -so3_right_jacobian_inverse(-r[3:])
        J = dr @ dP
        return r, J[:, :12], J[:, 12:]

    def stacked(self, X: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residuals (N, 6), state Jacobians (N, 6, 12) and robot-pose Jacobians (N, 6, 6)."""
        parts = [self.residual(X, B, i) for i in range(len(self.pairs))]
        return tuple(np.array(p) for p in zip(*parts, strict=True))

    def measurement_covariances(
        self, J_A: np.ndarray, levels: np.ndarray | None, indices: list[int] | None = None
    ) -> np.ndarray:
        """(n, 6, 6): the board pose covariance of the pairs at indices (default all; their own, or
        diag(levels^2), levels (6,) the sigmas per axis) plus the robot pose noise carried through
        J_A (n, 6, 6)."""
        pairs = self.pairs if indices is None else [self.pairs[i] for i in indices]
        own = [p.covariance if levels is None else np.diag(np.square(levels)) for p in pairs]
        return np.array(own) + J_A @ self.robot_cov @ np.swapaxes(J_A, 1, 2)

    def rms(self, X: np.ndarray, B: np.ndarray) -> tuple[float, float]:
        """RMS translation (metres) and rotation (radians) of the residuals."""
        r = self.stacked(X, B)[0]
        return float(np.sqrt(np.mean(np.sum(r[:, :3] ** 2, axis=1)))), float(
            np.sqrt(np.mean(np.sum(r[:, 3:] ** 2, axis=1)))
        )

    def tracking_scale(self, X: np.ndarray, B: np.ndarray, levels: np.ndarray | None) -> tuple[float, float]:
        """The scale of the tracking poses' translations (measured = scale x predicted) and its
        1-sigma, freed beside (X, B) at their optimum for these levels (see measurement_covariances):
        one Gauss-Newton step from scale 1, the model being linear in it. The sigma is inf when the
        views cannot tell the scale from the mount (all at one distance from the board)."""
        r, J, J_A = self.stacked(X, B)
        t_cam_board = np.array([(invert(X) @ invert(p.T_base_flange) @ B)[:3, 3] for p in self.pairs])
        d_scale = np.zeros((len(self.pairs), 6, 1))
        d_scale[:, :3, 0] = -t_cam_board  # d r / d(log scale) at scale 1
        J = np.concatenate([J, d_scale], axis=2)
        W = np.linalg.inv(self.measurement_covariances(J_A, levels))
        H = np.einsum("nji,njk,nkl->il", J, W, J)
        g = np.einsum("nji,njk,nk->i", J, W, r)
        # The scale's information with (X, B) free: the Schur complement of their block.
        gain = np.linalg.solve(H[:12, :12], H[:12, 12])
        information = float(H[12, 12] - H[12, :12] @ gain)
        if not information > 1e-12 * H[12, 12]:
            return 1.0, float("inf")
        step = -(g[12] - gain @ g[:12]) / information
        return float(np.exp(step)), float(1.0 / np.sqrt(information))

    def _gauss_newton(
        self, X: np.ndarray, B: np.ndarray, levels: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(X, B, information (12, 12), iterations) at the optimum for these noise levels."""
        iterations = 0
        while iterations < GN_ITERATIONS:
            iterations += 1
            r, J, J_A = self.stacked(X, B)
            W = np.linalg.inv(self.measurement_covariances(J_A, levels))
            H = np.einsum("nji,njk,nkl->il", J, W, J)
            g = np.einsum("nji,njk,nk->i", J, W, r)
            step = -np.linalg.solve(H, g)
            X, B = pose_plus(X, step[:6]), pose_plus(B, step[6:])
            if np.max(np.abs(step)) < 1e-12:
                break
        return X, B, H, iterations

    def batch(self, X: np.ndarray, B: np.ndarray) -> Calibration:
        """The optimum over all pairs (module doc), learning the board pose noise when the pairs
        have no covariance."""
        learn = any(p.covariance is None for p in self.pairs)
        levels = START_SIGMAS if learn else None
        for _ in range(VCE_ITERATIONS if learn else 1):
            X, B, H, iterations = self._gauss_newton(X, B, levels)
            if not learn:
                break
            updated = self._learned_levels(X, B, H, levels)
            done = np.all(np.abs(updated / levels - 1.0) < VCE_TOLERANCE)
            levels = updated
            if done:
                break
        if learn:
            X, B, H, iterations = self._gauss_newton(X, B, levels)
        result = Calibration("batch", X, np.linalg.inv(H)[:6, :6], B, None, [], len(self.pairs), 0)
        result.diagnostics["iterations"] = iterations
        widening = None if levels is None else self.level_widening(X, B, H, levels)
        self._note_noise(result, levels, widening)
        return result

    def _learned_levels(self, X: np.ndarray, B: np.ndarray, H: np.ndarray, levels: np.ndarray) -> np.ndarray:
        """Foerstner's variance component update of the per-axis sigmas levels (6,): each component's
        weighted squared residuals over its redundancy."""
        out = [
            sigma * np.sqrt(max(weighted, 0.0) / max(redundancy, 1e-12))
            for sigma, (weighted, redundancy, _) in zip(
                levels, self._components(X, B, H, levels), strict=True
            )
        ]
        return np.maximum(out, VCE_FLOOR * START_SIGMAS)

    def _components(
        self, X: np.ndarray, B: np.ndarray, H: np.ndarray, levels: np.ndarray
    ) -> list[tuple[float, float, np.ndarray]]:
        """Per component of levels (6,): its weighted squared residuals, its redundancy and its part of
        the information's sandwich, H_k (12, 12): inv(H) H_k inv(H) is what its noise adds to the
        state's covariance."""
        r, J, J_A = self.stacked(X, B)
        covs = self.measurement_covariances(J_A, levels)
        W = np.linalg.inv(covs)
        H_inv = np.linalg.inv(H)
        out = []
        for k, sigma in enumerate(levels):
            part = np.zeros(6)
            part[k] = sigma**2
            W_k = W @ (part[:, None] * np.eye(6)) @ W  # d(inverse covariance) direction of component k
            weighted = float(np.einsum("ni,nij,nj->", r, W_k, r))
            H_k = np.einsum("nji,njk,nkl->il", J, W_k, J)
            redundancy = float(np.einsum("nij,nji->", W_k, covs)) - float(np.trace(H_inv @ H_k))
            out.append((weighted, redundancy, H_k))
        return out

    def level_widening(self, X: np.ndarray, B: np.ndarray, H: np.ndarray, levels: np.ndarray) -> np.ndarray:
        """(6, 6) what the mount's covariance gains from levels (6,) being learned: each component's
        part widened by Student's t factor of its redundancy (hec.estimator.solve.level_uncertainty)."""
        H_inv = np.linalg.inv(H)
        widening = np.zeros((12, 12))
        for _, redundancy, H_k in self._components(X, B, H, levels):
            widening += (student_t_factor(redundancy) - 1.0) * (H_inv @ H_k @ H_inv)
        return 0.5 * (widening[:6, :6] + widening[:6, :6].T)

    def _note_noise(
        self, result: Calibration, levels: np.ndarray | None, widening: np.ndarray | None
    ) -> None:
        """Note learned levels (6,) on the result and widen its covariance by widening (6, 6)
        (level_widening), unless the pairs are exact."""
        if levels is None:
            return
        result.diagnostics["learned_pose_sigma"] = levels
        result.diagnostics["level_widening"] = widening
        # A component at its floor has no scatter beyond what the arm's declared noise explains.
        floored = levels <= 1.001 * VCE_FLOOR * START_SIGMAS
        if floored.all():
            result.warnings.append(
                "the pairs give no covariance for the board pose and fit each other exactly (residuals at "
                "numerical precision): there is no noise to learn and the uncertainty is that of exact "
                "pairs; real poses are never exact (were these simulated without noise?)"
            )
            return
        shown = np.r_[1e3 * levels[:3], np.degrees(levels[3:])]
        texts = [
            "none" if low else f"{v:.{3 if k < 3 else 4}f}"
            for k, (v, low) in enumerate(zip(shown, floored, strict=True))
        ]
        gain = float(np.trace(widening) / np.trace(result.covariance))
        result.covariance = result.covariance + widening
        result.warnings.append(
            f"the pairs give no covariance for the board pose: its noise was learned from the data, 1 sigma "
            f"[mm] along the camera's x y z {' '.join(texts[:3])}, [deg] about the board's x y z "
            f"{' '.join(texts[3:])}"
            + (" ('none': the declared arm noise explains all the scatter there)" if floored.any() else "")
            + f"; the mount's variance is widened by {100 * gain:.0f} % for the levels being learned from "
            f"{len(self.pairs)} pairs"
        )

    def filter(self, X: np.ndarray, B: np.ndarray, iterated: bool) -> Calibration:
        """The pairs fused one at a time (module doc), at the noise levels batch learns (or the
        pairs' own covariances)."""
        learn = any(p.covariance is None for p in self.pairs)
        learned = self.batch(X, B).diagnostics if learn else {}
        levels = learned.get("learned_pose_sigma")
        state_cov = np.diag([FILTER_PRIOR_SIGMA[0] ** 2] * 3 + [FILTER_PRIOR_SIGMA[1] ** 2] * 3)
        P = np.zeros((12, 12))
        P[:6, :6] = P[6:, 6:] = state_cov
        for i in range(len(self.pairs)):
            X0, B0 = X, B
            for _ in range(10 if iterated else 1):
                r, J, J_A = self.residual(X, B, i)
                R = self.measurement_covariances(J_A[None], levels, [i])[0]
                delta_now = np.concatenate([pose_minus(X, X0), pose_minus(B, B0)])
                innovation = r - J @ delta_now
                S = J @ P @ J.T + R
                K = P @ J.T @ np.linalg.inv(S)
                delta = -K @ innovation
                X, B = pose_plus(X0, delta[:6]), pose_plus(B0, delta[6:])
                if not iterated or np.max(np.abs(delta - delta_now)) < 1e-12:
                    break
            P = (np.eye(12) - K @ J) @ P
        result = Calibration("ekf", X, P[:6, :6], B, None, [], len(self.pairs), 0)
        self._note_noise(result, levels, learned.get("level_widening"))
        return result
