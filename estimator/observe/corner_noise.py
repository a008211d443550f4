"""The corner noise a dataset actually reached, measured from how well its markers agree.

The detector's corner covariance is the image-noise part of the code alignment plus a constant
floor per coordinate (hec.estimator.targets.qr_fit) measured on renders; blur, lighting, a lens
the alignment's per-marker homography does not model, or a real camera's processing give more.
What they give shows in the data: in every frame all markers lie on one board, so one model
must explain every corner of every frame at once:

    uv_imk = K distort(P_i(xy_mk + shift_m, z(xy_mk + shift_m)); dist + (dk1, dk2, 0, 0, 0))

with xy_mk the board-frame (x, y) of corner k of marker m (metres, the definition's), P_i
the view of frame i: a homography H_i from the board plane to undistorted normalised
coordinates (8 unknowns per frame: any board pose and any error of K) with the height z out
of the sheet added along the board normal that H_i implies; dk1, dk2 the radial distortion
the dataset does not declare; shift_m where the printer put marker m (2 per marker, shared
by all frames; a weak prior fixes the common shift every H_i absorbs; only on boards whose
markers are placed one by one, Target.markers_placed_one_by_one); and z = c0 x^2 +
c1 x y + c2 y^2 the sheet's bend (3 unknowns; lower orders are a pose). What this model
leaves is the corners' own error: on the realistic cell's true corners (K 0.3 % and 3 px
off, the lens undeclared, a 0.7 mm bend, shifted markers) it leaves 0.008 px RMS.

The measured noise is the RMS of the N corner residuals of the fit (P unknowns) times
sqrt(N / (N - P)), leaving out gross errors (beyond OUTLIER_GATE robust sigmas). The learned
floor f is the one for which those residuals, so scaled and divided by sqrt(c + f^2) (c: the
image-noise variance of that coordinate in the detector's covariance), have a mean square of
1; the covariances then use max(f, the constant floor). The centres' floor grows with it,
in the constants' ratio: the errors of a marker's corners largely cancel at its centre (a
change of its apparent size does not move it), on renders of the ideal and of the realistic
cell alike (centre error 0.27-0.30 of the corners'), and the markers' agreement cannot show
how much: fitted to the centres alone, the model absorbs half of their error.

What the model can absorb does not show: a bias shared by all markers of a frame (a light
gradient moving every edge the same way) looks like another pose, a bias that grows toward
the image border like another lens. On renders of the realistic cell the measured noise is
about 0.8 of the corners' RMS error against the truth for that reason (the normalised
errors come out near 1.45 rather than 1); the downstream estimator, which learns the pixel
noise from the robot's poses, sees those biases as what they look like.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.optimize import brentq, least_squares
from scipy.sparse import lil_matrix

from hec.estimator.geometry.camera import CameraIntrinsics, distort, pixel_rays
from hec.estimator.observe.observations import FrameObservations, with_pixel_floor
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.target import Target

# Fewest residual degrees of freedom for a measured figure.
MIN_DOF = 16
# Residuals beyond this many robust sigmas (1.4826 median |r|) are gross errors (a failed
# alignment), not noise: the corners' real errors have heavy tails that reach 8 (glare, a
# marker curved by the lens), which a narrower gate would cut from the measured noise.
OUTLIER_GATE = 10.0
# Robust loss scale of the final fit, in robust standard deviations of the first fit.
LOSS_SCALE = 3.0
# A board whose points miss the best homography of each view by more than this (robust sigma,
# pixels) is not the board in the images (a wrong or mirrored board file): nothing to learn from.
# Rendered views miss it by 0.01 px in the ideal cell and 0.13-0.24 px (at most 1.0 px) in the
# realistic one, with its unmodelled lens; the 8-QR board file mirrored top to bottom by 23 px.
BOARD_MISFIT_PX = 10.0
# Prior on each marker's print shift, metres: weak, it only fixes the common shift.
SHIFT_PRIOR_M = 0.005


@dataclass(frozen=True)
class CornerNoise:
    """The corner noise reached on a dataset and the floors the covariances use, pixels per
    coordinate. measured_px: None when it could not be measured (reason says why). frames,
    corners: what was measured from; dof: residual degrees of freedom.
    lens_k: the fitted (dk1, dk2) added to the declared distortion."""

    floor_px: float
    center_floor_px: float
    constant_px: float
    center_constant_px: float
    measured_px: float | None = None
    frames: int = 0
    corners: int = 0
    dof: int = 0
    lens_k: tuple[float, float] = (0.0, 0.0)
    reason: str | None = None

    def describe(self) -> str:
        """One line for a person: the measured figure beside the constant floor."""
        constant = f"constant {self.constant_px:.3f} px"
        if self.measured_px is None:
            return f"corner noise floor: not measured ({self.reason}); covariances use the {constant}"
        used = (
            f"the measured (floor {self.floor_px:.3f} px per corner coordinate, "
            f"{self.center_floor_px:.3f} px at centres)"
            if self.floor_px > self.constant_px
            else "the constant (the measured is not larger)"
        )
        return (
            f"corner noise floor: measured {self.measured_px:.3f} px from {self.frames} frames "
            f"({self.corners} corners, {self.dof} degrees of freedom; {constant}); covariances use {used}"
        )

    def to_dict(self) -> dict:
        return {
            "floor_px": self.floor_px,
            "center_floor_px": self.center_floor_px,
            "constant_px": self.constant_px,
            "center_constant_px": self.center_constant_px,
            "measured_px": self.measured_px,
            "frames": self.frames,
            "corners": self.corners,
            "dof": self.dof,
            "lens_k": list(self.lens_k),
            "reason": self.reason,
            "units": "pixels per image coordinate",
        }


@dataclass(frozen=True)
class _Views:
    """The corners of the markers of the frames with at least two, one row per marker: frame
    (n,) and marker (n,) indices (0-based, of the frames and markers that occur), points_px
    (n, P, 2) and their image-noise variances (n, P, 2, pixels^2), board_xy (M, P, 2) the
    points on the board (metres)."""

    frame: np.ndarray
    marker: np.ndarray
    points_px: np.ndarray
    image_var: np.ndarray
    board_xy: np.ndarray
    n_frames: int


@dataclass(frozen=True)
class BoardFit:
    """The fitted model's residuals (measured minus model, pixels) at the n markers' points
    (n, p, 2) with their image-noise variances (same shape, pixels^2); frames: frames fitted;
    unknowns: P; lens_k: the fitted (dk1, dk2)."""

    residuals: np.ndarray
    image_var: np.ndarray
    frames: int
    unknowns: int
    lens_k: tuple[float, float]

    @property
    def dof(self) -> int:
        return self.residuals.size - self.unknowns

    @property
    def dof_factor(self) -> float:
        """sqrt(N / (N - P)): how much larger the errors are than the residuals."""
        return float(np.sqrt(self.residuals.size / max(self.dof, 1)))


def _views(observations: list[FrameObservations], board: Target, corner_floor_px: float) -> _Views:
    """The corners the fit can use (of the frames with 2 or more markers), with the constant
    floor their covariances hold taken out of their variances."""
    usable = [o for o in observations if o.problem is None and len(o.markers) >= 2]
    markers = [(f, m) for f, o in enumerate(usable) for m in o.markers]
    ids = sorted({m.marker_id for _, m in markers})
    var = [np.diag(m.corners_cov) - corner_floor_px**2 for _, m in markers]
    P = board.points_per_marker
    return _Views(
        frame=np.array([f for f, _ in markers], dtype=int),
        marker=np.array([ids.index(m.marker_id) for _, m in markers], dtype=int),
        points_px=np.array([m.corners_px for _, m in markers]).reshape(-1, P, 2),
        image_var=np.maximum(np.array(var).reshape(-1, P, 2), 0.0),
        board_xy=np.array([board.marker_corners(i)[:, :2] for i in ids]).reshape(-1, P, 2),
        n_frames=len(usable),
    )


def _pixels(xy_norm: np.ndarray, intrinsics: CameraIntrinsics, lens_k: np.ndarray) -> np.ndarray:
    """(..., 2) undistorted normalised coordinates -> pixels through the declared lens plus lens_k."""
    dist = np.array((tuple(intrinsics.dist) + (0.0,) * 5)[:5])
    dist[:2] += lens_k
    flat = distort(xy_norm.reshape(-1, 2), tuple(dist))
    uv = flat * [intrinsics.fx, intrinsics.fy] + [intrinsics.cx, intrinsics.cy]
    return uv.reshape(xy_norm.shape)


def _through(H: np.ndarray, xy: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Board points (xy (n, p, 2), height z (n, p) out of the face, metres) seen through
    per-row homographies H (n, 3, 3) to normalised coordinates (n, p, 2). H = s [r1 r2 t] of
    the board pose, so the height adds z s r3, s r3 = (h1 x h2) / sqrt(|h1 x h2|)."""
    n = np.cross(H[:, :, 0], H[:, :, 1])
    s_r3 = n / np.sqrt(np.linalg.norm(n, axis=1))[:, None]
    w = xy @ H[:, :, :2].transpose(0, 2, 1) + H[:, None, :, 2] + z[:, :, None] * s_r3[:, None, :]
    return w[:, :, :2] / w[:, :, 2:3]


