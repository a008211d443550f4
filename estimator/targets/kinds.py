"""Board files of every target kind: reading, writing, and the detector each kind uses.

A board file (JSON, format hec-board version 1) names its ``kind``; a file without one is a
board of QR codes (hec.estimator.targets.board), as every board file before the other kinds.
Kalibr's target YAML and OpenCV's ChArUco parameters are read as well (tool_boards).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_json_object, read_yaml_object
from hec.estimator.common.models import models_dir
from hec.estimator.targets.aprilgrid import AprilGridBoard, AprilGridDetector
from hec.estimator.targets.board import BoardDefinition
from hec.estimator.targets.charuco import CharucoBoard, CharucoDetector
from hec.estimator.targets.chessboard import ChessboardBoard, ChessboardDetector
from hec.estimator.targets.qr import DetectorSettings, QRDetector
from hec.estimator.targets.target import BoardDefinitionError, Target, TargetDetector
from hec.estimator.targets.tool_boards import hec_board_dict

# kind -> (board from its file's dict and source name, detector of such a board)
KINDS: dict[
    str, tuple[Callable[[dict, str], Target], Callable[[Target, DetectorSettings], TargetDetector]]
] = {
    "qr": (BoardDefinition.from_dict, QRDetector),
    "aprilgrid": (AprilGridBoard.from_dict, AprilGridDetector),
    "chessboard": (ChessboardBoard.from_dict, ChessboardDetector),
    "charuco": (CharucoBoard.from_dict, CharucoDetector),
}


def board_from_dict(d: dict, source: str = "board definition") -> Target:
    """Validate a board file's content and build the board of its kind; errors name ``source``
    and the field."""
    if d.get("format") != "hec-board" or d.get("version") != 1:
        raise BoardDefinitionError(
            f"{source}: expected 'format': 'hec-board' and 'version': 1, "
            f"got {d.get('format')!r} version {d.get('version')!r}"
        )
    kind = d.get("kind", "qr")
    if kind not in KINDS:
        raise BoardDefinitionError(f"{source}: field 'kind' should be one of {sorted(KINDS)}, got {kind!r}")
    return KINDS[kind][0](d, source)


def load_board(path: str | Path) -> Target:
    """Read a board file of any kind, JSON or YAML, hec's or another tool's (tool_boards); errors
    name the file and the field."""
    path = Path(path)
    read = read_yaml_object if path.suffix.lower() in (".yaml", ".yml") else read_json_object
    data = read(path, BoardDefinitionError, "board definition file not found")
    return board_from_dict(hec_board_dict(data, str(path)), source=str(path))


def save_board(board: Target, path: str | Path) -> Path:
    """Write a board file (through a temporary name, so no half-written file is left)."""
    return write_atomic(Path(path), json.dumps(board.to_dict(), indent=2) + "\n")


def find_board(name: str, base_dir: Path = Path(".")) -> Target:
    """A board named in models/boards/ (without .json), else a JSON path relative to base_dir."""
    named = models_dir() / "boards" / f"{name}.json"
    return load_board(named if named.is_file() else base_dir / name)


def detector_for(board: Target, settings: DetectorSettings | None = None) -> TargetDetector:
    """The detector of the board's kind. settings: the QR passes and floors (the other kinds
    take what applies to them)."""
    return KINDS[board.kind][1](board, settings or DetectorSettings())
