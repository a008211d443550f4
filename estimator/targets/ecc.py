"""OpenCV's ECC alignment of a template to an image region, with the region's pixels that are not
what the template draws left out (qr_fit.fit_template)."""

from __future__ import annotations

import re

import cv2
import numpy as np

# Gaussian kernel size (pixels) both images are smoothed with before alignment.
ECC_SMOOTHING = 3


def align(
    template: np.ndarray,
    roi: np.ndarray,
    H_roi_tpl: np.ndarray,
    paper: np.ndarray | None,
    max_iterations: int,
) -> tuple[float, np.ndarray]:
    """Align the (S, S) float32 template to the float32 region starting from H_roi_tpl (3, 3,
    template pixels -> region pixels); the region's pixels outside ``paper`` ((H, W) uint8, None:
    all) take no part. Returns the correlation and the fitted H_roi_tpl; raises cv2.error."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, max_iterations, 1e-4)
    start = (H_roi_tpl / H_roi_tpl[2, 2]).astype(np.float32)
    correlation, warp = cv2.findTransformECC(
        template, roi, start, cv2.MOTION_HOMOGRAPHY, criteria, paper, ECC_SMOOTHING
    )
    return float(correlation), warp.astype(np.float64) / warp[2, 2]


def opencv_reason(exc: cv2.error) -> str:
    """What an OpenCV error says, without its source path and function ('NaN encountered.')."""
    line = str(exc).strip().splitlines()[-1]
    return re.sub(r"^.*error: \(-?\d+:[^)]*\)\s*|\s*in function .*$", "", line) or line


def paper_mask(
    shape: tuple[int, ...], H_roi_ab: np.ndarray, not_paper_ab: np.ndarray | None
) -> np.ndarray | None:
    """(H, W) uint8 mask of the region's pixels (1) whose symbol coordinates (through H_roi_ab, symbol
    -> region pixels) lie outside every rectangle of not_paper_ab ((K, 4) [a0, b0, a1, b1]); None
    when that is all of them."""
    if not_paper_ab is None or len(not_paper_ab) == 0:
        return None
    vs, us = np.mgrid[0 : shape[0], 0 : shape[1]]
    uv = np.column_stack([us.ravel(), vs.ravel()]).astype(np.float64).reshape(-1, 1, 2)
    ab = cv2.perspectiveTransform(uv, np.linalg.inv(H_roi_ab)).reshape(-1, 2)
    a, b = ab[:, :1], ab[:, 1:]
    r = np.asarray(not_paper_ab, dtype=np.float64)
    inside = (a > r[:, 0]) & (a < r[:, 2]) & (b > r[:, 1]) & (b < r[:, 3])
    paper = ~inside.any(axis=1)
    return None if paper.all() else paper.reshape(shape[:2]).astype(np.uint8)
