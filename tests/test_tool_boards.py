"""Board files other tools write, read directly: Kalibr's target YAML (aprilgrid, checkerboard) and
OpenCV's ChArUco parameters; the pattern each gives is the tool's own, and bad files name the field."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from hec.estimator.io.board_file import find_board, load_board
from hec.estimator.targets.aprilgrid import AprilGridBoard
from hec.estimator.targets.charuco import CharucoBoard
from hec.estimator.targets.chessboard import ChessboardBoard
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.target import BoardDefinitionError
from tests.sheet_views import PX_PER_M, tilted_homography, warped_view

KALIBR_APRILGRID = """\
target_type: 'aprilgrid' #gridtype
tagCols: 6               #number of apriltags
tagRows: 3               #number of apriltags
tagSize: 0.042           #size of apriltag, edge to edge [m]
tagSpacing: 0.3          #ratio of space between tags to tagSize
"""
KALIBR_CHECKERBOARD = """\
target_type: 'checkerboard' #gridtype
targetCols: 9               #number of internal chessboard corners
targetRows: 4               #number of internal chessboard corners
rowSpacingMeters: 0.03      #size of one chessboard square [m]
colSpacingMeters: 0.03      #size of one chessboard square [m]
"""
OPENCV_CHARUCO = """\
squaresX: 10
squaresY: 5
squareLength: 0.03
markerLength: 0.021
dictionary: 5
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_kalibrs_aprilgrid_yaml_is_kalibrs_print_and_is_detected(tmp_path: Path) -> None:
    board = load_board(_write(tmp_path, "aprilgrid.yaml", KALIBR_APRILGRID))
    assert isinstance(board, AprilGridBoard) and board.corner_squares and board.name == "aprilgrid_6x3"
    ours = find_board("aprilgrid_6x3_kalibr")
    assert board.grid_size_m == ours.grid_size_m and board.marker_ids == ours.marker_ids
    np.testing.assert_allclose(board.all_corners(), ours.all_corners(), atol=1e-12)  # both centred
    # The sheet: the grid and the white the corner fit needs, nothing more.
    assert board.size_m == pytest.approx(tuple(s + 2 * board.visible_margin_m for s in board.grid_size_m))
    found = detector_for(board).detect(warped_view(board, tilted_homography(board)))
    assert sorted(m.marker_id for m in found.markers) == board.marker_ids


def test_kalibrs_checkerboard_yaml_is_a_chessboard_of_its_inner_corners(tmp_path: Path) -> None:
    board = load_board(_write(tmp_path, "checkerboard.yml", KALIBR_CHECKERBOARD))
    assert isinstance(board, ChessboardBoard)
    assert (board.squares_x, board.squares_y, board.square_m) == (10, 5, 0.03)
    assert board.name == "chessboard_10x5" and board.size_m == pytest.approx((0.3, 0.15))


def test_opencv_charuco_parameters_give_opencvs_pattern(tmp_path: Path) -> None:
    board = load_board(_write(tmp_path, "charuco.yaml", OPENCV_CHARUCO))
    assert isinstance(board, CharucoBoard) and board.dictionary == "DICT_5X5_100"  # OpenCV's number 5
    assert board.name == "charuco_10x5" and board.size_m == pytest.approx((0.36, 0.21))  # a square around
    opencv = cv2.aruco.CharucoBoard((10, 5), 0.03, 0.021, cv2.aruco.getPredefinedDictionary(5))
    width_px, height_px = round(0.3 * PX_PER_M), round(0.15 * PX_PER_M)
    drawn = opencv.generateImage((width_px, height_px), marginSize=0, borderBits=1)
    margin_px = round(0.03 * PX_PER_M)
    sheet = board.image(PX_PER_M)
    np.testing.assert_array_equal(
        sheet[margin_px : margin_px + height_px, margin_px : margin_px + width_px], drawn
    )
    as_json = _write(
        tmp_path,
        "charuco.json",
        '{"squares_x": 10, "squares_y": 5, "square_length": 0.03, '
        '"marker_length": 0.021, "dictionary": "DICT_5X5_100"}',
    )
    assert load_board(as_json) == board


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("a.yaml", KALIBR_APRILGRID.replace("tagSize", "size"), "a.yaml: Kalibr target without 'tagSize'"),
        ("a.yaml", KALIBR_APRILGRID.replace("0.042", "42"), "'tagSize' 42 is no length in metres"),
        (
            "c.yaml",
            "target_type: 'circlegrid'\n",
            "hec reads 'aprilgrid' and 'checkerboard' (it has no circle",
        ),
        (
            "c.yaml",
            KALIBR_CHECKERBOARD.replace("colSpacingMeters: 0.03", "colSpacingMeters: 0.02"),
            "'rowSpacingMeters' 0.03 and 'colSpacingMeters' 0.02 differ",
        ),
        ("o.yaml", OPENCV_CHARUCO.replace("0.03", "200"), "'squareLength' 200 is no length in metres"),
        ("o.yaml", OPENCV_CHARUCO.replace("dictionary: 5", "dictionary: 99"), "'dictionary' 99 is no OpenCV"),
        ("o.yaml", OPENCV_CHARUCO.replace("markerLength", "marker"), "without 'markerLength'"),
        ("o.yaml", OPENCV_CHARUCO + "legacyPattern: true\n", "a legacy ChArUco pattern"),
        ("b.yaml", "squaresX: [10\n", "b.yaml: not valid YAML"),
        ("b.yaml", "- 10\n- 5\n", "b.yaml: expected a YAML mapping"),
    ],
)
def test_bad_tool_files_name_the_file_and_the_field(
    tmp_path: Path, name: str, text: str, message: str
) -> None:
    with pytest.raises(BoardDefinitionError) as err:
        load_board(_write(tmp_path, name, text))
    assert message in str(err.value)
