"""Drawing a target's sheet: blocks of square cells (QR modules, tag bits, checker squares) on paper.

Every kind draws its ``image()`` here, so the simulator's texture and the printed sheet of every
kind are area-averaged the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CellBlock:
    """A grid of square cells on the sheet. dark: (n_rows, n_cols) bool, row 0 at the top (largest
    y); left_m, top_m: board-frame x of its left edge and y of its top edge; cell_m: cell side."""

    dark: np.ndarray
    left_m: float
    top_m: float
    cell_m: float


def draw_sheet(
    size_m: tuple[float, float],
    blocks: list[CellBlock],
    px_per_m: float,
    supersample: int = 4,
    center_m: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """A size_m rectangle of the sheet centred at center_m (board frame; the whole sheet by default)
    as an (H, W) uint8 image, white paper, black cells.

    Row 0 is the rectangle's top edge (largest y), column 0 its left edge. It spans exactly the
    image: a pixel is size_m[0] / W wide. Edges that fall inside a pixel are area-averaged over
    supersample^2 samples.
    """
    w_m, h_m = size_m
    W, H = round(w_m * px_per_m), round(h_m * px_per_m)
    ss = supersample
    x = center_m[0] - w_m / 2 + (np.arange(W * ss) + 0.5) * (w_m / (W * ss))
    y = center_m[1] + h_m / 2 - (np.arange(H * ss) + 0.5) * (h_m / (H * ss))
    dark = np.zeros((H * ss, W * ss), dtype=bool)
    for block in blocks:
        n_rows, n_cols = block.dark.shape
        col = np.floor((x - block.left_m) / block.cell_m).astype(int)
        row = np.floor((block.top_m - y) / block.cell_m).astype(int)
        rr = np.nonzero((row >= 0) & (row < n_rows))[0]
        cc = np.nonzero((col >= 0) & (col < n_cols))[0]
        dark[np.ix_(rr, cc)] |= block.dark[np.ix_(row[rr], col[cc])]
    coverage = dark.reshape(H, ss, W, ss).mean(axis=(1, 3))
    return np.round(255.0 * (1.0 - coverage)).astype(np.uint8)
