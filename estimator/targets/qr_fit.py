"""Sub-pixel marker corners: align the known QR code to the image and give the corners' covariance.

A decoded marker's code is regenerated from the board definition, so the
whole symbol (finder patterns, timing and data modules) becomes a template.
The fit:

1. ``orient_corners``: the four rough corners from any decoder, in any order,
   are put in the marker's own order (top-left, top-right, bottom-right,
   bottom-left of the upright symbol) by sampling the module centres under
   each of the 8 orderings and keeping the one that matches the known code.
2. ``fit_marker``: a homography from the symbol to the image is refined by
   maximising the enhanced correlation coefficient (OpenCV's findTransformECC,
   invariant to gain and offset) between the template and the image.
3. The corners' 8x8 covariance is the Gauss-Newton one, sigma^2 (J^T J)^-1,
   where J is the fitted model's gradient times the derivative of each
   pixel's position with respect to the corners and sigma is the image noise
   measured in the marker's flat parts, plus a floor per coordinate for the
   errors image noise does not explain (DEFAULT_*_FLOOR_PX).

Symbol coordinates (a, b): a along the top edge from corner 0 to corner 1,
b along the left edge from corner 0 to corner 3, both in units of the symbol
side, so the corners are (0, 0), (1, 0), (1, 1), (0, 1). The homography maps
(a, b, 1) to image pixels (u, v, 1) with H[2, 2] = 1.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import cv2
import numpy as np

from hec.estimator.targets.ecc import ECC_SMOOTHING, align, opencv_reason, paper_mask

UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
# Quiet-zone modules kept around the symbol in the template (boards keep at least 4).
TEMPLATE_QUIET_MODULES = 2
# Standard deviation of 8-bit rounding, grey levels: the least image noise there is.
QUANTISATION_SIGMA = 1.0 / np.sqrt(12.0)
# Error per coordinate that image noise does not explain, pixels, for a corner and for
# the centre. Measured on noise-free renders of the default trajectory (RMS 0.013 px per
# corner coordinate, 0.0036 px at the centre: the renderer's texture sampling mostly
# changes a marker's apparent size, which cancels at its centre). A real cell adds more;
# a dataset's observations get the floor their markers' agreement shows
# (hec.estimator.observe.corner_noise), these as the least.
DEFAULT_CORNER_FLOOR_PX = 0.013
DEFAULT_CENTER_FLOOR_PX = 0.0036
# Fits (at most) of a code whose quiet zone holds something else than paper, each masking it where the
# previous one placed the code: the rough corners can be off by half a module (fit_template).
NOT_PAPER_PASSES = 3
# Module agreement that leaves no doubt about an ordering (a wrong one scores about 0.5-0.7).
CLEAR_AGREEMENT = 0.95
# The 8 ways four corners can be listed: 4 starting corners x 2 windings.
_ORDERINGS = [np.roll(np.arange(4), -k) for k in range(4)] + [
    np.roll(np.arange(4)[::-1], -k) for k in range(4)
]


# The rows of homography_from_corners' linear system that do not depend on the corners (8, 8), and
# the symbol coordinates (a, b) its last two columns multiply by -u or -v (8, 2), rows u0, v0, ..., v3.
_HOMOGRAPHY_AB = np.repeat(UNIT_SQUARE, 2, axis=0)
_HOMOGRAPHY_ROWS = np.zeros((8, 8))
_HOMOGRAPHY_ROWS[0::2, 0:2] = _HOMOGRAPHY_ROWS[1::2, 3:5] = UNIT_SQUARE
_HOMOGRAPHY_ROWS[0::2, 2] = _HOMOGRAPHY_ROWS[1::2, 5] = 1.0


class MarkerFitError(ValueError):
    """The code could not be aligned to the image; the message says why."""


def homography_from_corners(corners_px: np.ndarray) -> np.ndarray:
    """(..., 3, 3) homographies mapping symbol coordinates (a, b, 1) to pixels, H[2, 2] = 1.

    corners_px: (..., 4, 2) image corners in the marker's order. Solved in float64.
    """
    flat = np.asarray(corners_px, dtype=np.float64).reshape(*np.shape(corners_px)[:-2], 8)
    A = np.broadcast_to(_HOMOGRAPHY_ROWS, flat.shape[:-1] + (8, 8)).copy()
    A[..., 6:] = -_HOMOGRAPHY_AB * flat[..., None]
    h = np.linalg.solve(A, flat[..., None])[..., 0]
    return np.concatenate([h, np.ones(flat.shape[:-1] + (1,))], axis=-1).reshape(*flat.shape[:-1], 3, 3)


def apply_homography(H: np.ndarray, ab: np.ndarray) -> np.ndarray:
    """(..., N, 2) image points of (N, 2) symbol coordinates under H (..., 3, 3)."""
    uvw = ab @ np.swapaxes(H[..., :, :2], -1, -2) + H[..., None, :, 2]
    return uvw[..., :2] / uvw[..., 2:3]


def _point_jacobian_wrt_h(H: np.ndarray, ab: np.ndarray) -> np.ndarray:
    """(..., N, 2, 8) derivative of the image points of ab (N, 2) with respect to h = H.flat[:8]
    for homographies H (..., 3, 3)."""
    uv = apply_homography(H, ab)
    u, v = uv[..., 0], uv[..., 1]
    a, b = np.broadcast_to(ab[:, 0], u.shape), np.broadcast_to(ab[:, 1], u.shape)
    d = H[..., 2, 0, None] * a + H[..., 2, 1, None] * b + 1.0
    zero, one = np.zeros_like(u), np.ones_like(u)
    du = np.stack([a, b, one, zero, zero, zero, -a * u, -b * u], axis=-1) / d[..., None]
    dv = np.stack([zero, zero, zero, a, b, one, -a * v, -b * v], axis=-1) / d[..., None]
    return np.stack([du, dv], axis=-2)


def point_jacobian_wrt_corners(corners_px: np.ndarray, ab: np.ndarray) -> np.ndarray:
    """(..., N, 2, 8) derivative of the image points of symbol coordinates ab (N, 2) with respect
    to the corners (u0, v0, u1, v1, ..., v3) of (..., 4, 2) that define the homography."""
    H = homography_from_corners(corners_px)
    dcorners_dh = _point_jacobian_wrt_h(H, UNIT_SQUARE).reshape(*H.shape[:-2], 8, 8)
    dh_dcorners = np.linalg.inv(dcorners_dh)[..., None, :, :]
    return _point_jacobian_wrt_h(H, np.asarray(ab, dtype=np.float64)) @ dh_dcorners


def center_from_corners(corners_px: np.ndarray) -> np.ndarray:
    """(..., 2) image of the symbol centre of (..., 4, 2) corners: where the diagonals cross (exact
    under perspective)."""
    return apply_homography(homography_from_corners(corners_px), np.array([[0.5, 0.5]]))[..., 0, :]


def _bilinear(gray: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample a grey image at (..., 2) pixel positions; outside the image gives NaN."""
    flat = uv.reshape(-1, 2).astype(np.float32)
    return cv2.remap(
        gray if gray.dtype == np.float32 else gray.astype(np.float32),
        flat[:, 0:1],
        flat[:, 1:2],
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=np.nan,
    ).reshape(uv.shape[:-1])


