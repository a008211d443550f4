"""What every target detector returns: the markers (or points) found in an image with IDs,
ordered sub-pixel corners and covariances, and a reason for everything not used.

A target kind is one module beside this one (``qr`` for the board of QR codes) whose
detector takes an image and returns ``Detections``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

# Below this variance of the Laplacian an image without markers is reported as blurred.
BLURRED_SHARPNESS = 20.0


@dataclass(frozen=True)
class MarkerDetection:
    """One board marker found in an image: a QR code or tag (P = 4 corners) or a single
    chessboard corner (P = 1), see hec.estimator.targets.target.

    corners_px: (P, 2) in the marker's order; corners_cov: (2P, 2P) over (u0, v0, ...),
    pixels^2. center_px: (2,) the marker centre (the point itself when P is 1); center_cov:
    (2, 2). quality: how well the image matches the target there (0..1). module_agreement:
    fraction of modules (QR) or bits (tags) that read as the target says, 1 without any.
    noise_sigma: image noise, grey levels. found_by: what found it ("backend@scale" for QR).
    raw_corners_px: (P, 2) the points before refinement. depth_region_px: (k, 2) convex
    polygon whose depth pixels the depth plane is fitted to; None: the corners' own polygon.
    """

    marker_id: int
    corners_px: np.ndarray
    corners_cov: np.ndarray
    center_px: np.ndarray
    center_cov: np.ndarray
    quality: float
    module_agreement: float
    noise_sigma: float
    found_by: str
    raw_corners_px: np.ndarray
    depth_region_px: np.ndarray | None = None


@dataclass(frozen=True)
class Rejection:
    """A candidate not turned into a marker. corners_px: (4, 2) where it was seen or expected."""

    reason: str
    marker_id: int | None = None
    payload: str | None = None
    corners_px: np.ndarray | None = None


@dataclass
class Detections:
    """The detector's answer for one image. problem: why the whole image is unusable, else None.
    notes: remarks about what the detector assumed (each said once per detector)."""

    markers: list[MarkerDetection] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)
    problem: str | None = None
    notes: list[str] = field(default_factory=list)
    passes_run: list[str] = field(default_factory=list)
    sharpness: float = 0.0


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey from an (H, W) or (H, W, 3) RGB uint8 image; ValueError otherwise."""
    image = np.asarray(image)
    if image.size == 0:
        raise ValueError(f"image is empty (shape {image.shape})")
    if image.dtype != np.uint8:
        raise ValueError(f"expected an 8-bit image, got dtype {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    raise ValueError(f"expected an (H, W) grey or (H, W, 3) RGB image, got shape {image.shape}")


def start_detection(image: np.ndarray) -> tuple[np.ndarray | None, Detections]:
    """The (H, W) uint8 grey of an image a detector was given and its Detections begun with the
    image's sharpness; the grey is None, and the Detections say why, when the image cannot hold a
    readable marker (to_gray's errors, image_problem)."""
    try:
        gray = to_gray(image)
    except ValueError as exc:
        return None, Detections(problem=str(exc))
    problem = image_problem(gray)
    if problem is not None:
        return None, Detections(problem=problem)
    return gray, Detections(sharpness=float(cv2.Laplacian(gray, cv2.CV_32F).var()))


def image_problem(gray: np.ndarray) -> str | None:
    """Why an image cannot hold a readable marker (empty, black, saturated, flat), or None."""
    if gray.size == 0 or min(gray.shape) < 21:
        return f"image is empty or tiny ({gray.shape[1] if gray.ndim == 2 else 0}x{gray.shape[0]} pixels)"
    if int(gray.max()) <= 10:
        return f"image is black (brightest pixel {int(gray.max())})"
    saturated = float(np.mean(gray >= 254))
    if saturated > 0.5:
        return f"image is saturated ({saturated:.0%} of pixels at full scale)"
    spread = float(gray.std())
    if spread < 2.0:
        return f"image has no contrast (standard deviation {spread:.1f} grey levels)"
    return None
