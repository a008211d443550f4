"""Every board in models/boards/, whatever its kind: printed at true scale with a 100 mm bar, and the
issue's acceptance on the rendered default trajectory (detection, corner accuracy and honesty, and the
calibrated mount)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hec.bench.targets import board_trial
from hec.cli import main
from hec.commands.printable import printable_board
from hec.estimator.common.models import models_dir
from hec.estimator.io.board_file import find_board, load_board
from hec.estimator.targets.kinds import detector_for

BOARDS = sorted(p.stem for p in (models_dir() / "boards").glob("*.json"))


def _longest_dark_run(row: np.ndarray) -> int:
    dark = np.concatenate([[False], row < 128, [False]])
    edges = np.flatnonzero(np.diff(dark.astype(int)))
    return int(np.max(edges[1::2] - edges[0::2])) if len(edges) else 0


@pytest.mark.parametrize("name", BOARDS)
@pytest.mark.parametrize("dpi", [150.0, 300.0])
def test_the_printed_sheet_is_true_scale_with_a_100_mm_bar(name: str, dpi: float) -> None:
    board = find_board(name)
    sheet = printable_board(board, dpi)
    px_per_m = dpi / 0.0254
    assert sheet.shape == (round(board.size_m[1] * px_per_m), round(board.size_m[0] * px_per_m))
    # Where the label and the bar are drawn: below every marker and its margin, else the sheet is the
    # board's own image at this scale, every marker where the board frame puts it.
    lowest_m = board.all_corners()[..., 1].min() - board.visible_margin_m
    first_row = int(np.ceil((board.size_m[1] / 2 - lowest_m) * px_per_m))
    drawn = np.flatnonzero(np.any(sheet != board.image(px_per_m), axis=1))
    assert len(drawn) and drawn.min() >= first_row
    # The bar: the longest dark run along a row of that bottom margin.
    bar_mm = max(_longest_dark_run(row) for row in sheet[first_row:]) / px_per_m * 1000.0
    assert abs(bar_mm - 100.0) <= 25.4 / dpi, bar_mm  # within a pixel


@pytest.mark.parametrize("name", ["aprilgrid_6x3", "charuco_10x5", "chessboard_10x5"])
def test_hec_board_prints_every_kind_with_its_dpi(name: str, tmp_path: Path, capsys) -> None:
    assert main(["board", "--board", name, "--out", str(tmp_path / "sheet.png"), "--dpi", "150"]) == 0
    assert "QR version" not in capsys.readouterr().out
    with Image.open(tmp_path / "sheet.png") as png:
        assert png.info["dpi"] == pytest.approx((150, 150), abs=0.02)  # PNG stores dots per metre
        np.testing.assert_array_equal(np.asarray(png), printable_board(find_board(name), 150.0))
    assert load_board(tmp_path / "sheet.json") == find_board(name)


@pytest.mark.parametrize("name", BOARDS)
def test_rendered_default_trajectory_meets_the_acceptance(name: str) -> None:
    """The targets' figures per kind, one seed: >= 99 % of fully visible points found with the right ID,
    corner RMS <= 0.1 px, normalised corner error in [0.7, 1.5], ekf within 0.5 mm and 0.05 degrees."""
    trial = board_trial(name, seed=0)
    assert trial["detected_visible"] >= 0.99 * trial["visible_markers"] > 0
    assert trial["wrong_id"] == 0
    assert trial["corner_rms_px"] <= 0.1
    assert 0.7 <= trial["corner_nees"] <= 1.5
    error_mm, error_deg, _ = trial["ekf"]
    assert error_mm <= 0.5 and error_deg <= 0.05
    # The corner-noise learning starts from the floors this kind's covariances hold, not the QR codes'.
    detector = detector_for(find_board(name))
    assert trial["corner_noise"].constant_px == detector.corner_floor_px
    assert trial["corner_noise"].center_constant_px == detector.center_floor_px


def test_the_target_sweep_compares_every_board_file() -> None:
    from hec.sweep.config import load_config

    config = load_config(models_dir() / "sweeps" / "targets.toml")
    assert sorted(config.grid["board"]) == BOARDS