def sample_modules(gray: np.ndarray, corners_px: np.ndarray, n: int) -> np.ndarray | None:
    """(n, n) bool, True where the module centre reads dark, row 0 at the symbol's top; None if
    any module centre is outside the image.

    corners_px: (4, 2) corners in the marker's order. The threshold is halfway between the
    10th and 90th percentiles of the sampled values.
    """
    centres = (np.arange(n) + 0.5) / n
    ab = np.stack(np.meshgrid(centres, centres, indexing="xy"), axis=-1).reshape(-1, 2)
    samples = _bilinear(gray, apply_homography(homography_from_corners(corners_px), ab))
    if not np.all(np.isfinite(samples)):
        return None
    lo, hi = np.percentile(samples, [10, 90])
    return (samples < 0.5 * (lo + hi)).reshape(n, n)


def module_agreement(
    gray: np.ndarray, corners_px: np.ndarray, modules: np.ndarray, where: np.ndarray | None = None
) -> float:
    """Fraction of module centres whose dark/light state in the image matches ``modules``.

    corners_px: (4, 2) corners in the marker's order. modules: (n, n) bool, True = dark,
    row 0 at the symbol's top. where: (n, n) bool, the modules to count (default all).
    Returns 0.0 if any module centre is outside the image.
    """
    dark = sample_modules(gray, corners_px, modules.shape[0])
    if dark is None:
        return 0.0
    same = dark == modules
    return float(np.mean(same if where is None else same[where]))


