"""Chessboards as users print them, rendered by MuJoCo on the default trajectory: with the whole grid
in view, every inner corner is found and lands where the truth puts it, whether the sheet has a white
margin or ends at the grid (the outer corners' fit compares only the grid's own squares)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import hec.sim  # noqa: F401  (selects the GL backend before mujoco loads)
from hec.bench.targets import board_scenario
from hec.estimator.geometry.camera import project_points
from hec.estimator.io.board_file import find_board
from hec.estimator.observe.grading import true_T_cam_board
from hec.estimator.targets.kinds import detector_for
from hec.sim.simulate import simulate_in_memory

# The grid of chessboard_10x5 on a sheet cut at the grid: no margin at all.
EDGE_TO_EDGE = {
    "format": "hec-board",
    "version": 1,
    "kind": "chessboard",
    "name": "chessboard_10x5_edge_to_edge",
    "size_m": [0.3, 0.15],
    "squares_x": 10,
    "squares_y": 5,
    "square_m": 0.03,
}


@pytest.mark.parametrize("sheet", ["chessboard_10x5", "edge_to_edge"])
def test_every_corner_is_found_in_rendered_views_of_the_whole_grid(sheet: str, tmp_path: Path) -> None:
    if sheet == "edge_to_edge":
        sheet = str(tmp_path / "edge_to_edge.json")
        Path(sheet).write_text(json.dumps(EDGE_TO_EDGE))
    board = find_board(sheet)
    dataset = simulate_in_memory(board_scenario(sheet), seed=0, name=sheet)
    detector = detector_for(board)
    width, height = dataset.intrinsics.width, dataset.intrinsics.height
    # The grid's outline (its outer corners): in view, the grid is whole in the image.
    half_w, half_h = board.squares_x * board.square_m / 2, board.squares_y * board.square_m / 2
    outline = np.array(
        [[-half_w, half_h, 0.0], [half_w, half_h, 0.0], [half_w, -half_h, 0.0], [-half_w, -half_h, 0.0]]
    )
    whole = complete = 0
    errors = []
    for i in range(len(dataset)):
        T_cam_board = true_T_cam_board(dataset.ground_truth, i)
        uv = project_points(T_cam_board, outline, dataset.intrinsics.K)
        if not (np.all(uv >= 0) and np.all(uv[:, 0] <= width - 1) and np.all(uv[:, 1] <= height - 1)):
            continue
        whole += 1
        markers = detector.detect(dataset.frame(i).rgb).markers
        complete += [m.marker_id for m in markers] == board.marker_ids
        for m in markers:
            truth = project_points(T_cam_board, board.marker_corners(m.marker_id), dataset.intrinsics.K)
            errors.append(np.linalg.norm(m.corners_px - truth))
    assert whole >= 15
    assert complete >= 0.99 * whole, f"every corner found in {complete} of {whole} views of the whole grid"
    # Outer corners are as good as inner ones: no corner off by more than a tenth of a pixel.
    assert max(errors) < 0.1, max(errors)
