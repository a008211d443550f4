"""Pictures of what was simulated: the cell seen from outside, and a contact sheet of the views."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import mujoco
import numpy as np

from hec.estimator.io.png import write_png
from hec.sim.render import RGBDRenderer

if TYPE_CHECKING:
    from hec.sim.cell import SimCell

OVERVIEW_SIZE = (1280, 960)


def overview_image(cell: SimCell) -> np.ndarray:
    """(960, 1280, 3) uint8 RGB view of the cell from the room, arm at its current joints."""
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    board_centre = (cell.cell.T_world_base @ cell.T_base_board())[:3, 3]
    camera.lookat[:] = board_centre + np.array([0.0, 0.1, 0.25])
    camera.distance, camera.azimuth, camera.elevation = 2.0, 125.0, -22.0
    renderer = RGBDRenderer(cell.model, *OVERVIEW_SIZE)
    try:
        rgb, _ = renderer.render(cell.data, camera)
    finally:
        renderer.close()
    return rgb


def contact_sheet(
    images: list[np.ndarray], columns: int = 5, thumb_width: int = 256, labels: list[str] | None = None
) -> np.ndarray:
    """Tile RGB images (same size) into one RGB image, each labelled with labels[i] (default: its
    frame number)."""
    h, w = images[0].shape[:2]
    thumb_h = round(h * thumb_width / w)
    rows = -(-len(images) // columns)
    sheet = np.full((rows * (thumb_h + 4) + 4, columns * (thumb_width + 4) + 4, 3), 40, np.uint8)
    for i, image in enumerate(images):
        thumb = cv2.resize(image, (thumb_width, thumb_h), interpolation=cv2.INTER_AREA)
        cv2.putText(
            thumb,
            labels[i] if labels else f"frame {i}",
            (6, 20),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.55,
            (255, 40, 40),
            2,
            cv2.LINE_AA,
        )
        r, c = divmod(i, columns)
        y, x = 4 + r * (thumb_h + 4), 4 + c * (thumb_width + 4)
        sheet[y : y + thumb_h, x : x + thumb_width] = thumb
    return sheet


def write_preview(cell: SimCell, frames_rgb: list[np.ndarray], folder: Path) -> list[Path]:
    """Write overview.png and contact_sheet.png into folder; returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / "overview.png", folder / "contact_sheet.png"]
    for path, image in zip(paths, (overview_image(cell), contact_sheet(frames_rgb)), strict=True):
        write_png(path, cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return paths