def orient_corners(
    gray: np.ndarray, corners_px: np.ndarray, modules: np.ndarray, where: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Reorder four corners (any start, either winding) into the marker's order.

    Orderings are tried as given first; the first with agreement >= CLEAR_AGREEMENT wins,
    else the best of all 8. where: (n, n) bool, the modules that count (default all).
    Returns the (4, 2) reordered corners and the module agreement of the best ordering.
    """
    orderings = corner_orderings(corners_px)
    scores = []
    for corners in orderings:
        scores.append(module_agreement(gray, corners, modules, where))
        if scores[-1] >= CLEAR_AGREEMENT:
            break
    best = int(np.argmax(scores))
    return orderings[best], scores[best]


def corner_orderings(corners_px: np.ndarray) -> list[np.ndarray]:
    """The 8 ways (4 starts x 2 windings) four (4, 2) corners can be listed, as given first."""
    corners_px = np.asarray(corners_px, dtype=np.float64)
    return [corners_px[order] for order in _ORDERINGS]


@functools.lru_cache(maxsize=256)
def _template(modules_bytes: bytes, n: int, px_per_module: int, dark_corners: bool = False) -> np.ndarray:
    """(S, S) float32 template: white quiet zone, black modules; module edges on pixel edges. With
    dark_corners, the quiet zone's four corner blocks are black (squares touching the symbol's
    corners from outside, at least the quiet zone wide)."""
    modules = np.frombuffer(modules_bytes, dtype=bool).reshape(n, n)
    q = TEMPLATE_QUIET_MODULES
    padded = np.ones((n + 2 * q, n + 2 * q), dtype=np.float32)
    if dark_corners:
        for rows in (slice(0, q), slice(n + q, n + 2 * q)):
            for cols in (slice(0, q), slice(n + q, n + 2 * q)):
                padded[rows, cols] = 0.0
    padded[q : q + n, q : q + n] = np.where(modules, 0.0, 1.0)
    return np.kron(padded, np.ones((px_per_module, px_per_module), dtype=np.float32)) * 255.0


@dataclass(frozen=True)
class MarkerFit:
    """A refined marker: corners (4, 2) in the marker's order, their (8, 8) covariance
    (u0, v0, ..., v3; pixels^2), the centre (2,) and its (2, 2) covariance, the ECC
    correlation of the final fit (0..1), the module agreement (0..1) and the image
    noise (grey levels) the covariance was computed with."""

    corners_px: np.ndarray
    corners_cov: np.ndarray
    center_px: np.ndarray
    center_cov: np.ndarray
    correlation: float
    module_agreement: float
    noise_sigma: float


def fit_marker(
    gray: np.ndarray,
    corners_px: np.ndarray,
    modules: np.ndarray,
    corner_floor_px: float = DEFAULT_CORNER_FLOOR_PX,
    center_floor_px: float = DEFAULT_CENTER_FLOOR_PX,
    max_iterations: int = 30,
    min_correlation: float = 0.8,
    max_template_px_per_module: int = 3,
    dark_corners: bool = False,
    not_paper_ab: np.ndarray | None = None,
) -> MarkerFit:
    """Refine oriented corners by aligning the marker's code to the image.

    gray: (H, W) uint8. corners_px: (4, 2) rough corners in the marker's order.
    modules: (n, n) bool code of this marker. corner_floor_px, center_floor_px: standard
    deviation per coordinate of the errors image noise does not explain, added to the
    corners' and the centre's covariance. The template is drawn at the image's pixels per module,
    clipped to [2, max_template_px_per_module]: a template much coarser than the image biases the
    corners (AprilTag cells of 8-11 px fitted with 3 px ones shrank the tag by 0.04 px; QR modules
    of 3-5 px gain nothing from more). dark_corners: black squares touch the marker's corners from
    outside (Kalibr's AprilGrid; _template). not_paper_ab: (K, 4) rectangles in symbol coordinates
    where the sheet around the code is not plain paper (board.not_paper_around; fit_template).
    Raises MarkerFitError when the marker with its quiet zone leaves the image, the fit diverges, or
    its correlation stays below min_correlation.
    """
    n = modules.shape[0]
    corners_px = np.asarray(corners_px, dtype=np.float64)
    px_per_module = int(np.clip(round(_side_px(corners_px) / n), 2, max_template_px_per_module))
    q = TEMPLATE_QUIET_MODULES
    fit = fit_template(
        gray,
        corners_px,
        _template(modules.tobytes(), n, px_per_module, dark_corners),
        TemplateFrame(n * px_per_module, q * px_per_module),
        (q + 1) / n,
        corner_floor_px,
        center_floor_px,
        max_iterations,
        min_correlation,
        not_paper_ab=not_paper_ab,
    )
    return replace(fit, module_agreement=module_agreement(gray, fit.corners_px, modules))


def _side_px(corners_px: np.ndarray) -> float:
    """Mean side length (pixels) of a (4, 2) quad."""
    return float(np.linalg.norm(corners_px - np.roll(corners_px, 1, axis=0), axis=1).mean())


@dataclass(frozen=True)
class TemplateFrame:
    """Where the symbol (the unit square of symbol coordinates) lies in a template image: it spans
    template pixels [offset_px - 0.5, offset_px + side_px - 0.5] along u (right) and the same from
    offset_v_px along v (down; None: offset_px), pixel centres at integers, so the symbol's edges
    fall on pixel edges. An offset is negative where the template stops inside the symbol."""

    side_px: int
    offset_px: int
    offset_v_px: int | None = None

    def ab_to_template(self) -> np.ndarray:
        """(3, 3) symbol coordinates (a, b, 1) -> template pixels."""
        s, o = float(self.side_px), self.offset_px - 0.5
        o_v = o if self.offset_v_px is None else self.offset_v_px - 0.5
        return np.array([[s, 0.0, o], [0.0, s, o_v], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class FitWords:
    """How fit_template's errors say what went wrong: the alignment's name, what is out of the image
    before and after the fit, and who gave the rough corners."""

    alignment: str = "code alignment"
    outside: str = "the code itself (not only its quiet zone) is partly outside the image"
    leaves: str = "the fitted code leaves the image"
    rough_source: str = "the decoder's"


CODE_WORDS = FitWords()


def fit_template(
    gray: np.ndarray,
    corners_px: np.ndarray,
    template: np.ndarray,
    frame: TemplateFrame,
    region_fraction: float,
    corner_floor_px: float,
    center_floor_px: float,
    max_iterations: int = 30,
    min_correlation: float = 0.8,
    words: FitWords = CODE_WORDS,
    in_view: np.ndarray = UNIT_SQUARE,
    not_paper_ab: np.ndarray | None = None,
) -> MarkerFit:
    """Align a known template to the image by a homography (ECC) and give the symbol's corners.

    corners_px: (4, 2) rough image corners of the symbol (symbol coordinates (0, 0), (1, 0),
    (1, 1), (0, 1)). template: (S, S) float32 grey image of the symbol and what surrounds it, placed
    by ``frame``. region_fraction: how far around the symbol, as a fraction of its side, the image
    is cut for the fit (the template's surround and a margin). Floors as fit_marker's. Returns the
    MarkerFit with module_agreement 1 (the caller measures it when it has modules); raises
    MarkerFitError as fit_marker, worded by ``words``. in_view: (N, 2) symbol coordinates that must
    be in the image before and after the fit (the symbol's corners unless given); template pixels
    outside the image take no part in the fit. not_paper_ab: (K, 4) rectangles [a0, b0, a1, b1] in
    symbol coordinates whose image pixels take no part either: what the sheet prints there (a
    neighbouring code inside the quiet zone, the sheet's edge) is not the template's white paper.
    They are placed by the rough corners, then refitted (NOT_PAPER_PASSES) where each fit put them.
    """
    corners_px = np.asarray(corners_px, dtype=np.float64)
    side_px = _side_px(corners_px)
    if not fits_in_image(apply_homography(homography_from_corners(corners_px), in_view), 0.0, gray.shape):
        raise MarkerFitError(words.outside)
    S_ab_to_tpl = frame.ab_to_template()
    roi_origin, roi = _region(gray, corners_px, quiet_fraction=region_fraction)
    shift = np.array([[1.0, 0.0, -roi_origin[0]], [0.0, 1.0, -roi_origin[1]], [0.0, 0.0, 1.0]])
    H_roi_ab = shift @ homography_from_corners(corners_px)
    paper = paper_mask(roi.shape, H_roi_ab, not_paper_ab)
    for _ in range(NOT_PAPER_PASSES):
        try:
            correlation, H_roi_tpl = align(
                template, roi, H_roi_ab @ np.linalg.inv(S_ab_to_tpl), paper, max_iterations
            )
        except cv2.error as exc:
            raise MarkerFitError(f"{words.alignment} did not converge ({opencv_reason(exc)})") from None
        H_roi_ab = H_roi_tpl @ S_ab_to_tpl
        placed = paper_mask(roi.shape, H_roi_ab, not_paper_ab)  # where this pass put the code
        if (placed is None) == (paper is None) and (placed is None or np.array_equal(placed, paper)):
            break
        paper = placed
    H_img_ab = np.linalg.inv(shift) @ H_roi_tpl @ S_ab_to_tpl
    H_img_ab /= H_img_ab[2, 2]
    refined = apply_homography(H_img_ab, UNIT_SQUARE)
    if correlation < min_correlation:
        raise MarkerFitError(f"{words.alignment} correlation {correlation:.3f} < {min_correlation}")
    moved = float(np.abs(refined - corners_px).max())
    if moved > max(3.0, 0.15 * side_px):
        raise MarkerFitError(f"{words.alignment} moved a corner by {moved:.1f} px from {words.rough_source}")
    if not fits_in_image(apply_homography(H_img_ab, in_view), 0.0, gray.shape):
        raise MarkerFitError(words.leaves)
    noise_cov, sigma = _corner_covariance(roi, H_roi_tpl, template, refined - roi_origin, paper)
    J_center = point_jacobian_wrt_corners(refined, np.array([[0.5, 0.5]]))[0]
    return MarkerFit(
        corners_px=refined,
        corners_cov=noise_cov + corner_floor_px**2 * np.eye(8),
        center_px=center_from_corners(refined),
        center_cov=J_center @ noise_cov @ J_center.T + center_floor_px**2 * np.eye(2),
        correlation=float(correlation),
        module_agreement=1.0,
        noise_sigma=sigma,
    )


def grown_corners(corners_px: np.ndarray, quiet_fraction: float) -> np.ndarray:
    """(4, 2) corners of the marker grown about its centre by quiet_fraction of its side on every side."""
    center = corners_px.mean(axis=0)
    return center + (corners_px - center) * (1.0 + 2.0 * quiet_fraction)


def fits_in_image(corners_px: np.ndarray, quiet_fraction: float, shape: tuple[int, ...]) -> bool:
    """Whether the marker, grown by quiet_fraction of its side, lies inside an image of this shape."""
    grown = grown_corners(corners_px, quiet_fraction)
    h, w = shape[:2]
    return bool(np.all(grown >= 0.0) and np.all(grown[:, 0] <= w - 1) and np.all(grown[:, 1] <= h - 1))


def _region(gray: np.ndarray, corners_px: np.ndarray, quiet_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """The float32 crop (clipped to the image) around a marker grown by quiet_fraction of its
    side, and the (2,) int pixel of its top-left."""
    grown = grown_corners(corners_px, quiet_fraction)
    h, w = gray.shape
    lo = np.maximum(np.floor(grown.min(axis=0)).astype(int), 0)
    hi = np.minimum(np.ceil(grown.max(axis=0)).astype(int) + 1, [w, h])
    return lo, gray[lo[1] : hi[1], lo[0] : hi[0]].astype(np.float32)


def image_noise_sigma(gray: np.ndarray, mask: np.ndarray) -> float:
    """Standard deviation (grey levels) of white noise in an image, from its flat parts.

    Immerkaer's estimator: the image convolved with a kernel that cancels constant and
    linear intensity (so smooth shading does not count), averaged in absolute value over
    the pixels of ``mask`` (H, W) bool whose 3x3 neighbourhood is inside the mask.
    """
    kernel = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]], dtype=np.float32)
    response = cv2.filter2D(gray.astype(np.float32), -1, kernel, borderType=cv2.BORDER_REPLICATE)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    if np.count_nonzero(inner) < 50:
        inner = np.ones_like(mask, dtype=bool)
    return float(np.sqrt(np.pi / 2.0) / 6.0 * np.mean(np.abs(response[inner])))


def _corner_covariance(
    roi: np.ndarray,
    H_roi_tpl: np.ndarray,
    template: np.ndarray,
    corners_roi: np.ndarray,
    paper: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Covariance (8, 8) of the fitted corners under white image noise, and that noise's sigma.

    Gauss-Newton: sigma^2 (J^T J)^-1, one row of J per pixel under the marker and its quiet
    zone: the gradient of the fitted model image (the template warped into the image and
    smoothed like the alignment smooths it) times d(pixel position)/d(corners); paper: (H, W) mask of
    the pixels the fit used (None: all). sigma
    (grey levels) comes from the model's flat parts (image_noise_sigma). A Monte-Carlo
    test on rendered markers checks this against the scatter of repeated fits.
    """
    h, w = roi.shape
    model = cv2.warpPerspective(template, H_roi_tpl, (w, h), flags=cv2.INTER_LINEAR)
    covered = cv2.warpPerspective(np.ones_like(template), H_roi_tpl, (w, h), flags=cv2.INTER_NEAREST) > 0.5
    if paper is not None:
        covered &= paper.astype(bool)
    covered = cv2.erode(covered.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    gain = float(np.ptp(roi[covered])) / 255.0 if np.any(covered) else 1.0
    smooth_model = cv2.GaussianBlur(gain * model, (ECC_SMOOTHING, ECC_SMOOTHING), 0)
    grad_v, grad_u = np.gradient(smooth_model)
    grad_norm = np.hypot(grad_u, grad_v)
    flat = cv2.erode(
        (covered & (grad_norm < 1e-3 * gain * 255.0)).astype(np.uint8), np.ones((3, 3), np.uint8)
    )
    sigma = max(image_noise_sigma(roi, flat.astype(bool)), QUANTISATION_SIGMA)
    vs, us = np.nonzero(covered & (grad_norm > 0.0))  # pixels with zero gradient add nothing
    H = homography_from_corners(corners_roi)
    u, v = us.astype(np.float64), vs.astype(np.float64)
    ab = apply_homography(np.linalg.inv(H), np.column_stack([u, v]))
    a, b = ab[:, 0], ab[:, 1]
    gu, gv = (
        grad_u[vs, us] / (H[2, 0] * a + H[2, 1] * b + 1.0),
        grad_v[vs, us] / (H[2, 0] * a + H[2, 1] * b + 1.0),
    )
    # Rows d(model)/dh = g . d(u, v)/dh (see _point_jacobian_wrt_h), then corners = f(h).
    J_h = np.column_stack(
        [gu * a, gu * b, gu, gv * a, gv * b, gv, -(gu * u + gv * v) * a, -(gu * u + gv * v) * b]
    )
    dcorners_dh = _point_jacobian_wrt_h(H, UNIT_SQUARE).reshape(8, 8)
    cov = sigma * sigma * dcorners_dh @ np.linalg.inv(J_h.T @ J_h) @ dcorners_dh.T
    return cov, sigma
