"""The chessboard: a grid of black and white squares whose inner corners are one-point markers.

Board file fields: ``squares_x``, ``squares_y`` (squares, not inner corners: OpenCV's pattern
size is one less each) or ``inner_corners`` [x, y] (OpenCV's pattern size, as calibration tools
state it: one less than the squares each), ``square_m``, and the sheet's ``size_m`` (optional: the
grid's own size, squares reaching the sheet's edge) and ``name`` (optional: chessboard_<X>x<Y>,
squares); grid, corner IDs and frames as hec.estimator.targets.checker says. One of squares_x,
squares_y must be odd and the other even: only then does a half-turn change the squares' colours,
so the board's orientation can be read off the image (an odd-by-odd or even-by-even board looks the
same turned, and its IDs would be a guess).

Detection: OpenCV's findChessboardCornersSB finds the whole grid (a chessboard needs every corner
in view; a partial view gives the frame a problem saying so, never IDs); where it finds none, the
classic findChessboardCorners (adaptive threshold, normalised image) and cornerSubPix try, so a
frame either finder finds is found (pass "classic" in the detections). OpenCV lists the corners
from any of the grid's four corners; the listing is mapped to the board's IDs by the handedness of
the grid in the image (the printed face is seen from the front) and by which squares are dark.
Each corner is then refined and given its covariance (checker.CornerFitter).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hec.estimator.targets import checker
from hec.estimator.targets.detection import Detections
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.sheet import CellBlock, draw_sheet

# Error per coordinate image noise does not explain at a chessboard corner, pixels: the RMS on
# noise-free renders of the default trajectory, its blur kept (noise.rgb.sigma = 0; chessboard_10x5:
# 17 views, 612 corners, 0.0113 px; 0.0275 with a template of the 4 x 4 whole squares and the sheet
# around the grid; without the blur 0.0135).
CORNER_FLOOR_PX = 0.011


# The classic finder, tried when findChessboardCornersSB finds nothing, and its pass name.
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
CLASSIC_PASS = "classic"
# cornerSubPix's half window, pixels: a quarter of the closest corners' spacing, within these bounds.
SUB_PIXEL_HALF_WINDOW_PX = (2, 11)


@dataclass(frozen=True)
class ChessboardBoard(checker.GridCorners):
    """A chessboard on a sheet (module doc); lengths in metres."""

    name: str
    size_m: tuple[float, float]
    squares_x: int
    squares_y: int
    square_m: float

    kind = "chessboard"

    @property
    def feature_m(self) -> float:
        return self.square_m

    def image(self, px_per_m: float, supersample: int = 4) -> np.ndarray:
        """The sheet as an (H, W) uint8 image (sheet.draw_sheet)."""
        return draw_sheet(self.size_m, list(self.cell_blocks()), px_per_m, supersample)

    def cell_blocks(self) -> tuple[CellBlock, ...]:
        """What is printed: the black squares."""
        return (checker.squares_block(self.squares_x, self.squares_y, self.square_m),)


class ChessboardDetector(checker.GridCornerDetector):
    """Finds a chessboard's inner corners (module doc)."""

    pass_name = "sb"
    corner_floor = CORNER_FLOOR_PX

    def __init__(self, board: ChessboardBoard, settings: DetectorSettings | None = None) -> None:
        super().__init__(board, settings)
        self._pattern = (board.squares_x - 1, board.squares_y - 1)

    def find_corners(self, gray: np.ndarray, result: Detections) -> dict[int, np.ndarray] | None:
        found, grid = cv2.findChessboardCornersSB(gray, self._pattern, flags=cv2.CALIB_CB_EXHAUSTIVE)
        if not found:
            result.passes_run.append(CLASSIC_PASS)
            found, grid = cv2.findChessboardCorners(gray, self._pattern, flags=CLASSIC_FLAGS)
        if not found:
            result.problem = (
                f"the chessboard's {self._pattern[0]}x{self._pattern[1]} inner corners were not all found "
                "by either of OpenCV's finders (a chessboard needs its whole grid in view, sharp and lit)"
            )
            return None
        if result.passes_run[-1] == CLASSIC_PASS:
            grid = _sub_pixel(gray, grid, self._pattern)
        ids = self._corner_ids(gray, grid.reshape(self._pattern[1], self._pattern[0], 2))
        return dict(zip(ids.ravel(), grid.reshape(-1, 2).astype(np.float64), strict=True))

    def _corner_ids(self, gray: np.ndarray, grid: np.ndarray) -> np.ndarray:
        """(rows, cols) board IDs of OpenCV's (rows, cols, 2) grid: of the four ways to read it, the
        one seen from the front (board x right, y up appear as a right-handed turn away from the
        image's u right, v down) whose dark squares are dark."""
        rows, cols = grid.shape[:2]
        # Mean grey of each inner square (between four corners), and whether the board says dark.
        centres = 0.25 * (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:])
        map_u, map_v = (centres[..., k].astype(np.float32) for k in (0, 1))
        grey = cv2.remap(gray.astype(np.float32), map_u, map_v, cv2.INTER_LINEAR)
        best, best_contrast = None, -np.inf
        for flip_rows in (False, True):
            for flip_cols in (False, True):
                r = np.arange(rows)[::-1] if flip_rows else np.arange(rows)
                c = np.arange(cols)[::-1] if flip_cols else np.arange(cols)
                ids = r[:, None] * cols + c[None, :]
                # Board x along increasing c, board y along decreasing r, in the image.
                x_img = (grid[:, 1:] - grid[:, :-1]).mean(axis=(0, 1)) * (-1 if flip_cols else 1)
                y_img = -(grid[1:] - grid[:-1]).mean(axis=(0, 1)) * (-1 if flip_rows else 1)
                if x_img[0] * y_img[1] - x_img[1] * y_img[0] >= 0:
                    continue  # the back of the sheet: not a view of the printed face
                # The square right of and below corner (r, c) is square (r + 1, c + 1): dark when even.
                square_r = np.minimum(r[:-1], r[1:]) + 1
                square_c = np.minimum(c[:-1], c[1:]) + 1
                dark = (square_r[:, None] + square_c[None, :]) % 2 == 0
                contrast = float(grey[~dark].mean() - grey[dark].mean())
                if contrast > best_contrast:
                    best, best_contrast = ids, contrast
        return best


def _sub_pixel(gray: np.ndarray, grid: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """The classic finder's (N, 1, 2) corners refined by cornerSubPix (its corners are only pixel-near),
    with a window a quarter of the closest corners' spacing (the template fit then refines them)."""
    rows = grid.reshape(pattern[1], pattern[0], 2)
    spacing = min(
        float(np.linalg.norm(np.diff(rows, axis=1), axis=2).min()),
        float(np.linalg.norm(np.diff(rows, axis=0), axis=2).min()),
    )
    half = int(np.clip(spacing / 4, *SUB_PIXEL_HALF_WINDOW_PX))
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    return cv2.cornerSubPix(gray, grid.astype(np.float32), (half, half), (-1, -1), criteria)
