"""What every calibration target offers, whatever its kind.

A target is a planar sheet whose detectable points are grouped into "markers": a QR code
or an AprilTag is a marker of its 4 corners, a chessboard or ChArUco corner is a marker of
one point. Every marker of a target has the same number of points (``points_per_marker``),
so the estimators see an (M, P, 3) array of board-frame points whatever the kind.

Board frame, every kind: origin at the sheet centre, x right, y up, z out of the printed
face (OpenCV's own board frames put the origin at a corner with y down and z into the
board: a 180-degree turn about x away, see each kind's module).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from hec.estimator.targets.detection import Detections


class BoardDefinitionError(ValueError):
    """A board definition file is missing a field or has a bad value."""


class TargetDetector(Protocol):
    """Finds a target's markers. corner_floor_px, center_floor_px: the error per coordinate image
    noise does not explain that its corner and centre covariances hold (pixels)."""

    corner_floor_px: float
    center_floor_px: float

    def detect(self, image: np.ndarray) -> Detections:
        """The target's markers in an (H, W, 3) RGB or (H, W) grey uint8 image."""
        ...


class Target(Protocol):
    """A board definition of any kind. Lengths in metres, board frame (module doc)."""

    name: str
    size_m: tuple[float, float]

    @property
    def kind(self) -> str:
        """ "qr", "charuco", "chessboard" or "aprilgrid"; the board file's "kind" field."""
        ...

    @property
    def points_per_marker(self) -> int:
        """P: 4 for QR codes and AprilTags, 1 for chessboard and ChArUco corners."""
        ...

    @property
    def marker_ids(self) -> list[int]:
        """Sorted IDs of every marker on the sheet."""
        ...

    @property
    def markers_placed_one_by_one(self) -> bool:
        """Whether each marker may sit off its nominal place on its own (QR codes pasted or
        printed one by one): the print model shifts them and self-calibration may free a shift
        per marker. False for kinds printed as one pattern."""
        ...

    @property
    def corners_homography_fitted(self) -> bool:
        """Whether each marker's corners come from one homography fitted over the whole marker,
        so that lens distortion biases them (hec.estimator.geometry.marker_fit_bias)."""
        ...

    @property
    def feature_m(self) -> float:
        """The smallest printed feature a detector must resolve (a QR module, a tag bit, a
        chessboard square): below a few pixels per feature nothing is found."""
        ...

    @property
    def visible_margin_m(self) -> float:
        """How far around a marker's points the sheet must be in the image for the marker
        to count as fully visible (its quiet zone, half a square)."""
        ...

    def marker_corners(self, marker_id: int) -> np.ndarray:
        """(P, 3) the marker's points in the board frame, in the kind's documented order."""
        ...

    def marker_center(self, marker_id: int) -> np.ndarray:
        """(3,) the marker's centre in the board frame (the point itself when P is 1)."""
        ...

    def all_corners(self) -> np.ndarray:
        """(M, P, 3) every marker's points, ordered by marker_ids."""
        ...

    def pinned(self) -> Target:
        """The definition of exactly what is printed (a QR board states every mask the qrcode
        package chose); kinds with nothing left to choose return themselves."""
        ...

    def image(self, px_per_m: float, supersample: int = 4) -> np.ndarray:
        """The sheet as an (H, W) uint8 image, white paper, black ink; row 0 is the top edge
        (largest y), column 0 the left edge, and the image spans exactly the sheet."""
        ...
