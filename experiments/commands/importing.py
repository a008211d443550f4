"""`hec import LAYOUT SOURCE --out DIR`: a hec dataset from another tool's layout. The work is
hec.import_dataset (hec.calibration.importing, whose doc says what is checked); this parses the
options and prints what it did."""

from __future__ import annotations

import argparse
from pathlib import Path

from hec.calibration.importing import LAYOUTS, ImportOptions, import_dataset
from hec.commands import arguments
from hec.commands.verbs import HELP
from hec.estimator.common.setups import EYE_IN_HAND, SETUPS
from hec.estimator.geometry.kinematics import ARMS, JOINT_ORDERS
from hec.estimator.io.convention_check import TRACKING_DIRECTIONS
from hec.estimator.io.pairing import PAIR_BY, TIME_UNITS
from hec.estimator.io.pose_file import DIRECTIONS, ROTATIONS
from hec.estimator.observe.depth import DEPTH_CAMERAS

OPTION_NAMES = (
    "board",
    "setup",
    "intrinsics",
    "camera",
    "poses",
    "pair_by",
    "time_tolerance",
    "image_time_unit",
    "rotation",
    "angle_unit",
    "length_unit",
    "pose_direction",
    "tracking_direction",
    "joints",
    "joint_unit",
    "joint_order",
    "depth",
    "depth_scale",
    "depth_camera",
    "depth_noise",
    "robot_model",
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help=HELP["import"])
    p.add_argument("layout", choices=LAYOUTS, help="the source's layout")
    p.add_argument("source", type=Path, help="image folder (folder, visp) or .samples file (easy_handeye2)")
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    p.add_argument("--board", help="board name in models/boards/ or a board file (required with images)")
    p.add_argument(
        "--setup",
        choices=SETUPS,
        default=EYE_IN_HAND,
        help="eye-in-hand (the camera on the flange, default) or eye-to-hand (the camera fixed in the cell, "
        "the board on the flange; image layouts): recorded in the dataset, which hec calibrate then solves",
    )
    p.add_argument("--intrinsics", type=Path, help="OpenCV FileStorage YAML/JSON or ROS camera_info YAML")
    p.add_argument(
        "--camera",
        type=float,
        nargs=6,
        metavar=("FX", "FY", "CX", "CY", "WIDTH", "HEIGHT"),
        help="intrinsics as numbers instead of --intrinsics (pixels; no distortion)",
    )
    p.add_argument(
        "--poses",
        type=Path,
        help="folder layout: the pose file (CSV with or without a header, JSON, .npy/.npz), or a folder of "
        "pose files, one per image, named by its number",
    )
    p.add_argument(
        "--pair-by",
        choices=PAIR_BY,
        help="how images pair with poses: name (the pose file's image column), number (the number in each "
        "image name, natural order), time (nearest time, the pose file's time column), order (name "
        "order); default: name if the pose file has an image column, else number",
    )
    p.add_argument(
        "--time-tolerance",
        type=arguments.positive,
        default=0.02,
        metavar="S",
        help="--pair-by time: the largest image-to-pose time gap, seconds (default %(default)s)",
    )
    p.add_argument(
        "--image-time-unit",
        choices=tuple(TIME_UNITS),
        default="s",
        help="--pair-by time: the unit of the number in the image names (default %(default)s)",
    )
    p.add_argument("--rotation", default="quat-wxyz", choices=ROTATIONS, help="default: %(default)s")
    p.add_argument("--angle-unit", default="rad", choices=("rad", "deg"), help="default: %(default)s")
    p.add_argument("--length-unit", default="m", choices=("m", "mm"), help="default: %(default)s")
    p.add_argument(
        "--pose-direction", default="base-to-flange", choices=DIRECTIONS, help="default: %(default)s"
    )
    p.add_argument(
        "--tracking-direction",
        default="camera-to-target",
        choices=TRACKING_DIRECTIONS,
        help="easy_handeye2: which way the tracking poses map (default: %(default)s, T_cam_board)",
    )
    p.add_argument(
        "--joints", type=Path, help="folder layout: joint angles per image (CSV with a header, or JSON)"
    )
    p.add_argument("--joint-unit", default="rad", choices=("rad", "deg"), help="default: %(default)s")
    p.add_argument(
        "--joint-order",
        default="arm",
        choices=JOINT_ORDERS,
        help="a UR arm's six joints: the arm's order (base first) or the ROS driver's /joint_states "
        "(elbow first); default: %(default)s",
    )
    p.add_argument(
        "--depth", type=Path, help="folder layout: 16-bit depth PNGs (or .npy) named as the images"
    )
    p.add_argument(
        "--depth-scale", type=arguments.positive, default=0.001, help="metres per depth unit (default 0.001)"
    )
    p.add_argument(
        "--depth-camera",
        choices=tuple(DEPTH_CAMERAS),
        help="the depth camera, for its depth noise (default: d435); recorded in dataset.json",
    )
    p.add_argument(
        "--depth-noise",
        type=float,
        nargs=3,
        metavar=("SUBPIXEL", "BASELINE_M", "FOCAL_PX"),
        help="the depth's noise as a stereo camera's (sigma = z^2 subpixel / (focal baseline)), "
        "instead of --depth-camera",
    )
    p.add_argument(
        "--robot-model",
        metavar="ARM|FILE",
        help=f"the arm ({', '.join(ARMS)}, or a DH table file: estimator/io/arm_file.py), recorded in "
        "dataset.json; with --joints and no --poses, the flange poses are computed from the joints",
    )
    p.add_argument("--no-check", action="store_true", help="skip detection and the convention check")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Import, then (image layouts) detect and check the pose convention; prints what it did."""
    values = {name: getattr(args, name) for name in OPTION_NAMES}
    for name in ("camera", "depth_noise"):
        values[name] = None if values[name] is None else tuple(values[name])
    options = ImportOptions(**values, check=not args.no_check)
    result = import_dataset(args.layout, args.source, args.out, options, args.force, args.quiet)
    if result.pose_pairs is not None:
        print(
            f"imported {result.pose_pairs} pose pairs (robot T_base_flange, tracking T_cam_board) into "
            f"{result.path}"
        )
        print("observations: pose_pairs.json (imported; nothing regenerates them)")
    else:
        print(result.pairing)
        for note in result.notes:
            print(f"note: {note}")
        if result.empty_depth:
            print(
                f"note: {result.empty_depth} depth images hold no depth (every pixel 0): those frames are "
                "imported without"
            )
        joints = "" if result.joints is None else f", {result.joints} joints each,"
        print(
            f"imported {result.images} images ({result.with_depth} with depth){joints} with {result.poses} "
            f"into {result.path}"
        )
    for line in result.checks:
        print(line)
    return 0
