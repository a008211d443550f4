"""The marker detector: board markers in an image, with IDs, ordered sub-pixel corners and quality.

``QRDetector(board).detect(image)`` runs decoding passes (back-end and
upscaling, cheapest first), keeps the symbols whose payload names a marker of
the board, puts their corners in the marker's own order (top-left, top-right,
bottom-right, bottom-left of the upright symbol, whatever library found it and
however it is rotated in the image), and refines them by aligning the known
code (estimator.targets.qr_fit). Passes stop once every marker the board predicts
inside the image has been decoded. Everything not turned into a marker is
returned as a Rejection with its reason: foreign codes, markers seen twice,
fits that failed, and markers the board predicts in view that nobody decoded.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from estimator.targets.board import BoardDefinition
from estimator.targets.detection import Detections, MarkerDetection, Rejection, image_problem, to_gray
from estimator.targets.qr_decode import BACKENDS, DecodedSymbol, decode_qr
from estimator.targets.qr_fit import (
    DEFAULT_CENTER_FLOOR_PX,
    DEFAULT_CORNER_FLOOR_PX,
    MarkerFitError,
    fit_marker,
    fits_in_image,
    orient_corners,
)

DEFAULT_PASSES = ("zxing@1", "zxing@2", "pyzbar@1", "pyzbar@2")


@dataclass(frozen=True)
class DetectorSettings:
    """passes: "backend@scale" decoding passes in order (back-ends: zxing, pyzbar, opencv).
    stop_when_complete: skip later passes once every marker predicted in view is decoded.
    corner_floor_px, center_floor_px: pixel error image noise does not explain (see
    estimator.targets.qr_fit). Markers whose modules or aligned code match worse than
    min_module_agreement or min_correlation are rejected."""

    passes: tuple[str, ...] = DEFAULT_PASSES
    stop_when_complete: bool = True
    corner_floor_px: float = DEFAULT_CORNER_FLOOR_PX
    center_floor_px: float = DEFAULT_CENTER_FLOOR_PX
    min_module_agreement: float = 0.9
    min_correlation: float = 0.8

    def __post_init__(self) -> None:
        if not self.passes:
            raise ValueError("at least one decoding pass is needed")
        for spec in self.passes:
            parse_pass(spec)

    def to_dict(self) -> dict:
        return {
            "passes": list(self.passes),
            "stop_when_complete": self.stop_when_complete,
            "corner_floor_px": self.corner_floor_px,
            "center_floor_px": self.center_floor_px,
            "min_module_agreement": self.min_module_agreement,
            "min_correlation": self.min_correlation,
        }

    @classmethod
    def from_dict(cls, d: dict) -> DetectorSettings:
        return cls(**{**d, "passes": tuple(d["passes"])})


def parse_pass(spec: str) -> tuple[str, int]:
    """'zxing@2' -> ('zxing', 2); a bare back-end name means scale 1."""
    backend, _, scale = spec.partition("@")
    if backend not in BACKENDS or not (scale == "" or (scale.isdigit() and int(scale) >= 1)):
        raise ValueError(
            f"bad decoding pass {spec!r}: expected BACKEND[@SCALE], BACKEND one of {', '.join(BACKENDS)}"
        )
    return backend, int(scale or 1)


@dataclass
class _Candidate:
    symbol: DecodedSymbol
    marker_id: int
    corners_px: np.ndarray  # oriented
    found_by: str


class QRDetector:
    """Finds a board's QR markers in images; see the module docstring."""

    def __init__(self, board: BoardDefinition, settings: DetectorSettings | None = None) -> None:
        self.board = board
        self.settings = settings or DetectorSettings()
        self._passes = [parse_pass(p) for p in self.settings.passes]

    def detect(self, image: np.ndarray) -> Detections:
        """Detect the board's markers. image: (H, W, 3) RGB or (H, W) grey, uint8."""
        try:
            gray = to_gray(image)
        except ValueError as exc:
            return Detections(problem=str(exc))
        problem = image_problem(gray)
        if problem is not None:
            return Detections(problem=problem)
        result = Detections(sharpness=float(cv2.Laplacian(gray, cv2.CV_32F).var()))
        seen: list[DecodedSymbol] = []
        candidates: list[_Candidate] = []
        for (backend, scale), spec in zip(self._passes, self.settings.passes, strict=True):
            for symbol in decode_qr(gray, backend, scale):
                if any(_same_place(symbol, other) for other in seen):
                    continue
                seen.append(symbol)
                candidate = self._classify(gray, symbol, spec, result.rejected)
                if candidate is not None:
                    candidates.append(candidate)
            result.passes_run.append(spec)
            if self.settings.stop_when_complete and self._all_in_view_found(gray.shape, candidates):
                break
        for marker_id in sorted({c.marker_id for c in candidates}):
            same = [c for c in candidates if c.marker_id == marker_id]
            if len(same) > 1:
                where = ", ".join(f"({c.symbol.center_px[0]:.0f}, {c.symbol.center_px[1]:.0f})" for c in same)
                for c in same:
                    result.rejected.append(
                        Rejection(
                            f"marker {marker_id} appears {len(same)} times (at {where}): ambiguous, "
                            "all dropped",
                            marker_id,
                            c.symbol.payload,
                            c.corners_px,
                        )
                    )
                continue
            self._refine(gray, same[0], result)
        self._report_missing(gray.shape, result)
        return result

    def _classify(
        self, gray: np.ndarray, symbol: DecodedSymbol, spec: str, rejected: list[Rejection]
    ) -> _Candidate | None:
        marker_id = self.board.marker_id_from_payload(symbol.payload)
        if marker_id is None:
            rejected.append(
                Rejection(
                    f"foreign QR code {symbol.payload[:40]!r}: not a marker of board {self.board.name!r}",
                    payload=symbol.payload,
                    corners_px=symbol.corners_px,
                )
            )
            return None
        corners, agreement = orient_corners(gray, symbol.corners_px, self.board.module_matrix(marker_id))
        if agreement < self.settings.min_module_agreement:
            rejected.append(
                Rejection(
                    f"marker {marker_id}: only {agreement:.0%} of the modules under the symbol "
                    "match its code",
                    marker_id,
                    symbol.payload,
                    symbol.corners_px,
                )
            )
            return None
        return _Candidate(symbol, marker_id, corners, spec)

    def _refine(self, gray: np.ndarray, candidate: _Candidate, result: Detections) -> None:
        try:
            fit = fit_marker(
                gray,
                candidate.corners_px,
                self.board.module_matrix(candidate.marker_id),
                corner_floor_px=self.settings.corner_floor_px,
                center_floor_px=self.settings.center_floor_px,
                min_correlation=self.settings.min_correlation,
            )
        except MarkerFitError as exc:
            result.rejected.append(
                Rejection(
                    f"marker {candidate.marker_id}: {exc}",
                    candidate.marker_id,
                    candidate.symbol.payload,
                    candidate.corners_px,
                )
            )
            return
        result.markers.append(
            MarkerDetection(
                marker_id=candidate.marker_id,
                corners_px=fit.corners_px,
                corners_cov=fit.corners_cov,
                center_px=fit.center_px,
                center_cov=fit.center_cov,
                quality=fit.correlation,
                module_agreement=fit.module_agreement,
                noise_sigma=fit.noise_sigma,
                found_by=candidate.found_by,
                raw_corners_px=candidate.corners_px,
            )
        )

    def _missing_in_view(
        self, shape: tuple[int, ...], known: dict[int, np.ndarray], accounted: set[int]
    ) -> dict[int, np.ndarray]:
        """Markers not in ``accounted`` that the board-to-image homography of the ``known``
        markers' corners puts in view, with their predicted (4, 2) corners."""
        board_xy = np.concatenate([self.board.marker_corners(i)[:, :2] for i in known])
        H, _ = cv2.findHomography(board_xy, np.concatenate(list(known.values())), 0)
        if H is None:
            return {}
        missing = {}
        for marker_id in self.board.marker_ids:
            xy1 = np.column_stack([self.board.marker_corners(marker_id)[:, :2], np.ones(4)]) @ H.T
            if marker_id in accounted or not np.all(xy1[:, 2] > 0):
                continue
            corners = xy1[:, :2] / xy1[:, 2:3]
            if self._in_view(shape, corners):
                missing[marker_id] = corners
        return missing

    def _in_view(self, shape: tuple[int, ...], corners_px: np.ndarray) -> bool:
        """Whether a marker with its quiet zone lies inside the image and is big enough to decode."""
        side = float(np.linalg.norm(corners_px - np.roll(corners_px, 1, axis=0), axis=1).min())
        return fits_in_image(corners_px, 2.0 / self.board.modules, shape) and side >= 1.5 * self.board.modules

    def _all_in_view_found(self, shape: tuple[int, ...], candidates: list[_Candidate]) -> bool:
        known = {c.marker_id: c.corners_px for c in candidates}
        if set(known) >= set(self.board.marker_ids):
            return True
        return bool(known) and not self._missing_in_view(shape, known, set(known))

    def _report_missing(self, shape: tuple[int, ...], result: Detections) -> None:
        if not result.markers:
            return
        known = {m.marker_id: m.corners_px for m in result.markers}
        accounted = set(known) | {r.marker_id for r in result.rejected}
        for marker_id, corners in self._missing_in_view(shape, known, accounted).items():
            u, v = corners.mean(axis=0)
            result.rejected.append(
                Rejection(
                    f"marker {marker_id}: expected at ({u:.0f}, {v:.0f}) but no pass decoded it "
                    f"({', '.join(result.passes_run)})",
                    marker_id,
                    corners_px=corners,
                )
            )


def _same_place(a: DecodedSymbol, b: DecodedSymbol) -> bool:
    """Whether two decoded symbols are one symbol seen twice (same text, centres within 30% of a side)."""
    return a.payload == b.payload and float(np.linalg.norm(a.center_px - b.center_px)) < 0.3 * max(
        a.side_px, b.side_px
    )
