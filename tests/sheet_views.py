"""Synthetic views of a board's sheet for detector tests: the sheet drawn by its own definition and
seen through a known homography, so every point's true pixel is known."""

from __future__ import annotations

import cv2
import numpy as np

from hec.estimator.targets.target import Target

PX_PER_M = 2000.0  # the sheet's pixels per metre before the view's homography


def sheet_px(board: Target, points_board: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of board-frame points (N, 3) in board.image(PX_PER_M): the sheet spans the image."""
    w, h = board.size_m
    return np.column_stack(
        [(points_board[:, 0] + w / 2) * PX_PER_M - 0.5, (h / 2 - points_board[:, 1]) * PX_PER_M - 0.5]
    )


def warped_view(board: Target, H: np.ndarray, shape=(480, 640), ss: int = 4) -> np.ndarray:
    """The sheet seen through homography H (sheet pixels -> image pixels), grey uint8: warped at ss
    times the resolution and area-averaged down, so edges are not aliased."""
    sheet = board.image(ss * PX_PER_M)
    up = np.array([[ss, 0.0, (ss - 1) / 2], [0.0, ss, (ss - 1) / 2], [0.0, 0.0, 1.0]])  # pixel centres
    fine = cv2.warpPerspective(
        sheet,
        up @ H @ np.linalg.inv(up),
        (ss * shape[1], ss * shape[0]),
        flags=cv2.INTER_LINEAR,
        borderValue=128,
    )
    return cv2.resize(fine, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def tilted_homography(board: Target, scale: float = 0.75) -> np.ndarray:
    """A perspective view of the whole sheet, centred in a 640x480 image."""
    w, h = (round(s * PX_PER_M) for s in board.size_m)
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = np.float32([[60, 110], [600, 70], [585, 400], [40, 350]])
    centre = dst.mean(axis=0)
    return cv2.getPerspectiveTransform(src, (centre + scale / 0.75 * (dst - centre)).astype(np.float32))


def quarter_turned(H: np.ndarray, quarter_turns: int, side_px: int = 640) -> np.ndarray:
    """H followed by quarter_turns turns of 90 degrees within a side_px square image."""
    turn = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, side_px - 1.0], [0.0, 0.0, 1.0]])
    return np.linalg.matrix_power(turn, quarter_turns) @ H


def apply(H: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, 2) points uv (N, 2) through homography H."""
    return cv2.perspectiveTransform(uv.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)


def noisy_copies(clean: np.ndarray, sigma: float, count: int, rng: np.random.Generator):
    """count uint8 copies of a float image with Gaussian noise of sigma grey levels."""
    for _ in range(count):
        yield np.clip(np.round(clean + sigma * rng.standard_normal(clean.shape)), 0, 255).astype(np.uint8)


def as_camera_sees(view: np.ndarray, blur_px: float = 0.7) -> np.ndarray:
    """Ink at 30 and paper at 200 grey levels (noise clipped at 0 or 255 would be smaller in the flat
    parts, where its sigma is measured, than at the edges) and a lens's blur; float64."""
    return cv2.GaussianBlur(30 + 170 / 255 * view.astype(np.float64), (0, 0), blur_px)
