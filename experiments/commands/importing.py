"""`hec import LAYOUT SOURCE --out DIR`: a hec dataset from another tool's layout
(hec.estimator.io.layouts): an image folder with a pose file, ViSP's hand-eye folder, or an
easy_handeye2 .samples file of pose pairs. Image imports are detected at once (the observations
cached as `hec detect` would) and the robot poses' convention is checked: if a common mistake fits
the data much better than the stated convention, hec says which and the option that selects it. The
board file's layout is checked against the images (a mirrored one is named) and imported joints
against the robot poses (joints in the ROS driver's order, or poses in other base or tool frames
than the joints' kinematics, are named)."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from hec.commands import arguments
from hec.commands.verbs import HELP
from hec.estimator.common.files import refuse_writing_over_inputs
from hec.estimator.common.setups import EYE_IN_HAND, SETUPS
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import ARMS, JOINT_ORDERS, arm_dict
from hec.estimator.geometry.transforms import invert
from hec.estimator.io.arm_file import ArmFileError, read_arm
from hec.estimator.io.board_file import find_board
from hec.estimator.io.convention_check import TRACKING_DIRECTIONS, check_pose_pair_directions
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.intrinsics_file import IntrinsicsFileError, read_intrinsics
from hec.estimator.io.layouts import JointFile, LayoutError, read_easy_handeye_samples, read_folder, read_visp
from hec.estimator.io.pairing import PAIR_BY, TIME_UNITS, PairingError
from hec.estimator.io.pose_file import DIRECTIONS, ROTATIONS, PoseConvention, PoseFileError
from hec.estimator.io.pose_table import IMAGE_SUFFIXES
from hec.estimator.observe.depth import DEPTH_CAMERAS, DepthNoiseModel
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.pose_pairs import PosePair

LAYOUTS = ("folder", "visp", "easy_handeye2")
IMPORT_ERRORS = (LayoutError, PoseFileError, PairingError, IntrinsicsFileError, ArmFileError)


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
    from hec.estimator.io.importer import import_images, import_pose_pairs, provenance

    inputs = {"source": args.source, "pose file": args.poses, "depth folder": args.depth}
    inputs |= {"joint file": args.joints, "intrinsics file": args.intrinsics}
    refuse_writing_over_inputs(args.out, inputs)
    try:
        if args.layout == "easy_handeye2":
            if args.setup != EYE_IN_HAND:
                raise ValueError(
                    "--setup eye-to-hand is for image imports: hec calibrates pose pairs eye-in-hand only"
                )
            pairs = _directed(read_easy_handeye_samples(args.source), args)
            board = find_board(args.board) if args.board else None
            intrinsics = _intrinsics(args, required=False)
            check = None
            if not args.no_check:
                check = check_pose_pair_directions(pairs, args.pose_direction, args.tracking_direction)
                if check.mistake:
                    raise ValueError(
                        f"{args.source}: {check.message}; nothing written (--no-check imports them as stated)"
                    )
            out = import_pose_pairs(
                pairs, args.out, provenance(args.layout, [args.source]), board, intrinsics, args.force
            )
            print(f"imported {len(pairs)} pose pairs (robot T_base_flange, tracking T_cam_board) into {out}")
            print("observations: pose_pairs.json (imported; nothing regenerates them)")
            if check is not None:
                print(f"convention check: {check.message}")
            return 0
        if args.board is None:
            raise ValueError("--board is needed to import images: the board name or file they show")
        board = find_board(args.board)
        intrinsics = _intrinsics(args, required=True)
        arm = None if args.robot_model is None else read_arm(args.robot_model)
        if args.layout == "folder":
            if args.poses is None and (args.joints is None or arm is None):
                raise ValueError(
                    "the folder layout needs --poses, or --joints with --robot-model to compute the "
                    "flange poses from the joints"
                )
            joint_file = (
                None if args.joints is None else JointFile(args.joints, args.joint_unit, args.joint_order)
            )
            frames = read_folder(
                args.source,
                args.poses,
                _convention(args),
                args.depth,
                joint_file,
                args.pair_by,
                args.time_tolerance,
                args.image_time_unit,
                arm,
            )
            sources = [p for p in (args.source, args.poses, args.depth, args.joints) if p]
        else:
            if args.joints is not None or args.pair_by is not None:
                raise ValueError(
                    "--joints and --pair-by are for the folder layout (ViSP's pairs each image with the "
                    "pose file of its number, and has no joints)"
                )
            joint_file, frames = None, read_visp(args.source)
            sources = [args.source]
        extra = {} if arm is None else {"robot_model": arm.name}
        if args.setup != EYE_IN_HAND:
            extra["setup"] = args.setup
        depth_noise = _depth_noise(args)
        if depth_noise is not None:
            extra["depth_noise"] = depth_noise.to_dict()
        if arm is not None and ARMS.get(arm.name) != arm:
            extra["robot_dh"] = arm_dict(arm)
        checks: list[str] = []

        def check(folder: Path) -> None:  # on the complete dataset before it is moved into place
            checks.extend(check_import(folder, args.quiet, args.out))

        out = import_images(
            frames,
            args.out,
            board,
            intrinsics,
            args.depth_scale,
            provenance(args.layout, sources, frames, joint_file),
            extra,
            args.force,
            None if args.no_check else check,
        )
    except IMPORT_ERRORS as exc:
        raise ValueError(str(exc)) from None
    print(frames.pairing.describe())
    for note in frames.notes:
        print(f"note: {note}")
    depth = sum(bool(row["depth"]) for row in load_dataset(out).rows)
    empty = sum(d is not None for d in frames.depths) - depth
    if empty:
        print(f"note: {empty} depth images hold no depth (every pixel 0): those frames are imported without")
    joints = "" if frames.joints is None else f", {frames.joints.shape[1]} joints each,"
    poses = (
        f"flange poses computed from the joints with {arm.name}'s kinematics"
        if args.layout == "folder" and args.poses is None
        else f"robot poses read as {_describe(frames.convention)}"
    )
    print(f"imported {len(frames.images)} images ({depth} with depth){joints} with {poses} into {out}")
    for line in checks:
        print(line)
    return 0


def _directed(pairs: list[PosePair], args: argparse.Namespace) -> list[PosePair]:
    """The samples read in the directions the options state: T_base_flange and T_cam_board."""
    robot = args.pose_direction == "flange-to-base"
    tracking = args.tracking_direction == "target-to-camera"
    return [
        PosePair(
            p.frame,
            invert(p.T_base_flange) if robot else p.T_base_flange,
            invert(p.T_cam_board) if tracking else p.T_cam_board,
        )
        for p in pairs
    ]


def _depth_noise(args: argparse.Namespace) -> DepthNoiseModel | None:
    """The depth noise the options name, or None (the D435's, which datasets default to)."""
    if args.depth_camera is not None and args.depth_noise is not None:
        raise ValueError("give --depth-camera or --depth-noise, not both")
    if (args.depth_camera or args.depth_noise) and args.depth is None:
        raise ValueError("--depth-camera and --depth-noise describe the depth images: give --depth DIR too")
    if args.depth_noise is not None:
        subpixel, baseline_m, focal_px = args.depth_noise
        try:
            return DepthNoiseModel(subpixel, baseline_m, focal_px)
        except ValueError as exc:
            raise ValueError(f"--depth-noise: {exc}") from None
    return None if args.depth_camera is None else DEPTH_CAMERAS[args.depth_camera]


def _convention(args: argparse.Namespace) -> PoseConvention:
    return PoseConvention(args.rotation, args.angle_unit, args.length_unit, args.pose_direction)


def _describe(convention: PoseConvention) -> str:
    c = convention
    angles = "" if c.rotation.startswith("quat") or c.rotation == "matrix" else f" in {c.angle_unit}"
    return f"{c.rotation}{angles}, {c.length_unit}, {c.direction}"


def _intrinsics(args: argparse.Namespace, required: bool) -> CameraIntrinsics | None:
    if args.intrinsics is not None and args.camera is not None:
        raise ValueError("give --intrinsics or --camera, not both")
    if args.intrinsics is not None:
        return read_intrinsics(args.intrinsics, _first_image_size(args.source))
    if args.camera is not None:
        fx, fy, cx, cy, width, height = args.camera
        if width != int(width) or height != int(height):
            raise ValueError(f"--camera: WIDTH and HEIGHT are whole pixels, got {width:g} {height:g}")
        try:
            return CameraIntrinsics(int(width), int(height), fx, fy, cx, cy)
        except ValueError as exc:
            raise ValueError(f"--camera: {exc}") from None
    if required:
        raise ValueError("the camera is needed to import images: give --intrinsics FILE or --camera")
    return None


def _first_image_size(folder: Path) -> tuple[int, int] | None:
    """(width, height) of the first image in folder, for an intrinsics file that gives no size."""
    if not folder.is_dir():
        return None
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() in IMAGE_SUFFIXES:
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is not None:
                return image.shape[1], image.shape[0]
    return None


def check_import(dataset_path: Path, quiet: bool = False, shown_as: Path | None = None) -> list[str]:
    """Detect an imported image dataset (cached as `hec detect` does) and check its pose convention,
    its board file and its joints (if any): the lines to print. shown_as: the folder the dataset
    will be at, for the lines (the check runs before it is moved there)."""
    from hec.estimator.io.convention_check import check_board_layout, check_pose_convention
    from hec.estimator.solve.problem import build_problem, dataset_robot_noise, dataset_setup
    from hec.estimator.targets.qr import DetectorSettings
    from hec.support.detection import detect_and_cache

    dataset = load_dataset(dataset_path)
    observations, cache, _ = detect_and_cache(dataset, DetectorSettings(), quiet)
    found = sum(o.problem is None for o in observations)
    points = sum(len(m.corners_px) for o in observations for m in o.markers)
    lines = [
        f"detected the board in {found} of {len(observations)} frames ({points} points); cached in "
        f"{(shown_as or dataset_path) / cache.name}"
    ]
    record = dataset.metadata["provenance"]
    stated = PoseConvention(**record["pose_convention"])
    problem = build_problem(
        observations,
        dataset.board,
        dataset.intrinsics,
        dataset_robot_noise(dataset),
        setup=dataset_setup(dataset),
    )
    report = check_pose_convention(problem, record["pose_values"], stated)
    lines.append(f"convention check: {report.message}")
    lines.append(f"board check: {check_board_layout(problem)}")
    if "joints" in record:
        lines += _joint_check(dataset)
    return lines


def _joint_check(dataset: Dataset) -> list[str]:
    """The joint-order check of an imported dataset with joints (or why it cannot run) and, when the
    poses are the joints' kinematics in other base or tool frames, which."""
    from hec.estimator.io.joint_check import check_joint_frames, check_joint_order
    from hec.estimator.solve.problem import dataset_arm

    arm = dataset_arm(dataset)
    if arm is None:
        return ["joint check: not run: it needs a UR arm's six joints per image and --robot-model"]
    T_base_flange = np.array([row["T_base_flange"] for row in dataset.rows])
    joints = np.array([arm.joints[i] for i in range(len(dataset.rows))])
    order = dataset.metadata["provenance"]["joints"]["order"]
    lines = [f"joint check: {check_joint_order(T_base_flange, joints, arm.kinematics, order)}"]
    frames = check_joint_frames(T_base_flange, joints, arm.kinematics)
    return lines + ([f"frame check: {frames}"] if frames else [])
