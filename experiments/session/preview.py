"""`hec record --preview FILE.png`: the planned moves drawn in the MuJoCo cell before the arm moves, a
contact sheet with the arm halfway along each move and at its target, seen from the room. The cell
drawn is the simulated one (the built-in scenario's wall, table and board); the arm's joints are the
plan's. Only this option loads the simulator (OpenGL), so a robot PC without it records as before."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from hec.estimator.geometry.waypoints import PlannedMove
from hec.estimator.io.png import write_png


def add_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preview",
        type=Path,
        metavar="FILE.png",
        help="before moving, draw the planned moves in the simulated cell into this new PNG (needs hec[sim])",
    )


def check_preview_path(args: argparse.Namespace) -> None:
    """A preview never replaces a file, and is drawn for the real cell's plan: ValueError when
    args.preview exists, is not a .png, or comes with --sim."""
    path = args.preview
    if path is None:
        return
    if getattr(args, "sim", False):
        raise ValueError("--preview draws a real cell's plan; with --sim, hec simulate writes a preview")
    if path.suffix.lower() != ".png":
        raise ValueError(f"--preview {path}: give a .png file name")
    if path.exists():
        raise ValueError(f"--preview {path}: already exists; choose another name (nothing is overwritten)")


def write_path_preview(path: Path, moves: list[PlannedMove], q_start: np.ndarray) -> Path:
    """Render the arm halfway along and at the end of each usable move from q_start (6,), radians,
    into a labelled contact sheet at path (PNG, written atomically); returns path."""
    from hec.sim.cell import SimCell
    from hec.sim.preview import contact_sheet, overview_image
    from hec.sim.scenario import load_scenario

    cell = SimCell(load_scenario(None), np.random.default_rng(0))
    images, labels, q = [], [], np.asarray(q_start, dtype=float)
    try:
        for move in moves:
            if move.joints is None:
                continue
            for where, joints in (("halfway to", 0.5 * (q + move.joints)), ("at", move.joints)):
                cell.set_joints(joints)
                images.append(overview_image(cell))
                labels.append(f"{where} waypoint {move.waypoint.index}")
            q = move.joints
    finally:
        cell.close()
    if not images:
        raise ValueError("--preview: no move to draw (every waypoint was skipped)")
    sheet = contact_sheet(images, columns=4, thumb_width=320, labels=labels)
    return write_png(path, cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
