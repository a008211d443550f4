"""The AprilGrid: a grid of AprilTag 36h11 tags as Kalibr lays them out, and its detector.

Geometry (Kalibr's target yaml, in metres): ``tag_cols`` x ``tag_rows`` tags of side
``tag_size_m`` (edge to edge of the black border), ``tag_spacing`` times the side apart, each
tag drawn with ``border_bits`` black cells around its 6 x 6 code (Kalibr prints 2), centred on
the sheet. Tag IDs run as Kalibr's: ``first_id`` at the bottom-left, along x then up the rows.
Kalibr also prints black squares, ``tag_spacing`` times the side, touching each tag's four corners
from outside (``corner_squares``: true for a Kalibr print; hec's own sheet leaves them out). The
corner fit's template then has them too: fitted with a plain template, the squares pull the
corners 0.74-1.0 px off (fronto-parallel sheets at 1500-4000 px/m).

Corner order of every tag: bottom-left, bottom-right, top-right, top-left of the upright tag
(counter-clockwise from the corner nearest Kalibr's origin), in hec's board frame (origin at the
sheet centre, x right, y up, z out of the face).
Kalibr's target frame has its origin at the bottom-left corner of tag ``first_id`` with the same
axes, so p_kalibr = p_hec + (W / 2, H / 2, 0) with W, H the grid's outer width and height.

Detection: OpenCV's ArucoDetector with the AprilTag 36h11 dictionary finds each tag and its ID;
its corners are then refined by aligning the tag's known cells to the image (qr_fit.fit_marker,
the QR codes' homography fit), which also gives their covariance.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from hec.estimator.targets.detection import Detections, MarkerDetection, Rejection, start_detection
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.qr_fit import TEMPLATE_QUIET_MODULES, MarkerFitError, fit_marker
from hec.estimator.targets.sheet import CellBlock, draw_sheet

DICTIONARY = "DICT_APRILTAG_36h11"
CODE_BITS = 6  # a 36h11 tag's code is 6 x 6 cells inside its black border
# The corner fit's template follows the image's pixels per tag cell up to this (qr_fit.fit_marker):
# at 3, 50 mm tags came out 0.04 px small (corner RMS 0.059 px); at 6-12 unbiased (0.014-0.018).
MAX_TEMPLATE_PX_PER_CELL = 8
# Error per coordinate image noise does not explain, pixels, at a tag corner and centre: the RMS on
# noise-free renders of the default trajectory (aprilgrid_6x3: 17 views, 306 tags; the QR codes'
# are 0.013 and 0.0036). The detector uses these or the settings' floors, whichever is larger.
TAG_CORNER_FLOOR_PX = 0.027
TAG_CENTER_FLOOR_PX = 0.0058
# The same with Kalibr's corner squares (aprilgrid_6x3_kalibr, noise-free renders of seeds 0 and 1:
# the corners' RMS per coordinate is lower, 0.023 px; the centre's floor is the one that brings its
# normalised error to 1, 0.0093 px, against 2.6 with the plain grid's).
SQUARES_CORNER_FLOOR_PX = 0.023
SQUARES_CENTER_FLOOR_PX = 0.0093
# ArucoDetector's corners (top-left, top-right, bottom-right, bottom-left of the tag image) in
# the board's order (bottom-left, bottom-right, top-right, top-left).
_BOARD_FROM_ARUCO = np.array([3, 2, 1, 0])
# Tag corner offsets in the board's order, in units of the tag side (board frame, y up).
_CORNER_OFFSETS = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])


@functools.lru_cache(maxsize=1)
def _dictionary() -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY))


def tag_family_size() -> int:
    """How many tags tag36h11 has (IDs 0 to this less one)."""
    return _dictionary().bytesList.shape[0]


@functools.lru_cache(maxsize=4096)
def tag_cells(tag_id: int, border_bits: int) -> np.ndarray:
    """(n, n) bool, True where tag ``tag_id`` is black, row 0 at the top of the upright tag;
    n = 6 + 2 border_bits. Read-only."""
    n = CODE_BITS + 2 * border_bits
    cells = cv2.aruco.generateImageMarker(_dictionary(), tag_id, n, borderBits=border_bits) < 128
    cells.setflags(write=False)
    return cells


@dataclass(frozen=True)
class AprilGridBoard:
    """A Kalibr AprilGrid on a sheet (module doc); lengths in metres."""

    name: str
    size_m: tuple[float, float]
    tag_cols: int
    tag_rows: int
    tag_size_m: float
    tag_spacing: float
    border_bits: int = 2
    first_id: int = 0
    corner_squares: bool = False

    kind = "aprilgrid"
    points_per_marker = 4
    markers_placed_one_by_one = False
    corners_homography_fitted = True

    @property
    def marker_ids(self) -> list[int]:
        return list(range(self.first_id, self.first_id + self.tag_cols * self.tag_rows))

    @property
    def feature_m(self) -> float:
        """One cell of a tag."""
        return self.tag_size_m / (CODE_BITS + 2 * self.border_bits)

    @property
    def visible_margin_m(self) -> float:
        """The paper around a tag the corner fit compares (qr_fit's template quiet zone) and, with
        corner_squares, the squares."""
        quiet = TEMPLATE_QUIET_MODULES * self.feature_m
        return max(quiet, self.gap_m) if self.corner_squares else quiet

    @property
    def gap_m(self) -> float:
        """The paper between two tags, and the side of a corner square."""
        return self.tag_spacing * self.tag_size_m

    @property
    def grid_size_m(self) -> tuple[float, float]:
        """(W, H): the grid's outer width and height, from the first tag's left edge to the last's right."""
        pitch = self.tag_size_m * (1.0 + self.tag_spacing)
        return (
            (self.tag_cols - 1) * pitch + self.tag_size_m,
            (self.tag_rows - 1) * pitch + self.tag_size_m,
        )

    def marker_center(self, marker_id: int) -> np.ndarray:
        """(3,) the tag's centre in the board frame."""
        k = marker_id - self.first_id
        if not 0 <= k < self.tag_cols * self.tag_rows:
            raise KeyError(f"tag {marker_id} is not on board {self.name!r}")
        row, col = divmod(k, self.tag_cols)
        pitch = self.tag_size_m * (1.0 + self.tag_spacing)
        width, height = self.grid_size_m
        return np.array(
            [
                -width / 2 + self.tag_size_m / 2 + col * pitch,
                -height / 2 + self.tag_size_m / 2 + row * pitch,
                0.0,
            ]
        )

    def marker_corners(self, marker_id: int) -> np.ndarray:
        """(4, 3) the tag's corners in the board frame, in the module doc's order."""
        center = self.marker_center(marker_id)
        xy = center[:2] + _CORNER_OFFSETS * self.tag_size_m
        return np.column_stack([xy, np.zeros(4)])

    def all_corners(self) -> np.ndarray:
        """(M, 4, 3) every tag's corners, ordered by marker_ids."""
        return np.stack([self.marker_corners(i) for i in self.marker_ids])

    def pinned(self) -> AprilGridBoard:
        return self

    def image(self, px_per_m: float, supersample: int = 4) -> np.ndarray:
        """The sheet as an (H, W) uint8 image (sheet.draw_sheet)."""
        blocks = []
        square = np.ones((1, 1), dtype=bool)
        for marker_id in self.marker_ids:
            cells = tag_cells(marker_id, self.border_bits)
            left, top = self.marker_corners(marker_id)[3, :2]
            blocks.append(CellBlock(cells, float(left), float(top), self.feature_m))
            if self.corner_squares:  # outside each corner: left of it or right, above or below
                for corner in self.marker_corners(marker_id)[:, :2]:
                    offset = (corner - self.marker_center(marker_id)[:2] > 0) * self.gap_m
                    x, y = corner[0] - self.gap_m + offset[0], corner[1] + offset[1]
                    blocks.append(CellBlock(square, float(x), float(y), self.gap_m))
        return draw_sheet(self.size_m, blocks, px_per_m, supersample)


class AprilGridDetector:
    """Finds an AprilGrid's tags in images: OpenCV's ArucoDetector for the IDs and rough corners,
    then the tag's cells aligned to the image for sub-pixel corners and their covariance."""

    def __init__(self, board: AprilGridBoard, settings: DetectorSettings | None = None) -> None:
        self.board = board
        self.settings = settings or DetectorSettings()
        parameters = cv2.aruco.DetectorParameters()
        parameters.markerBorderBits = board.border_bits
        self._aruco = cv2.aruco.ArucoDetector(_dictionary(), parameters)
        self._ids = set(board.marker_ids)
        squares = board.corner_squares
        corner, center = (
            (SQUARES_CORNER_FLOOR_PX, SQUARES_CENTER_FLOOR_PX)
            if squares
            else (TAG_CORNER_FLOOR_PX, TAG_CENTER_FLOOR_PX)
        )
        self.corner_floor_px = max(self.settings.corner_floor_px, corner)
        self.center_floor_px = max(self.settings.center_floor_px, center)

    def detect(self, image: np.ndarray) -> Detections:
        """The board's tags in an (H, W, 3) RGB or (H, W) grey uint8 image."""
        gray, result = start_detection(image)
        if gray is None:
            return result
        result.passes_run.append("aruco")
        corners, ids, _ = self._aruco.detectMarkers(gray)
        found = (
            []
            if ids is None
            else [
                (int(i), c.reshape(4, 2).astype(np.float64))
                for i, c in zip(ids.ravel(), corners, strict=True)
            ]
        )
        counts: dict[int, int] = {}
        for tag_id, _ in found:
            counts[tag_id] = counts.get(tag_id, 0) + 1
        for tag_id, corners_tl in found:
            if tag_id not in self._ids:
                result.rejected.append(
                    Rejection(f"tag {tag_id} is not on board {self.board.name!r}", tag_id, None, corners_tl)
                )
            elif counts[tag_id] > 1:
                result.rejected.append(
                    Rejection(
                        f"tag {tag_id} appears {counts[tag_id]} times: ambiguous, all dropped",
                        tag_id,
                        None,
                        corners_tl,
                    )
                )
            else:
                self._refine(gray, tag_id, corners_tl, result)
        result.markers.sort(key=lambda m: m.marker_id)
        return result

    def _refine(self, gray: np.ndarray, tag_id: int, corners_tl: np.ndarray, result: Detections) -> None:
        """Fit the tag's cells to the image (corners_tl: ArucoDetector's order) and add the marker
        in the board's corner order, or a rejection saying why the fit failed."""
        s = self.settings
        try:
            fit = fit_marker(
                gray,
                corners_tl,
                tag_cells(tag_id, self.board.border_bits),
                corner_floor_px=self.corner_floor_px,
                center_floor_px=self.center_floor_px,
                min_correlation=s.min_correlation,
                max_template_px_per_module=MAX_TEMPLATE_PX_PER_CELL,
                dark_corners=self.board.corner_squares,
            )
        except MarkerFitError as exc:
            result.rejected.append(Rejection(f"tag {tag_id}: {exc}", tag_id, None, corners_tl))
            return
        if fit.module_agreement < s.min_module_agreement:
            result.rejected.append(
                Rejection(
                    f"tag {tag_id}: only {fit.module_agreement:.0%} of its cells match the tag",
                    tag_id,
                    None,
                    fit.corners_px,
                )
            )
            return
        order = _BOARD_FROM_ARUCO
        coordinates = np.stack([2 * order, 2 * order + 1], axis=1).ravel()
        result.markers.append(
            MarkerDetection(
                marker_id=tag_id,
                corners_px=fit.corners_px[order],
                corners_cov=fit.corners_cov[np.ix_(coordinates, coordinates)],
                center_px=fit.center_px,
                center_cov=fit.center_cov,
                quality=fit.correlation,
                module_agreement=fit.module_agreement,
                noise_sigma=fit.noise_sigma,
                found_by="aruco",
                raw_corners_px=corners_tl[order],
            )
        )
