"""The calibration board: QR markers with their IDs and corners in the board frame.

A board definition file (JSON, see models/boards/) gives the sheet size, the
marker side, each marker's centre and the payload prefix. The payload of
marker ``i`` is ``prefix + f"{i:02d}"``; anything else is a foreign code.
The same definition renders the simulator's texture and the printable sheet.

Board frame: origin at the sheet centre, x right, y up, z out of the printed
face. Corner order of every marker: top-left, top-right, bottom-right,
bottom-left of the upright symbol (finder patterns at corners 0, 1 and 3).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import qrcode

from estimator.io.jsonfile import read_json_object
from estimator.io.models import models_dir

_ERROR_CORRECTION = {
    "L": qrcode.constants.ERROR_CORRECT_L,
    "M": qrcode.constants.ERROR_CORRECT_M,
    "Q": qrcode.constants.ERROR_CORRECT_Q,
    "H": qrcode.constants.ERROR_CORRECT_H,
}
# Corner offsets of an upright marker, in units of its side, board frame (x right, y up).
_CORNER_OFFSETS = np.array([[-0.5, 0.5], [0.5, 0.5], [0.5, -0.5], [-0.5, -0.5]])
QUIET_ZONE_MODULES = 4


class BoardDefinitionError(ValueError):
    """A board definition file is missing a field or has a bad value."""


@dataclass(frozen=True)
class BoardDefinition:
    """A planar board of QR markers; all lengths in metres."""

    name: str
    size_m: tuple[float, float]
    marker_size_m: float
    qr_version: int
    qr_error_correction: str
    payload_prefix: str
    marker_centers_m: dict[int, tuple[float, float]]

    @property
    def marker_ids(self) -> list[int]:
        return sorted(self.marker_centers_m)

    @property
    def modules(self) -> int:
        """Modules along one side of a symbol (21 for QR version 1)."""
        return 17 + 4 * self.qr_version

    def payload(self, marker_id: int) -> str:
        return f"{self.payload_prefix}{marker_id:02d}"

    def marker_id_from_payload(self, payload: str) -> int | None:
        """The marker ID a decoded payload names, or None for a foreign code."""
        match = re.fullmatch(re.escape(self.payload_prefix) + r"(\d{2})", payload)
        if match is None:
            return None
        marker_id = int(match.group(1))
        return marker_id if marker_id in self.marker_centers_m else None

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

    def module_matrix(self, marker_id: int) -> np.ndarray:
        """(n, n) bool, True where the symbol is dark; row 0 is the symbol's top. Read-only."""
        return _qr_modules(self.payload(marker_id), self.qr_version, self.qr_error_correction)

    def to_dict(self) -> dict:
        return {
            "format": "hec-board",
            "version": 1,
            "name": self.name,
            "size_m": list(self.size_m),
            "marker_size_m": self.marker_size_m,
            "qr_version": self.qr_version,
            "qr_error_correction": self.qr_error_correction,
            "payload_prefix": self.payload_prefix,
            "markers": [{"id": i, "center_m": list(self.marker_centers_m[i])} for i in self.marker_ids],
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "board definition") -> BoardDefinition:
        """Validate and build; errors name ``source`` and the offending field."""

        def field(key: str, kind: type | tuple[type, ...]) -> object:
            if key not in d:
                raise BoardDefinitionError(f"{source}: missing field '{key}'")
            value = d[key]
            if not isinstance(value, kind) or isinstance(value, bool):
                raise BoardDefinitionError(
                    f"{source}: field '{key}' should be {_kind_name(kind)}, got {value!r}"
                )
            return value

        if d.get("format") != "hec-board" or d.get("version") != 1:
            raise BoardDefinitionError(
                f"{source}: expected 'format': 'hec-board' and 'version': 1, "
                f"got {d.get('format')!r} version {d.get('version')!r}"
            )
        size = field("size_m", list)
        if len(size) != 2 or not all(isinstance(v, int | float) and v > 0 for v in size):
            raise BoardDefinitionError(f"{source}: 'size_m' should be [width, height] > 0, got {size}")
        marker_size = float(field("marker_size_m", (int, float)))
        if marker_size <= 0:
            raise BoardDefinitionError(f"{source}: 'marker_size_m' must be > 0, got {marker_size}")
        version = field("qr_version", int)
        if not 1 <= version <= 40:
            raise BoardDefinitionError(f"{source}: 'qr_version' must be 1-40, got {version}")
        ec = field("qr_error_correction", str)
        if ec not in _ERROR_CORRECTION:
            raise BoardDefinitionError(f"{source}: 'qr_error_correction' must be L, M, Q or H, got {ec!r}")
        centers: dict[int, tuple[float, float]] = {}
        for k, marker in enumerate(field("markers", list)):
            where = f"{source}: markers[{k}]"
            if not isinstance(marker, dict) or not isinstance(marker.get("id"), int):
                raise BoardDefinitionError(f"{where}: expected {{'id': int, 'center_m': [x, y]}}")
            c = marker.get("center_m")
            if not isinstance(c, list) or len(c) != 2 or not all(isinstance(v, int | float) for v in c):
                raise BoardDefinitionError(f"{where}.center_m: expected [x, y] in metres, got {c!r}")
            if not 0 <= marker["id"] <= 99 or marker["id"] in centers:
                raise BoardDefinitionError(f"{where}.id: IDs must be unique and in 0-99, got {marker['id']}")
            centers[marker["id"]] = (float(c[0]), float(c[1]))
        if not centers:
            raise BoardDefinitionError(f"{source}: 'markers' is empty")
        board = cls(
            name=field("name", str),
            size_m=(float(size[0]), float(size[1])),
            marker_size_m=marker_size,
            qr_version=version,
            qr_error_correction=ec,
            payload_prefix=field("payload_prefix", str),
            marker_centers_m=centers,
        )
        board._check_layout(source)
        return board

    def _check_layout(self, source: str) -> None:
        """Markers, with their quiet zones, must lie on the sheet and not overlap."""
        pad = self.marker_size_m * (0.5 + QUIET_ZONE_MODULES / self.modules)
        w, h = self.size_m
        for i, (cx, cy) in self.marker_centers_m.items():
            if abs(cx) + pad > w / 2 + 1e-12 or abs(cy) + pad > h / 2 + 1e-12:
                raise BoardDefinitionError(f"{source}: marker {i} and its quiet zone do not fit on the sheet")
            for j, (ox, oy) in self.marker_centers_m.items():
                if j > i and abs(cx - ox) < 2 * pad - 1e-12 and abs(cy - oy) < 2 * pad - 1e-12:
                    raise BoardDefinitionError(f"{source}: markers {i} and {j} overlap their quiet zones")


