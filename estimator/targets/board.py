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

from hec.estimator.targets.qr_symbol import ERROR_CORRECTION, SymbolSpec
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

    def _marker_dict(self, marker_id: int) -> dict:
        """A marker's entry: id, centre and only what differs from the board's defaults."""
        entry: dict = {"id": marker_id, "center_m": list(self.marker_centers_m[marker_id])}
        symbol = self.symbol(marker_id)
        if self.payload_prefix is None or symbol.payload != f"{self.payload_prefix}{marker_id:02d}":
            entry["payload"] = symbol.payload
        if symbol.version != self.qr_version:
            entry["qr_version"] = symbol.version
        if symbol.error_correction != self.qr_error_correction:
            entry["qr_error_correction"] = symbol.error_correction
        if symbol.mask is not None:
            entry["qr_mask"] = symbol.mask
        return entry

    def to_dict(self) -> dict:
        d = {
            "format": "hec-board",
            "version": 1,
            "name": self.name,
            "size_m": list(self.size_m),
            "marker_size_m": self.marker_size_m,
            "qr_version": self.qr_version,
            "qr_error_correction": self.qr_error_correction,
            "payload_prefix": self.payload_prefix,
            "markers": [self._marker_dict(i) for i in self.marker_ids],
        }
        if self.payload_prefix is None:
            del d["payload_prefix"]
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "board definition") -> BoardDefinition:
        """Validate and build; errors name ``source`` and the offending field."""

        def typed(key: str, kind: type | tuple[type, ...], where: dict = d, name: str = "") -> object:
            if key not in where:
                raise BoardDefinitionError(f"{source}: missing field '{name or key}'")
            value = where[key]
            if not isinstance(value, kind) or isinstance(value, bool):
                raise BoardDefinitionError(
                    f"{source}: field '{name or key}' should be {_kind_name(kind)}, got {value!r}"
                )
            return value

        if d.get("format") != "hec-board" or d.get("version") != 1:
            raise BoardDefinitionError(
                f"{source}: expected 'format': 'hec-board' and 'version': 1, "
                f"got {d.get('format')!r} version {d.get('version')!r}"
            )
        size = typed("size_m", list)
        if len(size) != 2 or not all(isinstance(v, int | float) and v > 0 for v in size):
            raise BoardDefinitionError(f"{source}: 'size_m' should be [width, height] > 0, got {size}")
        marker_size = float(typed("marker_size_m", (int, float)))
        if marker_size <= 0:
            raise BoardDefinitionError(f"{source}: 'marker_size_m' must be > 0, got {marker_size}")
        version = _check_version(typed("qr_version", int), f"{source}: 'qr_version'")
        ec = _check_level(typed("qr_error_correction", str), f"{source}: 'qr_error_correction'")
        prefix = typed("payload_prefix", str) if "payload_prefix" in d else None
        centers: dict[int, tuple[float, float]] = {}
        symbols: dict[int, SymbolSpec] = {}
        for k, marker in enumerate(typed("markers", list)):
            where = f"markers[{k}]"
            if not isinstance(marker, dict) or not isinstance(marker.get("id"), int):
                raise BoardDefinitionError(f"{source}: {where}: expected {{'id': int, 'center_m': [x, y]}}")
            marker_id = marker["id"]
            c = marker.get("center_m")
            if not isinstance(c, list) or len(c) != 2 or not all(isinstance(v, int | float) for v in c):
                raise BoardDefinitionError(
                    f"{source}: {where}.center_m: expected [x, y] in metres, got {c!r}"
                )
            if "payload" in marker:
                payload = typed("payload", str, marker, f"{where}.payload")
                if not payload:
                    raise BoardDefinitionError(f"{source}: {where}.payload is empty")
            elif prefix is None:
                raise BoardDefinitionError(
                    f"{source}: {where} has no 'payload' and the board no 'payload_prefix'"
                )
            else:
                payload = f"{prefix}{marker_id:02d}"
            numbered = "payload" not in marker
            if marker_id in centers or marker_id < 0 or (numbered and marker_id > 99):
                raise BoardDefinitionError(
                    f"{source}: {where}.id: IDs must be unique and >= 0 (0-99 when the payload is "
                    f"payload_prefix + two digits), got {marker_id}"
                )
            mask = marker.get("qr_mask")
            if mask is not None and (
                not isinstance(mask, int) or isinstance(mask, bool) or not 0 <= mask <= 7
            ):
                raise BoardDefinitionError(
                    f"{source}: {where}.qr_mask must be 0-7 (or absent: automatic), got {mask!r}"
                )
            symbol = SymbolSpec(
                payload,
                _check_version(marker.get("qr_version", version), f"{source}: {where}.qr_version"),
                _check_level(marker.get("qr_error_correction", ec), f"{source}: {where}.qr_error_correction"),
                mask,
            )
            try:
                symbol.matrix()
            except ValueError as exc:
                raise BoardDefinitionError(f"{source}: {where}: {exc}") from None
            centers[marker_id] = (float(c[0]), float(c[1]))
            symbols[marker_id] = symbol
        if not centers:
            raise BoardDefinitionError(f"{source}: 'markers' is empty")
        payloads = [s.payload for s in symbols.values()]
        if len(set(payloads)) != len(payloads):
            raise BoardDefinitionError(f"{source}: two markers carry the same payload")
        board = cls(
            name=typed("name", str),
            size_m=(float(size[0]), float(size[1])),
            marker_size_m=marker_size,
            qr_version=version,
            qr_error_correction=ec,
            payload_prefix=prefix,
            marker_centers_m=centers,
            marker_symbols=symbols,
        )
        board._check_layout(source)
        return board

    def _check_layout(self, source: str) -> None:
        """Every code needs QUIET_ZONE_MODULES of its modules of light around it on the sheet; two
        codes side by side share theirs, so they need the larger one between them."""
        w, h = self.size_m
        quiet = {i: QUIET_ZONE_MODULES * self.marker_size_m / self.symbol(i).modules for i in self.marker_ids}
        half = self.marker_size_m / 2
        for i, (cx, cy) in self.marker_centers_m.items():
            edge = min(w / 2 - abs(cx), h / 2 - abs(cy)) - half
            if edge < quiet[i] - 1e-9:
                raise BoardDefinitionError(
                    f"{source}: marker {i} "
                    + ("leaves the sheet" if edge < 0 else f"is {edge * 1e3:.1f} mm from the sheet's edge")
                    + "; the detector needs "
                    f"{QUIET_ZONE_MODULES} modules ({quiet[i] * 1e3:.1f} mm) of white around each code"
                )
            for j, (ox, oy) in self.marker_centers_m.items():
                gap = max(abs(cx - ox), abs(cy - oy)) - 2 * half
                need = max(quiet[i], quiet[j])
                if j > i and gap < need - 1e-9:
                    raise BoardDefinitionError(
                        f"{source}: markers {i} and {j} "
                        + ("overlap" if gap < 0 else f"are {gap * 1e3:.1f} mm apart")
                        + "; the detector needs "
                        f"{QUIET_ZONE_MODULES} modules ({need * 1e3:.1f} mm) of white between codes"
                    )


def _check_version(version: object, where: str) -> int:
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= 40:
        raise BoardDefinitionError(f"{where} must be an integer 1-40, got {version!r}")
    return version


def _check_level(level: object, where: str) -> str:
    if level not in ERROR_CORRECTION:
        raise BoardDefinitionError(f"{where} must be L, M, Q or H, got {level!r}")
    return level


def _kind_name(kind: type | tuple[type, ...]) -> str:
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "an object"}
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def board_image(board: BoardDefinition, px_per_m: float, supersample: int = 4) -> np.ndarray:
    """Render the sheet as a (H, W) uint8 image, white with black modules (sheet.draw_sheet)."""
    blocks = []
    for marker_id in board.marker_ids:
        modules = board.module_matrix(marker_id)
        left, top = board.marker_corners(marker_id)[0, :2]
        blocks.append(CellBlock(modules, float(left), float(top), board.marker_size_m / modules.shape[0]))
    return draw_sheet(board.size_m, blocks, px_per_m, supersample)
