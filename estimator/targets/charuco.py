"""The ChArUco board: a chessboard whose white squares hold ArUco markers, as OpenCV draws it.

Board file fields: ``squares_x``, ``squares_y``, ``square_m``, ``marker_m`` (the ArUco marker's
side, black border included), ``dictionary`` (an OpenCV predefined dictionary name, for example
"DICT_5X5_100"), the sheet's ``size_m``. The pattern is OpenCV's (cv2.aruco.CharucoBoard, not
the legacy one): the top-left square black, marker IDs 0, 1, ... in the white squares row-major
from the top-left. Grid, corner IDs (OpenCV's ChArUco corner IDs) and frames as
hec.estimator.targets.checker says.

Detection: OpenCV's CharucoDetector finds the markers and, from them, the corners (partial views
are fine: a corner counts once its neighbouring markers are found); each corner is then refined
and given its covariance by the template fit of its 2 x 2 squares, markers included
(checker.CornerFitter).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from hec.estimator.targets import checker
from hec.estimator.targets.detection import Detections
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.sheet import CellBlock, draw_sheet

# Error per coordinate image noise does not explain at a ChArUco corner, pixels: the RMS on
# noise-free renders of the default trajectory (charuco_10x5: 17 views, 606 corners).
CORNER_FLOOR_PX = 0.020


@functools.lru_cache(maxsize=8)
def _dictionary(name: str) -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def dictionary_size(name: str) -> int | None:
    """How many markers OpenCV's ArUco dictionary ``name`` ("DICT_5X5_100") has; None when OpenCV
    has no dictionary of that name."""
    if not (name.startswith("DICT_") and hasattr(cv2.aruco, name)):
        return None
    return _dictionary(name).bytesList.shape[0]


@dataclass(frozen=True)
class CharucoBoard(checker.GridCorners):
    """A ChArUco board on a sheet (module doc); lengths in metres."""

    name: str
    size_m: tuple[float, float]
    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str

    kind = "charuco"

    @property
    def feature_m(self) -> float:
        """One cell of an ArUco marker."""
        return self.marker_m / (self.opencv_board().getDictionary().markerSize + 2)

    def opencv_board(self) -> cv2.aruco.CharucoBoard:
        """OpenCV's board of this geometry (its frame: module doc of checker)."""
        return _opencv_board(self.squares_x, self.squares_y, self.square_m, self.marker_m, self.dictionary)

    def cell_blocks(self) -> tuple[CellBlock, ...]:
        """What is printed: the black squares and every ArUco marker's cells."""
        width, height = checker.grid_size_m(self.squares_x, self.squares_y, self.square_m)
        board = self.opencv_board()
        dictionary = board.getDictionary()
        cells = dictionary.markerSize + 2
        blocks = [checker.squares_block(self.squares_x, self.squares_y, self.square_m)]
        for marker_id, corners in zip(board.getIds().ravel(), board.getObjPoints(), strict=True):
            left_cv, top_cv = np.asarray(corners)[0, :2]  # OpenCV frame: y down from the grid's top-left
            dark = cv2.aruco.generateImageMarker(dictionary, int(marker_id), cells, borderBits=1) < 128
            blocks.append(
                CellBlock(dark, float(left_cv - width / 2), float(height / 2 - top_cv), self.marker_m / cells)
            )
        return tuple(blocks)

    def image(self, px_per_m: float, supersample: int = 4) -> np.ndarray:
        """The sheet as an (H, W) uint8 image (sheet.draw_sheet); the grid as OpenCV's generateImage
        draws it."""
        return draw_sheet(self.size_m, list(self.cell_blocks()), px_per_m, supersample)


@functools.lru_cache(maxsize=8)
def _opencv_board(
    squares_x: int, squares_y: int, square_m: float, marker_m: float, dictionary: str
) -> cv2.aruco.CharucoBoard:
    return cv2.aruco.CharucoBoard((squares_x, squares_y), square_m, marker_m, _dictionary(dictionary))


class CharucoDetector(checker.GridCornerDetector):
    """Finds a ChArUco board's corners (module doc)."""

    pass_name = "charuco"
    corner_floor = CORNER_FLOOR_PX
    whole_squares = True  # its white squares hold markers (checker's module doc)

    def __init__(self, board: CharucoBoard, settings: DetectorSettings | None = None) -> None:
        super().__init__(board, settings)
        self._detector = cv2.aruco.CharucoDetector(board.opencv_board())

    def find_corners(self, gray: np.ndarray, result: Detections) -> dict[int, np.ndarray] | None:
        corners, ids, _, _ = self._detector.detectBoard(gray)
        if ids is None or len(ids) == 0:
            result.problem = f"no corner of ChArUco board {self.board.name!r} found"
            return None
        return {
            int(i): c.astype(np.float64) for i, c in zip(ids.ravel(), corners.reshape(-1, 2), strict=True)
        }
