"""Board files other calibration tools write, read as hec board files.

- Kalibr's target YAML: ``target_type: aprilgrid`` (``tagCols``, ``tagRows``, ``tagSize`` edge to
  edge in metres, ``tagSpacing`` gap / tag) becomes an AprilGrid with Kalibr's corner squares;
  ``target_type: checkerboard`` (``targetCols``, ``targetRows`` inner corners, ``rowSpacingMeters``,
  ``colSpacingMeters`` the square) a chessboard. Kalibr's circle grids have no hec kind.
- OpenCV's ChArUco parameters, as ``cv2.aruco.CharucoBoard`` takes them (YAML or JSON):
  ``squaresX``, ``squaresY``, ``squareLength``, ``markerLength`` (metres) and ``dictionary`` (a
  name such as ``DICT_5X5_100`` or OpenCV's number for it); snake_case names are read too.

The sheet is the pattern and the white around it the corner fit needs (no file states the paper).
"""

from __future__ import annotations

import cv2

from hec.estimator.targets.target import BoardDefinitionError

# hec's ChArUco field -> the names OpenCV's parameters go by
_CHARUCO_NAMES = {
    "squares_x": ("squaresX", "squares_x"),
    "squares_y": ("squaresY", "squares_y"),
    "square_m": ("squareLength", "square_length"),
    "marker_m": ("markerLength", "marker_length"),
    "dictionary": ("dictionary", "dictionary_id"),
}
# A length above this in a file that should give metres was written in pixels or millimetres.
_LONGEST_SQUARE_M = 1.0


def hec_board_dict(data: dict, source: str) -> dict:
    """The hec board file content for a file's content: a hec board file as it is, Kalibr's target
    YAML and OpenCV's ChArUco parameters translated (module doc); errors name source and the field."""
    if "format" in data:
        return data
    if "target_type" in data:
        return _kalibr(data, source)
    if any(name in data for name in _CHARUCO_NAMES["squares_x"]):
        return _opencv_charuco(data, source)
    return data  # board_from_dict names what is missing


def _kalibr(data: dict, source: str) -> dict:
    kind = data["target_type"]
    if kind == "aprilgrid":
        fields = {
            "tag_cols": "tagCols",
            "tag_rows": "tagRows",
            "tag_size_m": "tagSize",
            "tag_spacing": "tagSpacing",
        }
        board = {ours: _field(data, theirs, source) for ours, theirs in fields.items()}
        board["tag_size_m"] = _metres(board["tag_size_m"], "tagSize", source)
        return _header("aprilgrid") | board | {"corner_squares": True}
    if kind == "checkerboard":
        row, col = (_field(data, key, source) for key in ("rowSpacingMeters", "colSpacingMeters"))
        if row != col:
            raise BoardDefinitionError(
                f"{source}: 'rowSpacingMeters' {row} and 'colSpacingMeters' {col} differ; hec's chessboard "
                "has square squares"
            )
        inner = [_field(data, "targetCols", source), _field(data, "targetRows", source)]
        return _header("chessboard") | {
            "inner_corners": inner,
            "square_m": _metres(row, "rowSpacingMeters", source),
        }
    raise BoardDefinitionError(
        f"{source}: Kalibr 'target_type' {kind!r}: hec reads 'aprilgrid' and 'checkerboard' "
        "(it has no circle grids)"
    )


def _opencv_charuco(data: dict, source: str) -> dict:
    board = {}
    for ours, names in _CHARUCO_NAMES.items():
        given = next((name for name in names if name in data), None)
        if given is None:
            raise BoardDefinitionError(f"{source}: OpenCV ChArUco parameters without '{names[0]}'")
        board[ours] = data[given]
        if ours in ("square_m", "marker_m"):
            board[ours] = _metres(data[given], given, source)
    if data.get("legacy") or data.get("legacyPattern"):
        raise BoardDefinitionError(
            f"{source}: a legacy ChArUco pattern (OpenCV before 4.6, setLegacyPattern) is not read; hec "
            "reads OpenCV's current pattern"
        )
    board["dictionary"] = _dictionary_name(board["dictionary"], source)
    return _header("charuco") | board


def _header(kind: str) -> dict:
    return {"format": "hec-board", "version": 1, "kind": kind}


def _field(data: dict, key: str, source: str) -> object:
    if key not in data:
        raise BoardDefinitionError(f"{source}: Kalibr target without '{key}'")
    return data[key]


def _metres(value: object, key: str, source: str) -> object:
    """value, refused when it is a number too long for metres; other problems are the kind's to name."""
    if isinstance(value, int | float) and not isinstance(value, bool) and value > _LONGEST_SQUARE_M:
        raise BoardDefinitionError(
            f"{source}: '{key}' {value} is no length in metres (pixels or millimetres?); hec needs metres"
        )
    return value


def _dictionary_name(dictionary: object, source: str) -> object:
    """An OpenCV ArUco dictionary's name from its name or number (cv2.aruco.DICT_*)."""
    if not isinstance(dictionary, int) or isinstance(dictionary, bool):
        return dictionary
    names = [
        name for name in dir(cv2.aruco) if name.startswith("DICT_") and getattr(cv2.aruco, name) == dictionary
    ]
    if not names:
        raise BoardDefinitionError(
            f"{source}: 'dictionary' {dictionary} is no OpenCV ArUco dictionary number"
        )
    return names[0]
