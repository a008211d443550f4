"""The calibration board: QR markers with their IDs and corners in the board frame.

A board definition file (JSON, see models/boards/) gives the sheet size, the
marker side, each marker's centre and what its printed symbol holds. A marker's
payload is its own ``payload`` string if it has one, else ``payload_prefix +
f"{id:02d}"`` (the scheme of the boards hec prints); any other payload is a
foreign code. Its symbol's version and error correction are the board's unless
the marker states its own, and its mask is ``qr_mask`` if given, else the qrcode
package's automatic choice (``hec board`` writes the masks it printed). The same
definition renders the simulator's texture and the printable sheet.

Board frame: origin at the sheet centre, x right, y up, z out of the printed
face. Corner order of every marker: top-left, top-right, bottom-right,
bottom-left of the upright symbol (finder patterns at corners 0, 1 and 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from hec.estimator.targets.qr_symbol import SymbolSpec
from hec.estimator.targets.sheet import CellBlock, draw_sheet
from hec.estimator.targets.target import BoardDefinitionError

# Corner offsets of an upright marker, in units of its side, board frame (x right, y up).
_CORNER_OFFSETS = np.array([[-0.5, 0.5], [0.5, 0.5], [0.5, -0.5], [-0.5, -0.5]])
# Light modules the decoders need around a code (zxing and zbar find 2-module gaps between codes): the
# layout rule. Neighbours may share this zone; the corner fit leaves out what is not paper in it.
QUIET_ZONE_MODULES = 2


@dataclass(frozen=True)
class BoardDefinition:
    """A planar board of QR markers; all lengths in metres. qr_version and qr_error_correction
    are the symbols' defaults; marker_symbols holds each marker's own symbol (markers not in
    it carry payload_prefix + two digits with the defaults and the automatic mask)."""

    name: str
    size_m: tuple[float, float]
    marker_size_m: float
    qr_version: int
    qr_error_correction: str
    payload_prefix: str | None
    marker_centers_m: dict[int, tuple[float, float]]
    marker_symbols: dict[int, SymbolSpec] = field(default_factory=dict)

    kind = "qr"
    points_per_marker = 4
    markers_placed_one_by_one = True
    corners_homography_fitted = True

    @property
    def marker_ids(self) -> list[int]:
        return sorted(self.marker_centers_m)

    @property
    def feature_m(self) -> float:
        """The smallest module: the marker side over its symbol's module count."""
        return self.marker_size_m / self.modules

    @property
    def visible_margin_m(self) -> float:
        """The quiet zone the decoders need to find a symbol (QUIET_ZONE_MODULES)."""
        return QUIET_ZONE_MODULES * self.feature_m

    def image(self, px_per_m: float, supersample: int = 4) -> np.ndarray:
        """The sheet as an (H, W) uint8 image (board_image)."""
        return board_image(self, px_per_m, supersample)

    @property
    def modules(self) -> int:
        """Modules along one side of the board's smallest-count symbol (21 for QR version 1):
        quiet_modules / modules is then the largest quiet zone as a fraction of a marker side."""
        return min(self.symbol(i).modules for i in self.marker_ids)

    def symbol(self, marker_id: int) -> SymbolSpec:
        """What regenerates marker ``marker_id``'s printed symbol."""
        if marker_id in self.marker_symbols:
            return self.marker_symbols[marker_id]
        return self._default_symbol(marker_id)

    def payload(self, marker_id: int) -> str:
        return self.symbol(marker_id).payload

    def marker_id_from_payload(self, payload: str) -> int | None:
        """The marker ID a decoded payload names, or None for a foreign code."""
        return next((i for i in self.marker_ids if self.payload(i) == payload), None)

    def marker_corners(self, marker_id: int) -> np.ndarray:
        """(4, 3) corners of one marker in the board frame, in the documented order."""
        cx, cy = self.marker_centers_m[marker_id]
        xy = np.array([cx, cy]) + _CORNER_OFFSETS * self.marker_size_m
        return np.column_stack([xy, np.zeros(4)])

    def marker_center(self, marker_id: int) -> np.ndarray:
        """(3,) centre of one marker in the board frame."""
        cx, cy = self.marker_centers_m[marker_id]
        return np.array([cx, cy, 0.0])

    def all_corners(self) -> np.ndarray:
        """(M, 4, 3) corners of every marker, ordered by marker_ids."""
        return np.stack([self.marker_corners(i) for i in self.marker_ids])

    def not_paper_around(self, marker_id: int, margin_modules: float = 0.3) -> np.ndarray:
        """(K, 4) rectangles [a0, b0, a1, b1] in marker ``marker_id``'s symbol coordinates (a to the
        right, b down, the symbol spanning [0, 1]) where the sheet is not plain paper: the other
        codes grown by margin_modules of their own modules (for the image's blur), and everything
        beyond the sheet and within margin_modules of its edge. A wider margin costs more than it
        saves: the fit's mask stays put while the code moves (rendered qr_18_tight, 2.3-4.3 px per
        module: corner RMS 0.14 px with 1 module, 0.035 px with 0.3)."""
        side = self.marker_size_m
        left, top = self.marker_corners(marker_id)[0, :2]
        rects = []
        for other in self.marker_ids:
            if other != marker_id:
                grow = margin_modules * side / self.symbol(other).modules
                (x0, y1), (x1, y0) = self.marker_corners(other)[0, :2], self.marker_corners(other)[2, :2]
                rects.append([x0 - grow, y1 + grow, x1 + grow, y0 - grow])
        edge = margin_modules * side / self.symbol(marker_id).modules
        w, h, far = self.size_m[0] / 2 - edge, self.size_m[1] / 2 - edge, 1e3
        rects += [[-far, far, -w, -far], [w, far, far, -far], [-far, far, far, h], [-far, -h, far, -far]]
        xy = np.array(rects)  # [x_left, y_top, x_right, y_bottom] in the board frame
        return np.column_stack([xy[:, 0] - left, top - xy[:, 1], xy[:, 2] - left, top - xy[:, 3]]) / side

    def module_matrix(self, marker_id: int) -> np.ndarray:
        """(n, n) bool, True where the symbol is dark; row 0 is the symbol's top. Read-only."""
        return self.symbol(marker_id).matrix()

    def pinned(self) -> BoardDefinition:
        """The same board with every marker's mask stated (automatic choices made explicit), as
        ``hec board`` records what it printed."""
        return replace(self, marker_symbols={i: self.symbol(i).pinned() for i in self.marker_ids})

    def _default_symbol(self, marker_id: int) -> SymbolSpec:
        if self.payload_prefix is None:
            raise BoardDefinitionError(f"board {self.name!r}: marker {marker_id} has no payload")
        return SymbolSpec(f"{self.payload_prefix}{marker_id:02d}", self.qr_version, self.qr_error_correction)


def board_image(board: BoardDefinition, px_per_m: float, supersample: int = 4) -> np.ndarray:
    """Render the sheet as a (H, W) uint8 image, white with black modules (sheet.draw_sheet)."""
    blocks = []
    for marker_id in board.marker_ids:
        modules = board.module_matrix(marker_id)
        left, top = board.marker_corners(marker_id)[0, :2]
        blocks.append(CellBlock(modules, float(left), float(top), board.marker_size_m / modules.shape[0]))
    return draw_sheet(board.size_m, blocks, px_per_m, supersample)
