"""Board files of every target kind: reading, writing and finding them.

A board file (JSON, format hec-board version 1) names its ``kind``; a file without one is a
board of QR codes (qr_board_file), as every board file before the other kinds (grid_board_files).
Kalibr's target YAML and OpenCV's ChArUco parameters are read as well (tool_boards).
"""

from __future__ import annotations

import json
from pathlib import Path

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_json_object, read_yaml_object
from hec.estimator.common.models import models_dir
from hec.estimator.io.grid_board_files import AprilGridFile, CharucoFile, ChessboardFile
from hec.estimator.io.qr_board_file import QRBoardFile
from hec.estimator.io.schema import validated
from hec.estimator.io.tool_boards import hec_board_dict
from hec.estimator.targets.target import BoardDefinitionError, Target

# kind -> the schema of its board file
BOARD_FILES: dict[str, type[QRBoardFile | AprilGridFile | ChessboardFile | CharucoFile]] = {
    "qr": QRBoardFile,
    "aprilgrid": AprilGridFile,
    "chessboard": ChessboardFile,
    "charuco": CharucoFile,
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
    if kind not in BOARD_FILES:
        raise BoardDefinitionError(
            f"{source}: field 'kind' should be one of {sorted(BOARD_FILES)}, got {kind!r}"
        )
    return validated(BOARD_FILES[kind], d, source, BoardDefinitionError).board()


def board_to_dict(board: Target) -> dict:
    """The board file's content of a board (format hec-board version 1; board_from_dict reads it
    back to an equal board). The board is written as it is, unchecked: a sheet as printed, with
    markers off their places, is described too; reading it checks it."""
    data = BOARD_FILES[board.kind].of(board).model_dump(mode="json", exclude_none=True)
    if board.kind == "aprilgrid" and not data["corner_squares"]:
        del data["corner_squares"]  # as files without the corner squares always read
    return data


def load_board(path: str | Path) -> Target:
    """Read a board file of any kind, JSON or YAML, hec's or another tool's (tool_boards); errors
    name the file and the field."""
    path = Path(path)
    read = read_yaml_object if path.suffix.lower() in (".yaml", ".yml") else read_json_object
    data = read(path, BoardDefinitionError, "board definition file not found")
    return board_from_dict(hec_board_dict(data, str(path)), source=str(path))


def save_board(board: Target, path: str | Path) -> Path:
    """Write a board file (through a temporary name, so no half-written file is left)."""
    return write_atomic(Path(path), json.dumps(board_to_dict(board), indent=2) + "\n")


def find_board(name: str, base_dir: Path = Path(".")) -> Target:
    """A board named in models/boards/ (without .json), else a JSON path relative to base_dir."""
    named = models_dir() / "boards" / f"{name}.json"
    return load_board(named if named.is_file() else base_dir / name)
