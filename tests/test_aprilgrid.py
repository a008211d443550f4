"""The AprilGrid kind: Kalibr's layout and IDs, the board frame, detection under any rotation and in
partial views, honest corner covariances, and board files with bad fields named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.io.board_file import board_from_dict, board_to_dict, find_board, load_board
from hec.estimator.targets.aprilgrid import TAG_CORNER_FLOOR_PX, AprilGridBoard, AprilGridDetector, tag_cells
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


@pytest.fixture(scope="module")
def board() -> AprilGridBoard:
    loaded = find_board("aprilgrid_6x3")
    assert isinstance(loaded, AprilGridBoard)
    return loaded


def test_board_file_reads_back_and_lays_out_kalibrs_grid(board: AprilGridBoard, tmp_path: Path) -> None:
    assert board.kind == "aprilgrid" and board.points_per_marker == 4
    assert board_from_dict(board_to_dict(board), "copy") == board
    assert board.marker_ids == list(range(18))
    # Kalibr: tag 0 at the bottom-left, IDs along x, then up; corners BL, BR, TR, TL.
    c0, c5, c6 = (board.marker_center(i) for i in (0, 5, 6))
    assert c0[0] < 0 and c0[1] < 0 and c5[0] > 0 and np.isclose(c5[1], c0[1]) and c6[1] > c0[1]
    corners = board.marker_corners(0)[:, :2]
    np.testing.assert_allclose(np.sign(corners - c0[:2]), [[-1, -1], [1, -1], [1, 1], [-1, 1]])
    pitch = board.tag_size_m * (1 + board.tag_spacing)
    np.testing.assert_allclose(c5[0] - c0[0], 5 * pitch)
    path = tmp_path / "grid.json"
    path.write_text(json.dumps(board_to_dict(board)))
    assert load_board(path) == board


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"tag_cols": 0}, "field 'tag_cols' should be an integer >= 1, got 0"),
        ({"tag_rows": 2.5}, "field 'tag_rows' should be an integer >= 1"),
        ({"tag_size_m": -0.04}, "field 'tag_size_m' should be a number > 0"),
        ({"tag_spacing": "wide"}, "field 'tag_spacing' should be a number > 0"),
        ({"first_id": 580}, "tag36h11 has IDs 0-586"),
        ({"tag_cols": 9}, "does not fit on the sheet"),
        ({"tag_spacing": 0.1}, "the corner fit needs"),
        ({"size_m": [0.4]}, "field 'size_m' should be [width, height] > 0"),
        ({"corner_squares": "yes"}, "field 'corner_squares' must be true or false"),
        ({"corner_squares": True, "size_m": [0.335, 0.22]}, "does not fit on the sheet"),  # fits without them
    ],
)
def test_bad_fields_are_named(board: AprilGridBoard, change: dict, message: str) -> None:
    with pytest.raises(BoardDefinitionError, match="grid.json") as error:
        board_from_dict(board_to_dict(board) | change, "grid.json")
    assert message in str(error.value)


def test_the_sheet_draws_each_tag_where_the_board_says(board: AprilGridBoard) -> None:
    """Each tag's cells in board.image() are OpenCV's tag of that ID, upright (y up = image top)."""
    sheet = board.image(PX_PER_M, supersample=1)
    cells = 6 + 2 * board.border_bits
    for tag_id in (0, 7, 17):
        top_left = sheet_px(board, board.marker_corners(tag_id)[3:4])[0] + 0.5
        cell_px = board.feature_m * PX_PER_M
        rows = np.round(top_left[1] + (np.arange(cells) + 0.5) * cell_px).astype(int)
        cols = np.round(top_left[0] + (np.arange(cells) + 0.5) * cell_px).astype(int)
        np.testing.assert_array_equal(sheet[np.ix_(rows, cols)] < 128, tag_cells(tag_id, board.border_bits))


@pytest.mark.parametrize("quarter_turns", [0, 1, 2, 3])
def test_ids_and_corners_under_any_rotation(board: AprilGridBoard, quarter_turns: int) -> None:
    """Corners land where the board frame puts them, whichever way the sheet is turned in the image
    (a flipped frame or a wrong corner order would miss by tens of pixels)."""
    H = quarter_turned(tilted_homography(board, 0.7), quarter_turns)
    image = warped_view(board, H, shape=(640, 640))
    detections = detector_for(board).detect(image)
    assert [m.marker_id for m in detections.markers] == board.marker_ids
    for marker in detections.markers:
        expected = apply(H, sheet_px(board, board.marker_corners(marker.marker_id)))
        np.testing.assert_allclose(marker.corners_px, expected, atol=0.1)
        assert marker.corners_cov.shape == (8, 8)


def test_a_partial_view_gives_the_tags_inside_it(board: AprilGridBoard) -> None:
    H = np.diag([1.6, 1.6, 1.0]) @ tilted_homography(board, 0.75)  # the sheet overflows the image
    image = warped_view(board, H)
    detections = detector_for(board).detect(image)
    found = {m.marker_id for m in detections.markers}
    assert 3 <= len(found) < len(board.marker_ids)
    for marker in detections.markers:
        expected = apply(H, sheet_px(board, board.marker_corners(marker.marker_id)))
        assert np.all((expected >= 0) & (expected <= [639, 479]))
        np.testing.assert_allclose(marker.corners_px, expected, atol=0.1)


def test_tags_of_another_grid_are_rejected_by_id(board: AprilGridBoard) -> None:
    other = board_from_dict(board_to_dict(board) | {"first_id": 100}, "other")
    image = warped_view(board, tilted_homography(board))
    detections = AprilGridDetector(other).detect(image)
    assert detections.markers == []
    reasons = sorted(r.reason for r in detections.rejected)
    assert reasons == sorted(f"tag {i} is not on board 'aprilgrid_6x3'" for i in board.marker_ids)


def test_corner_covariance_matches_the_scatter_of_noisy_fits(board: AprilGridBoard) -> None:
    """Over repeated noise draws, the corners scatter as their covariance says, less its floor (the
    error noise does not explain, the same in every draw)."""
    H = tilted_homography(board)
    clean = as_camera_sees(warped_view(board, H))
    detector = AprilGridDetector(board)
    rng = np.random.default_rng(4)
    fits: dict[int, list] = {}
    for noisy in noisy_copies(clean, 6.0, 25, rng):
        for m in detector.detect(noisy).markers:
            fits.setdefault(m.marker_id, []).append((m.corners_px.ravel(), m.corners_cov))
    ratios = []
    for per_tag in fits.values():
        corners = np.array([c for c, _ in per_tag])
        scatter = np.cov(corners.T)
        reported = np.mean([c for _, c in per_tag], axis=0) - TAG_CORNER_FLOOR_PX**2 * np.eye(8)
        ratios.append(np.trace(scatter) / np.trace(reported))
    assert len(fits) == len(board.marker_ids)
    assert 0.6 <= float(np.median(ratios)) <= 1.6  # the QR fit's bounds (test_detect)


@pytest.fixture(scope="module")
def kalibr_print(board: AprilGridBoard) -> AprilGridBoard:
    """The same grid as Kalibr prints it, with its corner squares."""
    printed = board_from_dict(board_to_dict(board) | {"corner_squares": True}, "kalibr")
    assert isinstance(printed, AprilGridBoard) and board_to_dict(printed)["corner_squares"] is True
    return printed


def test_kalibrs_corner_squares_touch_each_tag_corner_from_outside(kalibr_print: AprilGridBoard) -> None:
    sheet = kalibr_print.image(PX_PER_M, supersample=1)
    g = kalibr_print.gap_m
    for tag_id in (0, 7, 17):
        for corner in kalibr_print.marker_corners(tag_id):
            outward = np.sign(corner[:2] - kalibr_print.marker_center(tag_id)[:2])
            inside_square = corner[:2] + outward * g / 2  # diagonally outside the corner
            along_side = corner[:2] + outward * [g / 2, -g / 2]  # beside the tag's edge: paper
            u, v = (
                np.round(sheet_px(kalibr_print, np.array([[*inside_square, 0], [*along_side, 0]])))
                .astype(int)
                .T
            )
            assert sheet[v[0], u[0]] < 64 and sheet[v[1], u[1]] > 192


@pytest.mark.parametrize("quarter_turns", [0, 1, 2, 3])
def test_a_kalibr_print_is_fitted_with_its_squares(
    board: AprilGridBoard, kalibr_print: AprilGridBoard, quarter_turns: int
) -> None:
    """Every tag and its corners on a Kalibr print; the fit's template has the squares: without them
    the squares pull the corners most of a pixel off."""
    H = quarter_turned(tilted_homography(kalibr_print, 0.7), quarter_turns)
    image = warped_view(kalibr_print, H, shape=(640, 640))
    errors = {}
    for name, detector in (("squares", AprilGridDetector(kalibr_print)), ("plain", AprilGridDetector(board))):
        detections = detector.detect(image)
        assert [m.marker_id for m in detections.markers] == kalibr_print.marker_ids
        errors[name] = np.array(
            [
                m.corners_px - apply(H, sheet_px(kalibr_print, kalibr_print.marker_corners(m.marker_id)))
                for m in detections.markers
            ]
        )
    assert np.abs(errors["squares"]).max() < 0.06
    assert np.sqrt(np.mean(errors["plain"] ** 2)) > 0.4
