"""A true-scale printable board from a board definition (PNG or PDF at a known DPI), and the
definition of what was printed (every marker's mask stated)."""

from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from hec.estimator.common.files import write_atomic
from hec.estimator.io.board_file import find_board, save_board
from hec.estimator.targets.target import Target

SCALE_BAR_M = 0.1
# The smallest printed feature (a QR module, a tag bit, a square) drawn narrower than this prints
# too coarse to keep its corners exact.
MIN_FEATURE_PX = 4
# No printer takes a sheet longer than this (A0 is 1.19 m; wide-format rolls are up to about 1.6 m
# wide), and a sheet of more pixels than this does not fit in memory (one byte a pixel).
MAX_SHEET_M = 2.0
MAX_SHEET_PIXELS = 1e9


# Lettering and bar: text this tall, this far from the sheet's bottom and side edges (inside most
# printers' unprintable border).
TEXT_HEIGHT_M = 0.002
EDGE_M = 0.005
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def printable_board(board: Target, dpi: float) -> np.ndarray:
    """(H, W) uint8 sheet at ``dpi`` with the board name and a 100 mm scale bar on one line in the
    bottom margin, below every marker and its margin (ValueError when that margin is too narrow)."""
    px_per_m = dpi / 0.0254
    _check_sheet_size(board, dpi)
    feature_px = board.feature_m * px_per_m
    if not feature_px >= MIN_FEATURE_PX:
        needed = MIN_FEATURE_PX / board.feature_m * 0.0254
        raise ValueError(
            f"at {dpi:g} dpi the smallest printed feature of {board.kind} board '{board.name}' is "
            f"{feature_px:.1f} px wide; give --dpi {needed:.0f} or more"
        )
    sheet = board.image(px_per_m)
    h, w = sheet.shape
    font_scale = TEXT_HEIGHT_M * px_per_m / cv2.getTextSize("0", _FONT, 1.0, 1)[0][1]
    thickness = max(1, round(font_scale * 1.5))
    edge = round(EDGE_M * px_per_m)
    label = f"{board.name}  {board.kind}  print at {dpi:g} dpi, 100% scale"
    (_, text_h), _ = cv2.getTextSize(label, _FONT, font_scale, thickness)
    lowest_m = float(board.all_corners()[..., 1].min()) - board.visible_margin_m
    free_px = (board.size_m[1] / 2 + lowest_m) * px_per_m
    if free_px < edge + text_h + 2 * thickness:
        raise ValueError(
            f"board '{board.name}' leaves {free_px / px_per_m * 1000:.1f} mm below its markers; the label "
            f"and scale bar need {(edge + text_h + 2 * thickness) / px_per_m * 1000:.1f} mm"
        )
    baseline = h - 1 - edge
    cv2.putText(sheet, label, (edge, baseline), _FONT, font_scale, 0, thickness, cv2.LINE_AA)
    bar = round(SCALE_BAR_M * px_per_m)
    x1 = w - edge - bar
    # cv2.rectangle includes both end pixels: bar pixels from x1 to x1 + bar - 1.
    cv2.rectangle(sheet, (x1, baseline - text_h), (x1 + bar - 1, baseline), 0, -1)
    (bar_label_w, _), _ = cv2.getTextSize("100 mm", _FONT, font_scale, thickness)
    cv2.putText(
        sheet, "100 mm", (x1 - bar_label_w - edge, baseline), _FONT, font_scale, 0, thickness, cv2.LINE_AA
    )
    return sheet


def _check_sheet_size(board: Target, dpi: float) -> None:
    """ValueError when the board's sheet is larger than any printer's, or too many pixels at dpi."""
    width_m, height_m = (float(v) for v in board.size_m)
    size = f"board '{board.name}' is {width_m:g} x {height_m:g} m (its size_m)"
    if not max(width_m, height_m) <= MAX_SHEET_M:
        raise ValueError(
            f"{size}: no printer takes a sheet over {MAX_SHEET_M:g} m; check size_m, which is in metres"
        )
    pixels = width_m * height_m * (dpi / 0.0254) ** 2
    if pixels > MAX_SHEET_PIXELS:
        most = 0.0254 * (MAX_SHEET_PIXELS / (width_m * height_m)) ** 0.5
        raise ValueError(
            f"{size}: at {dpi:g} dpi its sheet is {pixels / 1e9:.1f} gigapixels; give --dpi {most:.0f} "
            "or less"
        )


def save_printable_board(board: Target, path: str | Path, dpi: float = 300.0) -> Path:
    """Write the sheet as .png or .pdf with its DPI recorded, so it prints at true scale (through a
    temporary file and a rename: an interruption leaves no half-written sheet)."""
    path = Path(path)
    return write_atomic(path, _encoded_sheet(board, path, dpi))


def _encoded_sheet(board: Target, path: Path, dpi: float) -> bytes:
    """The sheet as the bytes of the PNG or PDF file path names."""
    if path.suffix.lower() not in (".png", ".pdf"):
        raise ValueError(f"{path}: choose a .png or .pdf file name")
    image = Image.fromarray(printable_board(board, dpi), mode="L")
    buffer = io.BytesIO()
    if path.suffix.lower() == ".pdf":
        image.save(buffer, "PDF", resolution=dpi)
    else:
        image.save(buffer, "PNG", dpi=(dpi, dpi))
    return buffer.getvalue()


def write_board(name: str, out: Path, dpi: float, definition: Path | None = None) -> list[str]:
    """`hec board`: the sheet of board ``name`` (models/boards/ or a file) at ``out``, and its
    definition with every marker's version, error correction and mask at ``definition``
    (default: ``out`` with .json). Returns the lines to print."""
    board = find_board(name)
    definition = definition or out.with_suffix(".json")
    source = Path(name) if Path(name).is_file() else None
    if source is not None and source.resolve() == definition.resolve():
        raise ValueError(f"{definition}: that is the board file being printed; choose --definition")
    sheet = _encoded_sheet(board, out, dpi)  # the slow part, before anything is written
    new_definition = not definition.exists()
    save_board(board.pinned(), definition)
    try:
        path = write_atomic(out, sheet)
    except BaseException:
        if new_definition:
            definition.unlink(missing_ok=True)  # no definition of a sheet that was not written
        raise
    stated = " (each marker's QR version, error correction and mask)" if board.kind == "qr" else ""
    return [
        f"wrote {path} at {dpi:g} dpi: print at 100% scale and check the 100 mm bar",
        f"wrote {definition}: the definition of this print{stated}; give it to the cell or scenario that "
        "uses this board",
    ]
