"""The marker detector: board markers in an image, with IDs, ordered sub-pixel corners and quality.

``QRDetector(board).detect(image)`` runs decoding passes (back-end and
upscaling, cheapest first), keeps the symbols whose payload names a marker of
the board, puts their corners in the marker's own order (top-left, top-right,
bottom-right, bottom-left of the upright symbol, whatever library found it and
however it is rotated in the image), and refines them by aligning the known
code (hec.estimator.targets.qr_fit). Passes stop once every marker the board predicts
inside the image has been decoded. Everything not turned into a marker is
returned as a Rejection with its reason: foreign codes, markers seen twice,
fits that failed, and markers the board predicts in view that nobody decoded.

The code each marker is compared with is regenerated from its SymbolSpec. When
a marker is printed with another version, error correction or mask than its
definition states (another generator, or a board file that leaves the mask to
the qrcode package), the detector takes what the print holds (as the decoder
reports it, or as the symbol's format modules read), says so once in the
Detections' notes, and keeps it for the detector's later images.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from hec.estimator.targets.board import QUIET_ZONE_MODULES, BoardDefinition
from hec.estimator.targets.detection import Detections, MarkerDetection, Rejection, start_detection
from hec.estimator.targets.qr_decode import BACKENDS, DecodedSymbol, decode_qr
from hec.estimator.targets.qr_fit import (
    DEFAULT_CENTER_FLOOR_PX,
    DEFAULT_CORNER_FLOOR_PX,
    MarkerFitError,
    corner_orderings,
    fit_marker,
    fits_in_image,
    module_agreement,
    orient_corners,
    sample_modules,
)
from hec.estimator.targets.qr_symbol import SymbolSpec, read_format

DEFAULT_PASSES = ("zxing@1", "zxing@2", "pyzbar@1", "pyzbar@2")
# Data-module agreement of two unrelated bit streams is about 0.5; up to this, the data differ.
RANDOM_DATA_AGREEMENT = 0.6


@dataclass(frozen=True)
class DetectorSettings:
    """passes: "backend@scale" decoding passes in order (back-ends: zxing, pyzbar, opencv).
    stop_when_complete: skip later passes once every marker predicted in view is decoded.
    corner_floor_px, center_floor_px: pixel error image noise does not explain (see
    hec.estimator.targets.qr_fit). learn_corner_floor: a dataset's observations get the floors
    its markers' consistency shows instead, these constants as the least
    (hec.estimator.observe.corner_noise; the detector itself always uses the constants).
    Markers whose modules or aligned code match worse than min_module_agreement or
    min_correlation are rejected. follow_printed_symbol: a marker
    printed with another version, error correction or mask than its definition is compared
    with the code as printed (False: rejected, naming the difference)."""

    passes: tuple[str, ...] = DEFAULT_PASSES
    stop_when_complete: bool = True
    corner_floor_px: float = DEFAULT_CORNER_FLOOR_PX
    center_floor_px: float = DEFAULT_CENTER_FLOOR_PX
    learn_corner_floor: bool = True
    min_module_agreement: float = 0.9
    min_correlation: float = 0.8
    follow_printed_symbol: bool = True

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
            "learn_corner_floor": self.learn_corner_floor,
            "min_module_agreement": self.min_module_agreement,
            "min_correlation": self.min_correlation,
            "follow_printed_symbol": self.follow_printed_symbol,
        }

    @classmethod
    def from_dict(cls, d: dict) -> DetectorSettings:
        """The settings to_dict wrote; without learn_corner_floor (caches made before it
        existed) the constant floors were used."""
        return cls(**{"learn_corner_floor": False, **d, "passes": tuple(d["passes"])})


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
    printed: SymbolSpec


class QRDetector:
    """Finds a board's QR markers in images; see the module docstring."""

    def __init__(self, board: BoardDefinition, settings: DetectorSettings | None = None) -> None:
        self.board = board
        self.settings = settings or DetectorSettings()
        self._passes = [parse_pass(p) for p in self.settings.passes]
        self.corner_floor_px = self.settings.corner_floor_px
        self.center_floor_px = self.settings.center_floor_px
        # Markers found printed otherwise than the board defines, as printed.
        self._printed: dict[int, SymbolSpec] = {}

    def detect(self, image: np.ndarray) -> Detections:
        """Detect the board's markers. image: (H, W, 3) RGB or (H, W) grey, uint8."""
        gray, result = start_detection(image)
        if gray is None:
            return result
        seen: list[DecodedSymbol] = []
        candidates: list[_Candidate] = []
        for (backend, scale), spec in zip(self._passes, self.settings.passes, strict=True):
            for symbol in decode_qr(gray, backend, scale):
                if any(_same_place(symbol, other) for other in seen):
                    continue
                seen.append(symbol)
                candidate = self._classify(gray, symbol, spec, result)
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
        self, gray: np.ndarray, symbol: DecodedSymbol, spec: str, result: Detections
    ) -> _Candidate | None:
        marker_id = self.board.marker_id_from_payload(symbol.payload)
        if marker_id is None:
            result.rejected.append(
                Rejection(
                    f"foreign QR code {symbol.payload[:40]!r}: not a marker of board {self.board.name!r}",
                    payload=symbol.payload,
                    corners_px=symbol.corners_px,
                )
            )
            return None
        expected = self._printed.get(marker_id, self.board.symbol(marker_id)).pinned()
        reported = replace(
            expected,
            version=symbol.version or expected.version,
            error_correction=symbol.error_correction or expected.error_correction,
            mask=expected.mask if symbol.mask is None else symbol.mask,
        )
        printed = self._printed_symbol(gray, symbol.corners_px, expected, reported)
        if isinstance(printed, str):
            result.rejected.append(
                Rejection(f"marker {marker_id}: {printed}", marker_id, symbol.payload, symbol.corners_px)
            )
            return None
        code, corners = printed
        if code != expected:
            self._follow(marker_id, code, result)
        return _Candidate(symbol, marker_id, corners, spec, code)

    def _printed_symbol(
        self, gray: np.ndarray, corners_px: np.ndarray, expected: SymbolSpec, reported: SymbolSpec
    ) -> tuple[SymbolSpec, np.ndarray] | str:
        """The symbol as printed and the (4, 2) corners oriented by it, or why the marker is
        rejected. reported: ``expected`` with what the decoder read. Without a match, the
        symbol's format modules say what differs."""
        follow = self.settings.follow_printed_symbol
        least = self.settings.min_module_agreement
        if reported != expected and not follow:
            return f"the printed code differs from the regenerated one: {expected.differences(reported)}"
        try:
            corners, agreement = orient_corners(gray, corners_px, reported.matrix())
        except ValueError as exc:  # the payload does not fit the version the decoder read
            return f"the printed code cannot be regenerated: {exc}"
        if agreement >= least:
            return reported, corners
        framed, read = _read_format(gray, corners_px, reported, least)
        if framed < least:
            return (
                f"the decoder's corners do not frame the code: only {framed:.0%} of its finder and timing "
                f"modules match ({agreement:.0%} of all modules)"
            )
        if read is None:
            return (
                f"only {agreement:.0%} of the modules match the regenerated code ({reported.describe()}) "
                "and the printed format modules cannot be read"
            )
        dark, fmt = read
        printed = replace(reported, error_correction=fmt[0], mask=fmt[1])
        if printed != reported:
            if not follow:
                return f"the printed code differs from the regenerated one: {expected.differences(printed)}"
            try:
                corners, agreement = orient_corners(gray, corners_px, printed.matrix())
            except ValueError as exc:
                return f"the printed code ({printed.describe()}) cannot be regenerated: {exc}"
            if agreement >= least:
                return printed, corners
        return _data_mismatch(dark, printed)

    def _follow(self, marker_id: int, printed: SymbolSpec, result: Detections) -> None:
        """Use ``printed`` for this marker from now on, and say so once."""
        if self._printed.get(marker_id) == printed:
            return
        defined = self.board.symbol(marker_id)
        self._printed[marker_id] = printed
        unstated = (
            " (the board file states no mask)"
            if defined.mask is None and printed.mask != defined.pinned().mask
            else ""
        )
        result.notes.append(
            f"marker {marker_id} is printed otherwise than board {self.board.name!r} defines: "
            f"{defined.pinned().differences(printed)}{unstated}; using the printed code"
        )

    def _refine(self, gray: np.ndarray, candidate: _Candidate, result: Detections) -> None:
        try:
            fit = fit_marker(
                gray,
                candidate.corners_px,
                candidate.printed.matrix(),
                corner_floor_px=self.settings.corner_floor_px,
                center_floor_px=self.settings.center_floor_px,
                min_correlation=self.settings.min_correlation,
                not_paper_ab=self.board.not_paper_around(candidate.marker_id),
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
        self, shape: tuple[int, ...], known: dict[int, np.ndarray], accounted: set[int], quiet_modules: float
    ) -> dict[int, np.ndarray]:
        """Markers not in ``accounted`` that the board-to-image homography of the ``known``
        markers' corners puts in view with ``quiet_modules`` of their quiet zone, with their
        predicted (4, 2) corners."""
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
            if self._in_view(shape, corners, self.board.symbol(marker_id).modules, quiet_modules):
                missing[marker_id] = corners
        return missing

    @staticmethod
    def _in_view(shape: tuple[int, ...], corners_px: np.ndarray, n: int, quiet_modules: float) -> bool:
        """Whether a marker of n modules with quiet_modules of its quiet zone lies inside the image
        and is big enough to decode."""
        side = float(np.linalg.norm(corners_px - np.roll(corners_px, 1, axis=0), axis=1).min())
        return fits_in_image(corners_px, quiet_modules / n, shape) and side >= 1.5 * n

    def _all_in_view_found(self, shape: tuple[int, ...], candidates: list[_Candidate]) -> bool:
        known = {c.marker_id: c.corners_px for c in candidates}
        if set(known) >= set(self.board.marker_ids):
            return True
        return bool(known) and not self._missing_in_view(shape, known, set(known), QUIET_ZONE_MODULES)

    def _report_missing(self, shape: tuple[int, ...], result: Detections) -> None:
        """A rejection for every marker whose code (if not its quiet zone) the found ones put in view."""
        if not result.markers:
            return
        known = {m.marker_id: m.corners_px for m in result.markers}
        accounted = set(known) | {r.marker_id for r in result.rejected}
        for marker_id, corners in self._missing_in_view(shape, known, accounted, 0.0).items():
            u, v = corners.mean(axis=0)
            n = self.board.symbol(marker_id).modules
            cut = (
                ""
                if self._in_view(shape, corners, n, QUIET_ZONE_MODULES)
                else "; its quiet zone leaves the image"
            )
            result.rejected.append(
                Rejection(
                    f"marker {marker_id}: expected at ({u:.0f}, {v:.0f}) but no pass decoded it "
                    f"({', '.join(result.passes_run)}){cut}",
                    marker_id,
                    corners_px=corners,
                )
            )


