"""The board file of a board of QR codes (format hec-board version 1, no 'kind' or kind "qr"):
its schema and the BoardDefinition it describes (hec.estimator.targets.board's module doc).

Besides the fields below a file may carry notes (hec's own boards have 'description', 'frame'
and 'corner_order'); other keys are read past, as they always were.
"""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field, model_validator

from hec.estimator.io.schema import FileFormat, Integer, Number, Positive, Text
from hec.estimator.targets.board import QUIET_ZONE_MODULES, BoardDefinition
from hec.estimator.targets.qr_symbol import SymbolSpec

ErrorCorrection = Literal["L", "M", "Q", "H"]
_VERSION = "must be an integer 1-40"
_LEVEL = "must be L, M, Q or H"


class QRMarkerEntry(FileFormat):
    """One marker: its ID, centre (board frame, metres) and what of its symbol differs from the
    board's defaults."""

    model_config = ConfigDict(extra="ignore")

    id: Integer = Field(ge=0, description="should be an integer >= 0")
    center_m: tuple[Number, Number] = Field(description="should be [x, y] in metres")
    payload: Text | None = Field(None, min_length=1, description="should be a non-empty string")
    qr_version: Integer | None = Field(None, ge=1, le=40, description=_VERSION)
    qr_error_correction: ErrorCorrection | None = Field(None, description=_LEVEL)
    qr_mask: Integer | None = Field(None, ge=0, le=7, description="must be 0-7 (or absent: automatic)")


class QRBoardFile(FileFormat):
    """A board of QR codes; lengths in metres."""

    model_config = ConfigDict(extra="ignore")

    format: Literal["hec-board"]
    version: Literal[1]
    kind: Literal["qr"] | None = None
    name: Text = Field(description="should be a string")
    size_m: tuple[Positive, Positive] = Field(description="should be [width, height] > 0")
    marker_size_m: Positive = Field(description="should be a number > 0")
    qr_version: Integer = Field(ge=1, le=40, description=_VERSION)
    qr_error_correction: ErrorCorrection = Field(description=_LEVEL)
    payload_prefix: Text | None = Field(None, description="should be a string")
    markers: list[QRMarkerEntry] = Field(min_length=1, description="should be a non-empty list of markers")

    @model_validator(mode="after")
    def _markers_readable(self) -> QRBoardFile:
        payloads = []
        for k, marker in enumerate(self.markers):
            where = f"markers[{k}]"
            if marker.payload is None and self.payload_prefix is None:
                raise ValueError(f"{where} has no 'payload' and the board no 'payload_prefix'")
            numbered = marker.payload is None
            if any(m.id == marker.id for m in self.markers[:k]) or (numbered and marker.id > 99):
                raise ValueError(
                    f"{where}.id: IDs must be unique and >= 0 (0-99 when the payload is "
                    f"payload_prefix + two digits), got {marker.id}"
                )
            symbol = self._symbol(marker)
            try:
                symbol.matrix()
            except ValueError as exc:
                raise ValueError(f"{where}: {exc}") from None
            payloads.append(symbol.payload)
        if len(set(payloads)) != len(payloads):
            raise ValueError("two markers carry the same payload")
        problem = layout_problem(self.board())
        if problem:
            raise ValueError(problem)
        return self

    def _symbol(self, marker: QRMarkerEntry) -> SymbolSpec:
        return SymbolSpec(
            marker.payload or f"{self.payload_prefix}{marker.id:02d}",
            marker.qr_version or self.qr_version,
            marker.qr_error_correction or self.qr_error_correction,
            marker.qr_mask,
        )

    def board(self) -> BoardDefinition:
        """The board this file describes."""
        return BoardDefinition(
            name=self.name,
            size_m=self.size_m,
            marker_size_m=self.marker_size_m,
            qr_version=self.qr_version,
            qr_error_correction=self.qr_error_correction,
            payload_prefix=self.payload_prefix,
            marker_centers_m={m.id: m.center_m for m in self.markers},
            marker_symbols={m.id: self._symbol(m) for m in self.markers},
        )

    @classmethod
    def of(cls, board: BoardDefinition) -> QRBoardFile:
        """The file of a board: each marker's entry states only what differs from the defaults."""
        return cls.model_construct(
            format="hec-board",
            version=1,
            name=board.name,
            size_m=board.size_m,
            marker_size_m=board.marker_size_m,
            qr_version=board.qr_version,
            qr_error_correction=board.qr_error_correction,
            payload_prefix=board.payload_prefix,
            markers=[_marker_entry(board, i) for i in board.marker_ids],
        )


def _marker_entry(board: BoardDefinition, marker_id: int) -> QRMarkerEntry:
    symbol = board.symbol(marker_id)
    numbered = board.payload_prefix is not None and symbol.payload == f"{board.payload_prefix}{marker_id:02d}"
    return QRMarkerEntry.model_construct(
        id=marker_id,
        center_m=board.marker_centers_m[marker_id],
        payload=None if numbered else symbol.payload,
        qr_version=None if symbol.version == board.qr_version else symbol.version,
        qr_error_correction=(
            None if symbol.error_correction == board.qr_error_correction else symbol.error_correction
        ),
        qr_mask=symbol.mask,
    )


def layout_problem(board: BoardDefinition) -> str | None:
    """Why the decoders cannot read the board's layout, or None: every code needs
    QUIET_ZONE_MODULES of its modules of light around it on the sheet; two codes side by side
    share theirs, so they need the larger one between them."""
    w, h = board.size_m
    quiet = {i: QUIET_ZONE_MODULES * board.marker_size_m / board.symbol(i).modules for i in board.marker_ids}
    half = board.marker_size_m / 2
    for i, (cx, cy) in board.marker_centers_m.items():
        edge = min(w / 2 - abs(cx), h / 2 - abs(cy)) - half
        if edge < quiet[i] - 1e-9:
            return (
                f"marker {i} "
                + ("leaves the sheet" if edge < 0 else f"is {edge * 1e3:.1f} mm from the sheet's edge")
                + f"; the detector needs {QUIET_ZONE_MODULES} modules ({quiet[i] * 1e3:.1f} mm) of white "
                "around each code"
            )
        for j, (ox, oy) in board.marker_centers_m.items():
            gap = max(abs(cx - ox), abs(cy - oy)) - 2 * half
            need = max(quiet[i], quiet[j])
            if j > i and gap < need - 1e-9:
                return (
                    f"markers {i} and {j} "
                    + ("overlap" if gap < 0 else f"are {gap * 1e3:.1f} mm apart")
                    + f"; the detector needs {QUIET_ZONE_MODULES} modules ({need * 1e3:.1f} mm) of white "
                    "between codes"
                )
    return None
