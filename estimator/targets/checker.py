"""What chessboards and ChArUco boards share: the grid of squares, its inner corners, and each
corner's sub-pixel fit with its covariance.

Grid: ``squares_x`` x ``squares_y`` squares of side ``square_m``, centred on the sheet, the
top-left square black (as OpenCV's ChArUco boards). Inner corner IDs run as OpenCV's ChArUco
corner IDs: row-major from the top-left, ID = r (squares_x - 1) + c, c counted to the right and r
downwards. Each corner is a one-point marker; in hec's board frame (origin at the sheet centre,
x right, y up) corner (r, c) sits at x = -W/2 + (c + 1) square_m, y = H/2 - (r + 1) square_m, W
and H the grid's width and height. OpenCV's board frame starts at the grid's top-left corner with
y down and z into the board: p_opencv = (x + W/2, H/2 - y, -z).

Sub-pixel corners: the 2 x 2 squares around a corner and half of each square around them are drawn
from the board's own definition as a template and aligned to the image by a homography
(qr_fit.fit_template, the QR codes' ECC fit); the corner is the block's centre, its covariance
the fit's centre covariance plus a floor measured on noise-free renders. The template holds only
the grid: where the grid ends sooner it stops in the middle of the outer squares, so whatever lies
beyond (a white margin, a sheet cut at the grid, the plate or table behind) is never compared. Its
edges all fall in the middle of squares, where the image is flat: an edge there would be blurred
into the image's side of the cut and not the template's, which shifts a corner whose template is
cut unevenly (0.08 px at the grid's edge on sharp views). The half squares around the block are
needed: the 2 x 2 squares alone are two lines crossing, which fix the corner but leave a
homography's scale along them free. A ChArUco board's white squares hold markers, whose bits a cut
in the middle of a square would cross, so its template keeps the 4 x 4 squares around the corner
whole, the sheet beyond the grid drawn as the board file says (whole_squares).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from hec.estimator.targets.detection import Detections, MarkerDetection, Rejection, start_detection
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.qr_fit import UNIT_SQUARE, FitWords, MarkerFitError, TemplateFrame, fit_template
from hec.estimator.targets.sheet import CellBlock, draw_sheet

# Template pixels per square: the image's, clipped to this range (a template much coarser than the
# image biases the fit, see qr_fit.fit_marker).
MIN_TEMPLATE_PX_PER_SQUARE = 6
MAX_TEMPLATE_PX_PER_SQUARE = 24
# The image cut for a corner's fit reaches this far around its 2 x 2 block, in block sides (the
# template's one-square surround is 0.5).
REGION_FRACTION = 0.6
# How far the template reaches from the corner, in squares (module doc).
TEMPLATE_REACH_SQUARES = 1.5
# A template cut in the middle of squares needs this much of the squares around the corner in the
# image, in squares either side (the rest of it may leave the image: those pixels take no part); a
# whole-squares template needs its 2 x 2 block in the image.
IN_VIEW_SQUARES = 0.5
# In symbol coordinates (the 2 x 2 block is the unit square).
_IN_VIEW = 0.5 + IN_VIEW_SQUARES / 2 * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
# How the fit's errors say what went wrong, for the cut and the whole-squares template.
CORNER_WORDS = FitWords(
    alignment="squares fit",
    outside=f"the corner's squares are not in the image {IN_VIEW_SQUARES:g} square either side of it",
    leaves=f"the fitted corner is not {IN_VIEW_SQUARES:g} square inside the image",
    rough_source="OpenCV's",
)
WHOLE_SQUARES_WORDS = FitWords(
    alignment="squares fit",
    outside="the corner's 2 x 2 squares are partly outside the image",
    leaves="the fitted corner's 2 x 2 squares leave the image",
    rough_source="OpenCV's",
)


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


class CornerFitter:
    """Sub-pixel corners of a grid board (module doc): board, a GridCorners with cell_blocks(),
    what it prints; floor_px: error per coordinate image noise does not explain; whole_squares: the
    template is the 4 x 4 squares around the corner, sheet included (ChArUco), not cut in the middle
    of squares and at the grid."""

    def __init__(
        self, board: GridCorners, floor_px: float, min_correlation: float, whole_squares: bool = False
    ) -> None:
        self._whole_squares = whole_squares
        self._blocks = board.cell_blocks()
        self._square_m = board.square_m
        self._squares = (board.squares_x, board.squares_y)
        self._xy = lambda corner_id: board.marker_center(corner_id)[:2]
        self._floor_px = floor_px
        self._min_correlation = min_correlation
        self._template = functools.lru_cache(maxsize=1024)(self._draw_template)

    def _draw_template(self, corner_id: int, p: int) -> tuple[np.ndarray, TemplateFrame]:
        """The template of a corner at p pixels per square, float32 (module doc), and where its 2 x 2
        block lies in it."""
        r, c = divmod(corner_id, self._squares[0] - 1)
        # The template's extent from the corner in squares, u right and v down (module doc).
        u0, v0, u1, v1 = (-2, -2, 2, 2)
        if not self._whole_squares:
            u0, u1 = (
                max(-TEMPLATE_REACH_SQUARES, 0.5 - (c + 1)),
                min(TEMPLATE_REACH_SQUARES, self._squares[0] - c - 1.5),
            )
            v0, v1 = (
                max(-TEMPLATE_REACH_SQUARES, 0.5 - (r + 1)),
                min(TEMPLATE_REACH_SQUARES, self._squares[1] - r - 1.5),
            )
        u0, u1, v0, v1 = (round(e * p) for e in (u0, u1, v0, v1))
        x, y = self._xy(corner_id)
        px_m = self._square_m / p
        centre = (x + 0.5 * (u0 + u1) * px_m, y - 0.5 * (v0 + v1) * px_m)
        size = ((u1 - u0) * px_m, (v1 - v0) * px_m)
        patch = draw_sheet(size, list(self._blocks), 1.0 / px_m, 4, centre)
        return patch.astype(np.float32), TemplateFrame(2 * p, -p - u0, -p - v0)

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
            if (around := np.count_nonzero(near) - 1) < 3:
                rejected.append(
                    Rejection(
                        f"corner {corner_id}: {around} of the corners around it found, 3 needed to "
                        "place its squares",
                        int(corner_id),
                    )
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
            template, frame = self._template(int(corner_id), p)
            try:
                fit = fit_template(
                    gray,
                    rough,
                    template,
                    frame,
                    REGION_FRACTION,
                    corner_floor_px=0.0,
                    center_floor_px=self._floor_px,
                    min_correlation=self._min_correlation,
                    words=WHOLE_SQUARES_WORDS if self._whole_squares else CORNER_WORDS,
                    in_view=UNIT_SQUARE if self._whole_squares else _IN_VIEW,
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
    OpenCV (find_corners, per kind, named pass_name in the detections, or the pass it adds), each
    refined by the CornerFitter, with corner_floor_px (a corner is its own centre: one floor for
    both)."""

    pass_name: str
    corner_floor: float
    whole_squares = False  # CornerFitter's

    def __init__(self, board: GridCorners, settings: DetectorSettings | None = None) -> None:
        self.board = board
        self.settings = settings or DetectorSettings()
        self.corner_floor_px = self.center_floor_px = max(self.settings.center_floor_px, self.corner_floor)
        self._fitter = CornerFitter(
            board, self.corner_floor_px, self.settings.min_correlation, self.whole_squares
        )

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
        # The pass that found the corners: the last one run (find_corners may run more).
        result.markers, result.rejected = self._fitter.fit(gray, found, result.passes_run[-1])
        result.markers.sort(key=lambda m: m.marker_id)
        return result
