"""What chessboards and ChArUco boards share: the grid of squares, its inner corners, and each
corner's sub-pixel fit with its covariance.

Grid: ``squares_x`` x ``squares_y`` squares of side ``square_m``, centred on the sheet, the
top-left square black (as OpenCV's ChArUco boards). Inner corner IDs run as OpenCV's ChArUco
corner IDs: row-major from the top-left, ID = r (squares_x - 1) + c, c counted to the right and r
downwards. Each corner is a one-point marker; in hec's board frame (origin at the sheet centre,
x right, y up) corner (r, c) sits at x = -W/2 + (c + 1) square_m, y = H/2 - (r + 1) square_m, W
and H the grid's width and height. OpenCV's board frame starts at the grid's top-left corner with
y down and z into the board: p_opencv = (x + W/2, H/2 - y, -z).

Sub-pixel corners: the 2 x 2 squares around a corner, with one square of the board around them,
are drawn from the board's own definition as a template and aligned to the image by a homography
(qr_fit.fit_template, the QR codes' ECC fit); the corner is the block's centre, its covariance
the fit's centre covariance plus a floor measured on noise-free renders.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from hec.estimator.targets.detection import Detections, MarkerDetection, Rejection, start_detection
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.qr_fit import MarkerFitError, TemplateFrame, fit_template
from hec.estimator.targets.sheet import CellBlock, draw_sheet
from hec.estimator.targets.target import BoardDefinitionError, integer_field, positive_field, sheet_fields

# Template pixels per square: the image's, clipped to this range (a template much coarser than the
# image biases the fit, see qr_fit.fit_marker).
MIN_TEMPLATE_PX_PER_SQUARE = 6
MAX_TEMPLATE_PX_PER_SQUARE = 24
# The image cut for a corner's fit reaches this far around its 2 x 2 block, in block sides (the
# template's one-square surround is 0.5).
REGION_FRACTION = 0.6


class GridCorners:
    """The inner corners of a squares_x x squares_y grid of square_m squares as one-point markers
    (module doc): what a chessboard and a ChArUco board share. Their frozen dataclasses hold the
    three fields."""

    squares_x: int
    squares_y: int
    square_m: float

    points_per_marker = 1
    markers_placed_one_by_one = False
    corners_homography_fitted = False

    @property
    def marker_ids(self) -> list[int]:
        return corner_ids(self.squares_x, self.squares_y)

    @property
    def visible_margin_m(self) -> float:
        """The corner's 2 x 2 squares (its fit's block)."""
        return self.square_m

    def marker_corners(self, marker_id: int) -> np.ndarray:
        """(1, 3) the corner in the board frame."""
        return self.marker_center(marker_id)[None, :]

    def marker_center(self, marker_id: int) -> np.ndarray:
        x, y = corner_xy(self.squares_x, self.squares_y, self.square_m, marker_id)
        return np.array([x, y, 0.0])

    def all_corners(self) -> np.ndarray:
        """(M, 1, 3) every corner, ordered by ID."""
        return np.stack([self.marker_corners(i) for i in self.marker_ids])

    def pinned(self) -> GridCorners:
        """Nothing left to choose: the board itself."""
        return self


def grid_size_m(squares_x: int, squares_y: int, square_m: float) -> tuple[float, float]:
    return squares_x * square_m, squares_y * square_m


def corner_ids(squares_x: int, squares_y: int) -> list[int]:
    return list(range((squares_x - 1) * (squares_y - 1)))


def corner_xy(squares_x: int, squares_y: int, square_m: float, corner_id: int) -> np.ndarray:
    """(2,) board-frame x, y of an inner corner (module doc); KeyError for an unknown ID."""
    if not 0 <= corner_id < (squares_x - 1) * (squares_y - 1):
        raise KeyError(f"corner {corner_id} is not on a {squares_x}x{squares_y}-square grid")
    r, c = divmod(corner_id, squares_x - 1)
    width, height = grid_size_m(squares_x, squares_y, square_m)
    return np.array([-width / 2 + (c + 1) * square_m, height / 2 - (r + 1) * square_m])


def squares_block(squares_x: int, squares_y: int, square_m: float) -> CellBlock:
    """The black squares as one block of cells (top-left black)."""
    rows, cols = np.indices((squares_y, squares_x))
    width, height = grid_size_m(squares_x, squares_y, square_m)
    return CellBlock((rows + cols) % 2 == 0, -width / 2, height / 2, square_m)


def check_grid(d: dict, source: str) -> tuple[str, tuple[float, float], int, int, float]:
    """name, size_m, squares_x, squares_y, square_m of a board file, validated (errors name source
    and the field); the grid must fit on the sheet with a square of white around it (the corner
    fit's surround)."""
    name, size = sheet_fields(d, source)
    squares_x = integer_field(d, "squares_x", source, least=2)
    squares_y = integer_field(d, "squares_y", source, least=2)
    square_m = positive_field(d, "square_m", source)
    width, height = grid_size_m(squares_x, squares_y, square_m)
    if width + 2 * square_m > size[0] + 1e-12 or height + 2 * square_m > size[1] + 1e-12:
        raise BoardDefinitionError(
            f"{source}: the {squares_x}x{squares_y} grid of {square_m * 1e3:g} mm squares with a square of "
            f"white around it ({(width + 2 * square_m) * 1e3:.0f} x {(height + 2 * square_m) * 1e3:.0f} mm) "
            f"does not fit on the sheet 'size_m' {list(size)}"
        )
    return name, size, squares_x, squares_y, square_m


class CornerFitter:
    """Sub-pixel corners of a grid board (module doc): board, a GridCorners with cell_blocks(),
    what it prints; floor_px: error per coordinate image noise does not explain."""

    def __init__(self, board: GridCorners, floor_px: float, min_correlation: float) -> None:
        self._blocks = board.cell_blocks()
        self._square_m = board.square_m
        self._xy = lambda corner_id: board.marker_center(corner_id)[:2]
        self._floor_px = floor_px
        self._min_correlation = min_correlation
        self._template = functools.lru_cache(maxsize=1024)(self._draw_template)

    def _draw_template(self, corner_id: int, px_per_square: int) -> np.ndarray:
        """(4p, 4p) float32: the 4 x 4 squares centred on the corner, p pixels per square."""
        x, y = self._xy(corner_id)
        side = 4 * self._square_m
        patch = draw_sheet((side, side), list(self._blocks), px_per_square / self._square_m, 4, (x, y))
        return patch.astype(np.float32)

    def fit(
        self, gray: np.ndarray, found: dict[int, np.ndarray], found_by: str
    ) -> tuple[list[MarkerDetection], list[Rejection]]:
        """Refine every corner of ``found`` (ID -> (2,) rough pixel): a local homography through its
        found neighbours gives the rough image of its 2 x 2 block, then the template fit."""
        ids = np.array(sorted(found))
        board_xy = np.array([self._xy(i) for i in ids])
        image_uv = np.array([found[i] for i in ids])
        markers, rejected = [], []
        sq = self._square_m
        # The block's corners in symbol order: top-left, top-right, bottom-right, bottom-left.
        block = np.array([[-sq, sq], [sq, sq], [sq, -sq], [-sq, -sq]])
        for corner_id, xy, uv in zip(ids, board_xy, image_uv, strict=True):
            near = np.max(np.abs(board_xy - xy), axis=1) <= 1.5 * sq
            if np.count_nonzero(near) < 4:
                rejected.append(
                    Rejection(f"corner {corner_id}: fewer than 4 neighbours found", int(corner_id))
                )
                continue
            H, _ = cv2.findHomography(board_xy[near], image_uv[near])
            if H is None:
                rejected.append(
                    Rejection(f"corner {corner_id}: its neighbours are degenerate", int(corner_id))
                )
                continue
            rough = cv2.perspectiveTransform((xy + block).reshape(-1, 1, 2), H).reshape(4, 2)
            side_px = float(np.linalg.norm(rough - np.roll(rough, 1, axis=0), axis=1).mean())
            p = int(np.clip(round(side_px / 2), MIN_TEMPLATE_PX_PER_SQUARE, MAX_TEMPLATE_PX_PER_SQUARE))
            try:
                fit = fit_template(
                    gray,
                    rough,
                    self._template(int(corner_id), p),
                    TemplateFrame(2 * p, p),
                    REGION_FRACTION,
                    corner_floor_px=0.0,
                    center_floor_px=self._floor_px,
                    min_correlation=self._min_correlation,
                )
            except MarkerFitError as exc:
                rejected.append(Rejection(f"corner {corner_id}: {exc}", int(corner_id), None, rough))
                continue
            markers.append(
                MarkerDetection(
                    marker_id=int(corner_id),
                    corners_px=fit.center_px[None, :],
                    corners_cov=fit.center_cov,
                    center_px=fit.center_px,
                    center_cov=fit.center_cov,
                    quality=fit.correlation,
                    module_agreement=1.0,
                    noise_sigma=fit.noise_sigma,
                    found_by=found_by,
                    raw_corners_px=np.asarray(uv, dtype=np.float64)[None, :],
                    depth_region_px=fit.corners_px,
                )
            )
        return markers, rejected


class GridCornerDetector:
    """What the chessboard's and the ChArUco board's detectors share: the grid's corners found by
    OpenCV (find_corners, per kind, named pass_name in the detections), each refined by the
    CornerFitter, with corner_floor_px (a corner is its own centre: one floor for both)."""

    pass_name: str
    corner_floor: float

    def __init__(self, board: GridCorners, settings: DetectorSettings | None = None) -> None:
        self.board = board
        self.settings = settings or DetectorSettings()
        self.corner_floor_px = self.center_floor_px = max(self.settings.center_floor_px, self.corner_floor)
        self._fitter = CornerFitter(board, self.corner_floor_px, self.settings.min_correlation)

    def find_corners(self, gray: np.ndarray, result: Detections) -> dict[int, np.ndarray] | None:
        """OpenCV's corners, corner ID -> (2,) pixels; None with result.problem set when none."""
        raise NotImplementedError

    def detect(self, image: np.ndarray) -> Detections:
        """The board's corners in an (H, W, 3) RGB or (H, W) grey uint8 image."""
        gray, result = start_detection(image)
        if gray is None:
            return result
        result.passes_run.append(self.pass_name)
        found = self.find_corners(gray, result)
        if found is None:
            return result
        result.markers, result.rejected = self._fitter.fit(gray, found, self.pass_name)
        result.markers.sort(key=lambda m: m.marker_id)
        return result