def _read_format(
    gray: np.ndarray, corners_px: np.ndarray, spec: SymbolSpec, least: float
) -> tuple[float, tuple[np.ndarray, tuple[str, int, int]] | None]:
    """The printed format (level, mask, bit errors) and the (n, n) modules read under the corner
    ordering that frames ``spec``'s mask-independent modules (at least ``least`` of them) and
    reads the nearest format word: the format tells the two orderings apart that the
    mask-independent modules cannot (the symbol and its mirror about the diagonal).
    Returns the best framing agreement and the reading, None if no format could be read."""
    framed, best = 0.0, None
    for corners in corner_orderings(corners_px):
        agreement = module_agreement(gray, corners, spec.matrix(), spec.mask_independent())
        framed = max(framed, agreement)
        dark = sample_modules(gray, corners, spec.modules) if agreement >= least else None
        fmt = None if dark is None else read_format(dark)
        if fmt is not None and (best is None or fmt[2] < best[1][2]):
            best = (dark, fmt)
    return framed, best


def _data_mismatch(dark: np.ndarray, printed: SymbolSpec) -> str:
    """Why modules read as ``dark`` (n, n) do not match ``printed``, whose format and fixed
    patterns they do match: about half the data modules wrong is another bit stream (the
    payload encoded otherwise); fewer, a part of the symbol read wrong (named by its quarter)."""
    wrong = dark != printed.matrix()
    data_agreement = 1.0 - float(np.mean(wrong[~printed.mask_independent()]))
    head = (
        f"the printed code differs from the regenerated one in its data: {printed.describe()} on both, "
        f"but only {data_agreement:.0%} of the data modules match"
    )
    if data_agreement <= RANDOM_DATA_AGREEMENT:
        return f"{head} (the payload encoded otherwise, by another QR generator?)"
    h = wrong.shape[0] // 2
    quarters = {
        "top-left": wrong[:h, :h],
        "top-right": wrong[:h, h:],
        "bottom-left": wrong[h:, :h],
        "bottom-right": wrong[h:, h:],
    }
    worst = max(quarters, key=lambda k: int(quarters[k].sum()))
    share = quarters[worst].sum() / max(int(wrong.sum()), 1)
    return (
        f"{head}, {share:.0%} of the wrong ones in the symbol's {worst} quarter (blur, glare or damage "
        "there, or the decoder's corners off?)"
    )


def _same_place(a: DecodedSymbol, b: DecodedSymbol) -> bool:
    """Whether two decoded symbols are one symbol seen twice (same text, centres within 30% of a side)."""
    return a.payload == b.payload and float(np.linalg.norm(a.center_px - b.center_px)) < 0.3 * max(
        a.side_px, b.side_px
    )
