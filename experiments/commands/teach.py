"""`hec teach`: store waypoints by moving the real arm by hand.

The arm is put in UR teach mode (freedrive); the user moves it and presses Enter to store
its joint angles. A pose is stored only once the arm is still, within the joint limits
and the workspace box of the cell file, and with every board marker found in the
RealSense colour image. The output is a joint waypoint CSV (sim/trajectory.py) that
`hec record --waypoints` reads; each row is on disk as soon as it is stored.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hec.commands.verbs import HELP
from hec.estimator.geometry.waypoints import JOINT_COLUMNS, WaypointFileError
from hec.estimator.io.board_file import find_board
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.target import BoardDefinitionError, TargetDetector
from hec.hardware.ur_robot import RobotError, URRobot
from hec.session.cell_config import CellConfigError, load_cell_config

if TYPE_CHECKING:
    import pyrealsense2 as rs

    from hec.hardware.realsense import RealSenseCamera

HEADER = (*JOINT_COLUMNS, "label")
PROMPT = "move the arm by hand, then Enter to store the pose, q to finish: "


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add `hec teach --out FILE.csv`."""
    p = sub.add_parser("teach", help=HELP["teach"])
    p.add_argument("--robot", metavar="HOST", help="the UR controller's address (else robot.host of --cell)")
    p.add_argument(
        "--camera",
        nargs="?",
        const="",
        metavar="SERIAL",
        help="the RealSense's serial number; without one the first camera (else camera.serial of --cell)",
    )
    p.add_argument("--cell", type=Path, metavar="FILE", help="cell file (TOML): limits, camera, board")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.csv", help="joint waypoint CSV to write")
    p.add_argument("--append", action="store_true", help="add waypoints to an existing --out file")
    p.add_argument(
        "--allow-partial",
        action="store_true",
        help="store a pose that shows some but not all markers (with a warning)",
    )


def run(
    args: argparse.Namespace,
    camera_context: rs.context | None = None,
    read_line: Callable[[str], str] = input,
) -> int:
    """`hec teach`: 0 when finished, 2 with a message on stderr when the cell cannot be used.

    camera_context: a librealsense context to find the camera in (tests pass a software device's).
    read_line: reads the user's answer to a prompt; "" stores the pose, "q" (or end of input) finishes.
    """
    # librealsense (the extra hec[realsense]) loads when the command runs.
    from hec.hardware.camera_settings import CameraError
    from hec.hardware.realsense import RealSenseCamera

    user_errors = (
        RobotError,
        CameraError,
        CellConfigError,
        BoardDefinitionError,
        WaypointFileError,
        FileExistsError,
    )
    try:
        config = load_cell_config(args.cell)
        host = config.robot_host(args.robot)
        stored_before = _existing_waypoints(args.out, args.append)
        board = find_board(config.board)
        detector = detector_for(board)
        count = stored_before
        with config.open_robot(host) as robot:
            with RealSenseCamera(config.camera_settings(args.camera), camera_context) as camera:
                robot.teach_mode(True)
                try:
                    while _next_pose(read_line):
                        count += _store_pose(robot, camera, detector, board.marker_ids, args, count + 1)
                except KeyboardInterrupt:
                    print()  # Ctrl-C finishes; every stored row is on disk already
                except BaseException:
                    with contextlib.suppress(RobotError):  # report the first error, not this one
                        robot.teach_mode(False)
                    raise
                robot.teach_mode(False)
    except user_errors as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
    new = count - stored_before
    print(f"stored {new} waypoint{'' if new == 1 else 's'} ({count} in {args.out})")
    if count:
        cell = f" --cell {args.cell}" if args.cell else ""
        print(f"next: hec record --robot {host}{cell} --waypoints {args.out} --out DIR")
    return 0


def _existing_waypoints(path: Path, append: bool) -> int:
    """How many waypoints the --out file holds already (0 if it does not exist); raises when it
    exists without --append or is not a joint waypoint file."""
    if not path.exists():
        return 0
    if not append:
        raise FileExistsError(f"{path} exists; give --append to add waypoints to it, or another --out")
    try:
        lines = _csv_lines(path.read_text())
    except UnicodeDecodeError as exc:
        raise WaypointFileError(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    if lines and next(csv.reader(lines[:1])) != list(HEADER):
        raise WaypointFileError(
            f"{path}: cannot append joint waypoints, its header is not {','.join(HEADER)}"
        )
    return max(len(lines) - 1, 0)


def _next_pose(read_line: Callable[[str], str]) -> bool:
    """Wait for the user: True to store the pose, False to finish (q or end of input)."""
    while True:
        try:
            answer = read_line(PROMPT).strip().lower()
        except EOFError:
            print()
            return False
        if answer in ("", "q"):
            return answer == ""
        print("press Enter to store the pose or q to finish")


def _store_pose(
    robot: URRobot,
    camera: RealSenseCamera,
    detector: TargetDetector,
    marker_ids: list[int],
    args: argparse.Namespace,
    number: int,
) -> int:
    """Append the arm's pose to args.out as waypoint `number` if it may be stored: 1 if stored,
    else 0 with the reason printed."""
    try:
        robot.wait_settled()
    except RobotError as exc:
        robot.joints()  # raises when the connection is lost: that ends the session
        print(f"not stored: {exc}")
        return 0
    q = robot.joints()
    problem = robot.check_joint_target(q)
    if problem:
        print(f"not stored: {problem}")
        return 0
    detections = detector.detect(camera.capture().rgb)
    if np.max(np.abs(robot.joints() - q)) > robot.motion.joint_tolerance_rad:
        print("not stored: the arm moved during the capture; hold it still")
        return 0
    found = {m.marker_id for m in detections.markers}
    missing = sorted(set(marker_ids) - found)
    if missing and (not args.allow_partial or not found):
        why = f"; {detections.problem}" if detections.problem else ""
        print(f"not stored: markers {missing} not seen{why}; move so the whole board is in view")
        return 0
    if missing:
        print(f"warning: markers {missing} not seen; storing the pose anyway (--allow-partial)")
    _append_row(args.out, q, f"taught {number}")
    p_base_flange = np.round(robot.flange_pose()[:3, 3], 3).tolist()
    print(f"stored waypoint {number}: {len(found)}/{len(marker_ids)} markers, flange at {p_base_flange} m")
    return 1


def _append_row(path: Path, q: np.ndarray, label: str) -> None:
    """Append joints q (6,), radians, as a row (after the header if the file is new). The file
    is closed at once, so a stored row is on disk whatever ends the session."""
    text = path.read_text() if path.exists() else ""
    with open(path, "a", newline="") as f:
        if text and not text.endswith("\n"):
            f.write("\n")
        writer = csv.writer(f, lineterminator="\n")
        if not _csv_lines(text):
            writer.writerow(HEADER)
        writer.writerow([repr(float(v)) for v in q] + [label])


def _csv_lines(text: str) -> list[str]:
    """The header and data lines of a waypoint CSV (no blank or comment lines)."""
    return [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