@functools.lru_cache(maxsize=1024)
def _qr_modules(payload: str, version: int, error_correction: str) -> np.ndarray:
    """The module matrix of one QR symbol (cached: encoding costs milliseconds)."""
    qr = qrcode.QRCode(version=version, error_correction=_ERROR_CORRECTION[error_correction], border=0)
    qr.add_data(payload)
    qr.make(fit=False)
    modules = np.array(qr.get_matrix(), dtype=bool)
    modules.flags.writeable = False
    return modules


def _kind_name(kind: type | tuple[type, ...]) -> str:
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "an object"}
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def load_board(path: str | Path) -> BoardDefinition:
    """Read a board definition file; errors name the file and the field."""
    path = Path(path)
    data = read_json_object(path, BoardDefinitionError, "board definition file not found")
    return BoardDefinition.from_dict(data, source=str(path))


def board_image(board: BoardDefinition, px_per_m: float, supersample: int = 4) -> np.ndarray:
    """Render the sheet as a (H, W) uint8 image, white with black modules.

    Row 0 is the sheet's top edge (largest y), column 0 its left edge.
    The sheet spans exactly the image: a pixel is size_m[0] / W wide. Edges
    that fall inside a pixel are area-averaged over supersample^2 samples.
    """
    w_m, h_m = board.size_m
    W, H = round(w_m * px_per_m), round(h_m * px_per_m)
    ss = supersample
    px_x, px_y = w_m / (W * ss), h_m / (H * ss)
    dark = np.zeros((H * ss, W * ss), dtype=bool)
    module = board.marker_size_m / board.modules
    for marker_id in board.marker_ids:
        modules = board.module_matrix(marker_id)
        left, top = board.marker_corners(marker_id)[0, :2]
        cols = np.arange(W * ss)
        rows = np.arange(H * ss)
        x = -w_m / 2 + (cols + 0.5) * px_x
        y = h_m / 2 - (rows + 0.5) * px_y
        mc = np.floor((x - left) / module).astype(int)
        mr = np.floor((top - y) / module).astype(int)
        in_c = (mc >= 0) & (mc < board.modules)
        in_r = (mr >= 0) & (mr < board.modules)
        rr, cc = np.nonzero(in_r)[0], np.nonzero(in_c)[0]
        dark[np.ix_(rr, cc)] |= modules[np.ix_(mr[rr], mc[cc])]
    coverage = dark.reshape(H, ss, W, ss).mean(axis=(1, 3))
    return np.round(255.0 * (1.0 - coverage)).astype(np.uint8)


def find_board(name: str, base_dir: Path = Path(".")) -> BoardDefinition:
    """A board named in models/boards/ (without .json), else a JSON path relative to base_dir."""
    named = models_dir() / "boards" / f"{name}.json"
    return load_board(named if named.is_file() else base_dir / name)
