"""Chessboard and ChArUco kinds: board files, OpenCV's pattern and frame, IDs under any rotation,
partial views, and honest corner covariances."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from hec.estimator.io.board_file import board_from_dict, board_to_dict, find_board
from hec.estimator.targets.charuco import CharucoBoard
from hec.estimator.targets.chessboard import CLASSIC_FLAGS, ChessboardBoard
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.target import BoardDefinitionError
from tests.sheet_views import (
    PX_PER_M,
    apply,
    as_camera_sees,
    noisy_copies,
    quarter_turned,
    sheet_px,
    tilted_homography,
    warped_view,
)

BOARDS = ("chessboard_10x5", "charuco_10x5")


@pytest.mark.parametrize("name", BOARDS)
def test_board_files_read_back_and_number_corners_as_opencv(name: str) -> None:
    board = find_board(name)
    assert board.points_per_marker == 1 and not board.markers_placed_one_by_one
    assert board_from_dict(board_to_dict(board), "copy") == board
    assert board.marker_ids == list(range(36))  # 9 x 4 inner corners
    # ID 0 at the top-left inner corner, row-major to the right then down (OpenCV's ChArUco IDs).
    first, second, next_row = (board.marker_center(i) for i in (0, 1, 9))
    np.testing.assert_allclose(first[:2], [-0.15 + 0.03, 0.075 - 0.03])
    np.testing.assert_allclose(second - first, [0.03, 0.0, 0.0])
    np.testing.assert_allclose(next_row - first, [0.0, -0.03, 0.0])


def test_the_charuco_sheet_is_opencvs_pattern_and_its_corners_opencvs() -> None:
    board = find_board("charuco_10x5")
    assert isinstance(board, CharucoBoard)
    opencv = board.opencv_board()
    width_px, height_px = round(0.3 * PX_PER_M), round(0.15 * PX_PER_M)
    drawn = opencv.generateImage((width_px, height_px), marginSize=0, borderBits=1)
    top, left = round((0.22 - 0.15) / 2 * PX_PER_M), round((0.4 - 0.3) / 2 * PX_PER_M)
    np.testing.assert_array_equal(board.image(PX_PER_M)[top : top + height_px, left : left + width_px], drawn)
    # OpenCV's frame: origin at the grid's top-left, y down, z into the board (module doc of checker).
    p_opencv = np.asarray(opencv.getChessboardCorners())
    p_hec = board.all_corners()[:, 0]
    np.testing.assert_allclose(
        p_opencv, np.column_stack([p_hec[:, 0] + 0.15, 0.075 - p_hec[:, 1], -p_hec[:, 2]])
    )


@pytest.mark.parametrize(
    ("name", "change", "message"),
    [
        ("chessboard_10x5", {"squares_x": 9}, "one must be odd and the other even"),
        ("chessboard_10x5", {"squares_x": 1}, "field 'squares_x' should be an integer >= 2"),
        ("chessboard_10x5", {"square_m": 0.045}, "field 'size_m' [0.4, 0.22]: the 10x5 grid of 45 mm"),
        ("charuco_10x5", {"square_m": 0.038}, "with 1 square of white around it (456 x 266 mm) does not fit"),
        ("chessboard_10x5", {"name": ""}, "field 'name' should be a non-empty string"),
        ("charuco_10x5", {"marker_m": 0.03}, "field 'marker_m' 0.03 should be smaller than 'square_m'"),
        ("charuco_10x5", {"dictionary": "DICT_9X9"}, "field 'dictionary' should name an OpenCV ArUco"),
        (
            "charuco_10x5",
            {
                "dictionary": "DICT_4X4_50",
                "squares_x": 12,
                "squares_y": 9,
                "square_m": 0.015,
                "marker_m": 0.01,
            },
            "needs 54 markers; 'dictionary' DICT_4X4_50 has 50",
        ),
    ],
)
def test_bad_fields_are_named(name: str, change: dict, message: str) -> None:
    with pytest.raises(BoardDefinitionError, match="board.json") as error:
        board_from_dict(board_to_dict(find_board(name)) | change, "board.json")
    assert message in str(error.value)


@pytest.mark.parametrize("quarter_turns", [0, 1, 2, 3])
@pytest.mark.parametrize("name", BOARDS)
def test_ids_and_corners_under_any_rotation(name: str, quarter_turns: int) -> None:
    """Corners land where the board frame puts them, however the sheet is turned in the image (a
    half-turned reading of the grid would miss by whole squares)."""
    board = find_board(name)
    H = quarter_turned(tilted_homography(board, 0.7), quarter_turns)
    detections = detector_for(board).detect(warped_view(board, H, shape=(640, 640)))
    assert detections.problem is None
    assert [m.marker_id for m in detections.markers] == board.marker_ids
    for marker in detections.markers:
        expected = apply(H, sheet_px(board, board.marker_corners(marker.marker_id)))
        np.testing.assert_allclose(marker.corners_px, expected, atol=0.1)
        assert marker.corners_cov.shape == (2, 2) and marker.depth_region_px.shape == (4, 2)


def test_a_chessboard_seen_in_part_gives_a_problem_not_ids() -> None:
    board = find_board("chessboard_10x5")
    assert isinstance(board, ChessboardBoard)
    H = np.diag([1.5, 1.5, 1.0]) @ tilted_homography(board)  # the grid overflows the image
    detections = detector_for(board).detect(warped_view(board, H))
    assert detections.markers == []
    assert "a chessboard needs its whole grid in view" in detections.problem


def test_a_charuco_board_seen_in_part_gives_the_corners_inside() -> None:
    board = find_board("charuco_10x5")
    H = np.diag([1.5, 1.5, 1.0]) @ tilted_homography(board)
    detections = detector_for(board).detect(warped_view(board, H))
    assert 4 <= len(detections.markers) < len(board.marker_ids)
    for marker in detections.markers:
        expected = apply(H, sheet_px(board, board.marker_corners(marker.marker_id)))
        np.testing.assert_allclose(marker.corners_px, expected, atol=0.05)


@pytest.mark.parametrize("name", BOARDS)
def test_corner_covariance_matches_the_scatter_of_noisy_fits(name: str) -> None:
    """Over repeated noise draws the corners scatter as their covariance, less its floor, says (the
    QR fit's bounds, test_detect)."""
    board = find_board(name)
    detector = detector_for(board)
    floor_px = np.sqrt(
        detector.detect(warped_view(board, tilted_homography(board))).markers[0].center_cov[0, 0]
    )
    clean = as_camera_sees(warped_view(board, tilted_homography(board)))
    fits: dict[int, list] = {}
    for noisy in noisy_copies(clean, 6.0, 25, np.random.default_rng(5)):
        for m in detector.detect(noisy).markers:
            fits.setdefault(m.marker_id, []).append((m.center_px, m.center_cov))
    ratios = []
    for per_corner in fits.values():
        scatter = np.cov(np.array([c for c, _ in per_corner]).T)
        reported = np.mean([c for _, c in per_corner], axis=0) - floor_px**2 * np.eye(2)
        ratios.append(np.trace(scatter) / np.trace(reported))
    assert len(fits) == len(board.marker_ids)
    assert 0.6 <= float(np.median(ratios)) <= 1.6


def test_a_chessboard_only_the_classic_finder_finds_is_found_by_it() -> None:
    """A dim board lit from one side (contrast 0.15, light falling to 0.2 across the image):
    findChessboardCornersSB finds nothing, the classic finder does, and so does hec: every corner
    with its ID, within half a pixel (the light's ramp across a corner's template, which the fit's
    gain and offset do not model, costs up to 0.31 px at the grid's corners; a wrong ID would miss
    by a square, 25 px)."""
    board = find_board("chessboard_10x5")
    H = tilted_homography(board, 0.5)
    light = 1.0 - 0.8 * np.linspace(0.0, 1.0, 640)[None, :]
    dim = np.round((128 + 0.15 * (warped_view(board, H).astype(np.float64) - 128)) * light).astype(np.uint8)
    pattern = (board.squares_x - 1, board.squares_y - 1)
    assert not cv2.findChessboardCornersSB(dim, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE)[0]
    assert cv2.findChessboardCorners(dim, pattern, flags=CLASSIC_FLAGS)[0]
    detections = detector_for(board).detect(dim)
    assert detections.passes_run == ["sb", "classic"] and detections.problem is None
    assert [m.marker_id for m in detections.markers] == board.marker_ids
    for marker in detections.markers:
        assert marker.found_by == "classic"
        expected = apply(H, sheet_px(board, board.marker_corners(marker.marker_id)))
        np.testing.assert_allclose(marker.corners_px, expected, atol=0.5)


def test_a_chessboard_file_may_give_inner_corners_and_leave_out_the_sheet() -> None:
    """What a calibration tool states (inner corners, the square) is a board: squares one more each,
    the sheet the grid's own size (edge to edge) and a name from the grid; a sheet given still counts."""
    header = {"format": "hec-board", "version": 1, "kind": "chessboard"}
    board = board_from_dict(header | {"inner_corners": [9, 6], "square_m": 0.026}, "board.json")
    assert isinstance(board, ChessboardBoard)
    assert (board.squares_x, board.squares_y, board.name) == (10, 7, "chessboard_10x7")
    assert board.size_m == pytest.approx((0.26, 0.182))
    assert len(board.marker_ids) == 54
    assert board_from_dict(board_to_dict(board), "copy") == board
    sheet = board_from_dict(header | {"inner_corners": [9, 6], "square_m": 0.026, "size_m": [0.297, 0.21]})
    assert sheet.size_m == (0.297, 0.21)
    # An edge-to-edge sheet given as squares works too.
    squares = {"squares_x": 10, "squares_y": 7, "square_m": 0.026, "size_m": [0.26, 0.182], "name": "b"}
    assert board_from_dict(header | squares).squares_x == 10


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"inner_corners": [9]}, "field 'inner_corners' should be [x, y], the inner corners along each side"),
        ({"inner_corners": [9, 0]}, "field 'inner_corners' should be [x, y]"),
        ({"inner_corners": [9, 6], "squares_x": 9}, "field 'squares_x' 9 disagrees with 'inner_corners'"),
        ({"inner_corners": [9, 7]}, "field 'inner_corners' [9, 7] (10x8 squares): one must be odd"),
        ({"inner_corners": [9, 6], "size_m": [0.25, 0.2]}, "field 'size_m' [0.25, 0.2]: the 10x7 grid"),
        ({"inner_corners": [9, 6], "square_m": -1}, "field 'square_m' should be a number > 0"),
        ({}, "field 'squares_x' should be an integer >= 2, got None"),
    ],
)
def test_a_bad_inner_corners_file_is_refused_naming_the_file_and_field(change: dict, message: str) -> None:
    d = {"format": "hec-board", "version": 1, "kind": "chessboard", "square_m": 0.026} | change
    with pytest.raises(BoardDefinitionError, match="^board.json: ") as error:
        board_from_dict(d, "board.json")
    assert message in str(error.value) and "\n" not in str(error.value)
