"""QR codes tiled as a code generator prints them: the layout rule follows the decoders (2 modules of
white around each code, shared between neighbours), its refusals give the spacing needed, and the
corner fit leaves out what is not paper in a code's quiet zone (qr_18_tight: 2-module gaps). The
rendered default trajectory on that board is checked with every board file in test_target_kinds."""

from __future__ import annotations

import numpy as np
import pytest

from hec.estimator.io.board_file import board_from_dict, find_board
from hec.estimator.targets.board import QUIET_ZONE_MODULES
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.qr_fit import fit_marker
from hec.estimator.targets.target import BoardDefinitionError
from tests.sheet_views import apply, noisy_copies, sheet_px, tilted_homography, warped_view

MODULE_M = 0.003  # 63 mm version-1 codes


def _row_of_codes(gap_modules: float, edge_modules: float) -> dict:
    """Three 63 mm codes in a row, gap_modules apart and edge_modules from the sheet's edges."""
    side, gap, edge = 21 * MODULE_M, gap_modules * MODULE_M, edge_modules * MODULE_M
    pitch = side + gap
    return {
        "format": "hec-board",
        "version": 1,
        "name": "row",
        "size_m": [3 * side + 2 * gap + 2 * edge, side + 2 * edge],
        "marker_size_m": side,
        "qr_version": 1,
        "qr_error_correction": "M",
        "payload_prefix": "ROW/",
        "markers": [{"id": i, "center_m": [(i - 1) * pitch, 0.0]} for i in range(3)],
    }


def test_codes_two_modules_apart_and_from_the_edge_are_a_valid_board() -> None:
    assert QUIET_ZONE_MODULES == 2
    board = board_from_dict(_row_of_codes(2.0, 2.0), "row.json")
    assert board.visible_margin_m == pytest.approx(2 * MODULE_M)
    assert find_board("qr_18_tight").marker_ids == list(range(18))


@pytest.mark.parametrize(
    ("gap_modules", "edge_modules", "message"),
    [
        (
            1.5,
            2.0,
            "markers 0 and 1 are 4.5 mm apart; the detector needs 2 modules (6.0 mm) of white between codes",
        ),
        (-1.0, 2.0, "markers 0 and 1 overlap; the detector needs 2 modules (6.0 mm)"),
        (
            2.0,
            1.0,
            "marker 0 is 3.0 mm from the sheet's edge; the detector needs 2 modules (6.0 mm) of white",
        ),
        (
            2.0,
            -1.0,
            "marker 0 leaves the sheet; the detector needs 2 modules (6.0 mm) of white around each code",
        ),
    ],
)
def test_a_layout_the_decoders_cannot_read_names_the_spacing_needed(
    gap_modules: float, edge_modules: float, message: str
) -> None:
    with pytest.raises(BoardDefinitionError, match="row.json: ") as err:
        board_from_dict(_row_of_codes(gap_modules, edge_modules), "row.json")
    assert message in str(err.value)


@pytest.mark.parametrize("scale", [0.75, 0.55])
def test_codes_two_modules_apart_are_found_and_fitted_as_finely_as_lone_ones(scale: float) -> None:
    """Every code of qr_18_tight in a tilted, slightly noisy view, its corners within 0.03 px RMS (a lone
    code's fit reaches about 0.012 px here); fitted against white paper all round, the neighbours'
    modules inside the quiet zone pull them about 0.15 px."""
    board = find_board("qr_18_tight")
    H = tilted_homography(board, scale)
    clean = warped_view(board, H)
    image = next(noisy_copies(clean.astype(np.float64), 1.0, 1, np.random.default_rng(0)))
    detections = detector_for(board).detect(image)
    assert sorted(m.marker_id for m in detections.markers) == board.marker_ids
    masked, plain = [], []
    for marker in detections.markers:
        truth = apply(H, sheet_px(board, board.marker_corners(marker.marker_id)))
        masked.append(marker.corners_px - truth)
        lone = fit_marker(image, marker.raw_corners_px, board.module_matrix(marker.marker_id))
        plain.append(lone.corners_px - truth)
    rms = float(np.sqrt(np.mean(np.square(masked)) * 2))
    rms_plain = float(np.sqrt(np.mean(np.square(plain)) * 2))
    assert rms <= 0.03, rms
    assert rms_plain >= 0.1, rms_plain