class _Model:
    """The board-views model of the module docstring over one _Views. Unknowns, packed: H_i
    flat[:8] per frame; dk1, dk2 if lens; if bend, the sheet's height z = c0 x^2 + c1 x y +
    c2 y^2 (metres, the board centre at 0; lower orders are a pose); if shifts, each marker's shift."""

    def __init__(
        self, views: _Views, intrinsics: CameraIntrinsics, lens: bool, shifts: bool, bend: bool
    ) -> None:
        self.views, self.intrinsics = views, intrinsics
        self.n_h = 8 * views.n_frames
        self.n_lens = 2 if lens else 0
        self.n_shape = 3 if bend else 0
        self.n_shift = 2 * len(views.board_xy) if shifts else 0
        self.size = self.n_h + self.n_lens + self.n_shape + self.n_shift

    def unpack(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Homographies (F, 3, 3), lens_k (2,), height coefficients (3,), shifts (M, 2) metres."""
        F, i = self.views.n_frames, self.n_h
        H = np.concatenate([params[:i].reshape(F, 8), np.ones((F, 1))], axis=1).reshape(F, 3, 3)
        lens_k = params[i : i + 2] if self.n_lens else np.zeros(2)
        i += self.n_lens
        shape = params[i : i + 3] if self.n_shape else np.zeros(3)
        i += self.n_shape
        shifts = params[i:].reshape(-1, 2) if self.n_shift else np.zeros((len(self.views.board_xy), 2))
        return H, lens_k, shape, shifts

    def predict(self, params: np.ndarray) -> np.ndarray:
        """Model pixels (n, p, 2) of every row's points."""
        H, lens_k, shape, shifts = self.unpack(params)
        v = self.views
        xy = v.board_xy[v.marker] + shifts[v.marker][:, None]
        x, y = xy[..., 0], xy[..., 1]
        z = shape[0] * x * x + shape[1] * x * y + shape[2] * y * y
        return _pixels(_through(H[v.frame], xy, z), self.intrinsics, lens_k)

    def residuals(self, params: np.ndarray) -> np.ndarray:
        """The points' residuals (model minus measured, pixels), then the shift prior's."""
        prior = self.unpack(params)[3].ravel() / SHIFT_PRIOR_M if self.n_shift else np.zeros(0)
        return np.concatenate([(self.predict(params) - self.views.points_px).ravel(), prior])

    def sparsity(self) -> lil_matrix:
        """Which unknowns each residual depends on."""
        v = self.views
        per_row = v.points_px[0].size
        shared = self.n_h + self.n_lens + self.n_shape
        S = lil_matrix((v.points_px.size + self.n_shift, self.size), dtype=int)
        for row, (f, m) in enumerate(zip(v.frame, v.marker, strict=True)):
            rows = slice(per_row * row, per_row * (row + 1))
            S[rows, 8 * f : 8 * f + 8] = 1
            S[rows, self.n_h : shared] = 1
            if self.n_shift:
                S[rows, shared + 2 * m : shared + 2 * m + 2] = 1
        for k in range(self.n_shift):
            S[v.points_px.size + k, shared + k] = 1
        return S

    def start(self) -> np.ndarray:
        """Per-frame homographies from the declared lens; no lens deltas, flat sheet, no shifts."""
        v = self.views
        H0 = []
        for f in range(v.n_frames):
            rows = v.frame == f
            xy = pixel_rays(v.points_px[rows].reshape(-1, 2), self.intrinsics)[0][:, :2]
            H, _ = cv2.findHomography(v.board_xy[v.marker[rows]].reshape(-1, 2), xy, 0)
            H0.append((H / H[2, 2]).ravel()[:8])
        return np.concatenate([np.ravel(H0), np.zeros(self.size - self.n_h)])


class BoardMisfitError(ValueError):
    """The board's layout does not fit the detected points (BOARD_MISFIT_PX)."""


def fit_board_views(
    observations: list[FrameObservations],
    board: Target,
    intrinsics: CameraIntrinsics,
    settings: DetectorSettings,
    lens: bool = True,
    printed: bool = True,
) -> BoardFit | None:
    """The robust fit of the module docstring's model to the corners of observations detected
    with settings, without the lens deltas if lens is False and without the sheet's bend and
    the markers' shifts if printed is False (no shifts on a board printed as one pattern); None
    when it leaves fewer than MIN_DOF degrees of freedom; BoardMisfitError when the board's layout
    does not fit the points (BOARD_MISFIT_PX). Least squares first, then a soft-L1 loss at LOSS_SCALE
    robust sigmas."""
    views = _views(observations, board, detector_for(board, settings).corner_floor_px)
    model = _Model(views, intrinsics, lens, printed and board.markers_placed_one_by_one, printed)
    n = views.points_px.size
    if n - model.size < MIN_DOF:
        return None
    start = model.start()
    misfit = _robust_sigma(model.residuals(start)[:n])
    if misfit > BOARD_MISFIT_PX:
        raise BoardMisfitError(
            f"the board's points miss each view's best homography by {misfit:.3g} px (robust sigma): "
            "is the board file the board in the images?"
        )
    sparsity = model.sparsity()
    first = least_squares(model.residuals, start, jac_sparsity=sparsity, x_scale="jac")
    scale = max(_robust_sigma(first.fun[:n]), 1e-6)
    final = least_squares(
        model.residuals,
        first.x,
        jac_sparsity=sparsity,
        x_scale="jac",
        loss="soft_l1",
        f_scale=LOSS_SCALE * scale,
    )
    dk1, dk2 = model.unpack(final.x)[1]
    return BoardFit(
        residuals=views.points_px - model.predict(final.x),
        image_var=views.image_var,
        frames=views.n_frames,
        unknowns=model.size,
        lens_k=(float(dk1), float(dk2)),
    )


def _robust_sigma(residuals: np.ndarray) -> float:
    """1.4826 median |r|: the standard deviation of normal residuals, pixels."""
    return 1.4826 * float(np.median(np.abs(residuals)))


def _inliers(residuals: np.ndarray) -> np.ndarray:
    """bool, residuals within OUTLIER_GATE robust sigmas."""
    return np.abs(residuals) <= OUTLIER_GATE * _robust_sigma(residuals)


def measured_noise(residuals: np.ndarray, dof_factor: float) -> float:
    """The noise (pixels) behind fit residuals: their RMS within the gate times dof_factor."""
    return float(np.sqrt(np.mean(np.square(residuals[_inliers(residuals)])))) * dof_factor


def learned_floor(residuals: np.ndarray, image_var: np.ndarray, dof_factor: float) -> float:
    """The floor f (pixels) for which residuals * dof_factor / sqrt(image_var + f^2) within the
    gate have a mean square of 1; 0 when the image noise alone explains them. residuals and
    image_var: the same shape, pixels and pixels^2."""
    keep = _inliers(residuals)
    z2 = np.square(residuals[keep] * dof_factor)
    var = image_var[keep]

    def excess(f: float) -> float:
        return float(np.mean(z2 / (var + f * f + 1e-18))) - 1.0

    if excess(0.0) <= 0.0:
        return 0.0
    return float(brentq(excess, 0.0, float(np.sqrt(z2.max())) + 1e-9, xtol=1e-7))


def measure_corner_noise(
    observations: list[FrameObservations],
    board: Target,
    intrinsics: CameraIntrinsics,
    settings: DetectorSettings,
) -> CornerNoise:
    """The corner noise of a dataset's observations (detected with ``settings`` by the board's
    detector, whose constant floors their covariances hold) and the floors the covariances should use."""
    detector = detector_for(board, settings)
    corner_floor, center_floor = detector.corner_floor_px, detector.center_floor_px
    constant = {
        "floor_px": corner_floor,
        "center_floor_px": center_floor,
        "constant_px": corner_floor,
        "center_constant_px": center_floor,
    }
    try:
        fit = fit_board_views(observations, board, intrinsics, settings)
    except BoardMisfitError as exc:
        return CornerNoise(**constant, reason=str(exc))
    if fit is None:
        return CornerNoise(
            **constant, reason=f"fewer than {MIN_DOF} degrees of freedom in the frames with 2+ markers"
        )
    floor = max(learned_floor(fit.residuals, fit.image_var, fit.dof_factor), corner_floor)
    return CornerNoise(
        floor_px=floor,
        center_floor_px=floor * center_floor / corner_floor,
        constant_px=corner_floor,
        center_constant_px=center_floor,
        measured_px=measured_noise(fit.residuals, fit.dof_factor),
        frames=fit.frames,
        corners=fit.residuals.size // 2,
        dof=fit.dof,
        lens_k=fit.lens_k,
    )


def apply_corner_noise(
    observations: list[FrameObservations],
    noise: CornerNoise,
    intrinsics: CameraIntrinsics,
) -> list[FrameObservations]:
    """The observations with every marker's covariances on noise's floors instead of the
    constant ones they were detected with (pixels, and the 3D points that follow from them)."""
    corner = noise.floor_px**2 - noise.constant_px**2
    center = noise.center_floor_px**2 - noise.center_constant_px**2
    return [
        replace(o, markers=[with_pixel_floor(m, corner, center, intrinsics) for m in o.markers])
        for o in observations
    ]


def learn_corner_floor(
    observations: list[FrameObservations],
    board: Target,
    intrinsics: CameraIntrinsics,
    settings: DetectorSettings,
) -> tuple[list[FrameObservations], CornerNoise | None]:
    """A dataset's observations (detected with settings) on the floors their markers show, and
    what was measured; unchanged, and None, when settings.learn_corner_floor is off."""
    if not settings.learn_corner_floor:
        return observations, None
    noise = measure_corner_noise(observations, board, intrinsics, settings)
    return apply_corner_noise(observations, noise, intrinsics), noise
