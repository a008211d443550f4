"""A hec dataset from another tool's layout (hec.estimator.io.layouts): an image folder with a pose
file, ViSP's hand-eye folder, or an easy_handeye2 .samples file of pose pairs; what `hec import` and
hec.import_dataset do. Image imports are detected at once (the observations cached as `hec detect`
would) and the robot poses' convention is checked: if a common mistake fits the data much better
than the stated convention, the check says which and the option that selects it. The board file's
layout is checked against the images (a mirrored one is named) and imported joints against the
robot poses (joints in the ROS driver's order, or poses in other base or tool frames than the
joints' kinematics, are named)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from hec.estimator.common.files import refuse_writing_over_inputs
from hec.estimator.common.setups import EYE_IN_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import ARMS, arm_dict
from hec.estimator.geometry.transforms import invert
from hec.estimator.io.arm_file import ArmFileError, read_arm
from hec.estimator.io.board_file import find_board
from hec.estimator.io.convention_check import check_pose_pair_directions
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.importer import import_images, import_pose_pairs, provenance
from hec.estimator.io.intrinsics_file import IntrinsicsFileError, read_intrinsics
from hec.estimator.io.layouts import JointFile, LayoutError, read_easy_handeye_samples, read_folder, read_visp
from hec.estimator.io.pairing import PairingError
from hec.estimator.io.pose_file import PoseConvention, PoseFileError
from hec.estimator.io.pose_table import IMAGE_SUFFIXES
from hec.estimator.observe.depth import DEPTH_CAMERAS, DepthNoiseModel
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.pose_pairs import PosePair

LAYOUTS = ("folder", "visp", "easy_handeye2")
IMPORT_ERRORS = (LayoutError, PoseFileError, PairingError, IntrinsicsFileError, ArmFileError)


class DatasetImportError(ValueError):
    """An import refused: the one-line message `hec import` prints (nothing is written)."""


@dataclass(frozen=True)
class ImportOptions:
    """How to read the source: `hec import`'s options (its --help says each), as Python values.

    board: a board name in models/boards/ or a board file (required with images); setup: eye-in-hand
    or eye-to-hand; intrinsics: a camera file, or camera (fx, fy, cx, cy, width, height) in pixels;
    poses, joints, depth: the folder layout's pose file (or folder), joint file and depth folder;
    pair_by, time_tolerance (s), image_time_unit: how images pair with poses; rotation, angle_unit,
    length_unit, pose_direction: the pose convention; tracking_direction: easy_handeye2's tracking
    poses; joint_unit, joint_order: the joints'; depth_scale: metres per depth unit; depth_camera or
    depth_noise (subpixel, baseline m, focal px): the depth's noise; robot_model: an arm name or DH
    file; check: detect and check the convention after importing.
    """

    board: str | None = None
    setup: str = EYE_IN_HAND
    intrinsics: Path | None = None
    camera: tuple[float, float, float, float, float, float] | None = None
    poses: Path | None = None
    pair_by: str | None = None
    time_tolerance: float = 0.02
    image_time_unit: str = "s"
    rotation: str = "quat-wxyz"
    angle_unit: str = "rad"
    length_unit: str = "m"
    pose_direction: str = "base-to-flange"
    tracking_direction: str = "camera-to-target"
    joints: Path | None = None
    joint_unit: str = "rad"
    joint_order: str = "arm"
    depth: Path | None = None
    depth_scale: float = 0.001
    depth_camera: str | None = None
    depth_noise: tuple[float, float, float] | None = None
    robot_model: str | None = None
    check: bool = True


@dataclass(frozen=True)
class ImportResult:
    """What an import wrote at path: pose_pairs (easy_handeye2: how many; else None) or images, of
    them with_depth (and empty_depth: depth images that held no depth), joints per image (or None);
    poses: how the robot poses were read, in words; pairing: how images paired with poses; notes;
    checks: the detection and convention checks' lines (empty when not checked)."""

    path: Path
    layout: str
    pose_pairs: int | None = None
    images: int = 0
    with_depth: int = 0
    empty_depth: int = 0
    joints: int | None = None
    poses: str = ""
    pairing: str = ""
    notes: tuple[str, ...] = ()
    checks: tuple[str, ...] = ()


def import_dataset(
    layout: str,
    source: Path,
    out: Path,
    options: ImportOptions = ImportOptions(),
    force: bool = False,
    quiet: bool = True,
) -> ImportResult:
    """Import source (an image folder for folder and visp, a .samples file for easy_handeye2) as a
    hec dataset at out (nothing appears there unless it completes; force replaces a dataset there);
    image layouts are detected and checked unless options.check is False. Raises
    DatasetImportError with the command's message."""
    if layout not in LAYOUTS:
        raise DatasetImportError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    inputs = {"source": source, "pose file": options.poses, "depth folder": options.depth}
    inputs |= {"joint file": options.joints, "intrinsics file": options.intrinsics}
    try:
        refuse_writing_over_inputs(out, inputs)
    except ValueError as exc:
        raise DatasetImportError(str(exc)) from None
    try:
        if layout == "easy_handeye2":
            return _import_pose_pairs(source, out, options, force)
        return _import_images(layout, source, out, options, force, quiet)
    except IMPORT_ERRORS as exc:
        raise DatasetImportError(str(exc)) from None


def _import_pose_pairs(source: Path, out: Path, options: ImportOptions, force: bool) -> ImportResult:
    if options.setup != EYE_IN_HAND:
        raise DatasetImportError(
            "--setup eye-to-hand is for image imports: hec calibrates pose pairs eye-in-hand only"
        )
    pairs = _directed(read_easy_handeye_samples(source), options)
    board = find_board(options.board) if options.board else None
    intrinsics = _intrinsics(options, source, required=False)
    check = None
    if options.check:
        check = check_pose_pair_directions(pairs, options.pose_direction, options.tracking_direction)
        if check.mistake:
            raise DatasetImportError(
                f"{source}: {check.message}; nothing written (--no-check imports them as stated)"
            )
    path = import_pose_pairs(pairs, out, provenance("easy_handeye2", [source]), board, intrinsics, force)
    checks = () if check is None else (f"convention check: {check.message}",)
    return ImportResult(path, "easy_handeye2", pose_pairs=len(pairs), checks=checks)


def _import_images(
    layout: str, source: Path, out: Path, options: ImportOptions, force: bool, quiet: bool
) -> ImportResult:
    if options.board is None:
        raise DatasetImportError("--board is needed to import images: the board name or file they show")
    board = find_board(options.board)
    intrinsics = _intrinsics(options, source, required=True)
    arm = None if options.robot_model is None else read_arm(options.robot_model)
    if layout == "folder":
        if options.poses is None and (options.joints is None or arm is None):
            raise DatasetImportError(
                "the folder layout needs --poses, or --joints with --robot-model to compute the "
                "flange poses from the joints"
            )
        joint_file = (
            None
            if options.joints is None
            else JointFile(options.joints, options.joint_unit, options.joint_order)
        )
        frames = read_folder(
            source,
            options.poses,
            _convention(options),
            options.depth,
            joint_file,
            options.pair_by,
            options.time_tolerance,
            options.image_time_unit,
            arm,
        )
        sources = [p for p in (source, options.poses, options.depth, options.joints) if p]
    else:
        if options.joints is not None or options.pair_by is not None:
            raise DatasetImportError(
                "--joints and --pair-by are for the folder layout (ViSP's pairs each image with the "
                "pose file of its number, and has no joints)"
            )
        joint_file, frames = None, read_visp(source)
        sources = [source]
    extra = {} if arm is None else {"robot_model": arm.name}
    if options.setup != EYE_IN_HAND:
        extra["setup"] = options.setup
    depth_noise = _depth_noise(options)
    if depth_noise is not None:
        extra["depth_noise"] = depth_noise.to_dict()
    if arm is not None and ARMS.get(arm.name) != arm:
        extra["robot_dh"] = arm_dict(arm)
    checks: list[str] = []

    def check(folder: Path) -> None:  # on the complete dataset before it is moved into place
        checks.extend(check_import(folder, quiet, out))

    path = import_images(
        frames,
        out,
        board,
        intrinsics,
        options.depth_scale,
        provenance(layout, sources, frames, joint_file),
        extra,
        force,
        check if options.check else None,
    )
    depth = sum(bool(row["depth"]) for row in load_dataset(path).rows)
    poses = (
        f"flange poses computed from the joints with {arm.name}'s kinematics"
        if layout == "folder" and options.poses is None and arm is not None
        else f"robot poses read as {_describe(frames.convention)}"
    )
    return ImportResult(
        path,
        layout,
        images=len(frames.images),
        with_depth=depth,
        empty_depth=sum(d is not None for d in frames.depths) - depth,
        joints=None if frames.joints is None else int(frames.joints.shape[1]),
        poses=poses,
        pairing=frames.pairing.describe(),
        notes=tuple(frames.notes),
        checks=tuple(checks),
    )


def _directed(pairs: list[PosePair], options: ImportOptions) -> list[PosePair]:
    """The samples read in the directions the options state: T_base_flange and T_cam_board."""
    robot = options.pose_direction == "flange-to-base"
    tracking = options.tracking_direction == "target-to-camera"
    return [
        PosePair(
            p.frame,
            invert(p.T_base_flange) if robot else p.T_base_flange,
            invert(p.T_cam_board) if tracking else p.T_cam_board,
        )
        for p in pairs
    ]


def _depth_noise(options: ImportOptions) -> DepthNoiseModel | None:
    """The depth noise the options name, or None (the D435's, which datasets default to)."""
    if options.depth_camera is not None and options.depth_noise is not None:
        raise DatasetImportError("give --depth-camera or --depth-noise, not both")
    if (options.depth_camera or options.depth_noise) and options.depth is None:
        raise DatasetImportError(
            "--depth-camera and --depth-noise describe the depth images: give --depth DIR too"
        )
    if options.depth_noise is not None:
        subpixel, baseline_m, focal_px = options.depth_noise
        try:
            return DepthNoiseModel(subpixel, baseline_m, focal_px)
        except ValueError as exc:
            raise DatasetImportError(f"--depth-noise: {exc}") from None
    return None if options.depth_camera is None else DEPTH_CAMERAS[options.depth_camera]


def _convention(options: ImportOptions) -> PoseConvention:
    return PoseConvention(options.rotation, options.angle_unit, options.length_unit, options.pose_direction)


def _describe(convention: PoseConvention) -> str:
    c = convention
    angles = "" if c.rotation.startswith("quat") or c.rotation == "matrix" else f" in {c.angle_unit}"
    return f"{c.rotation}{angles}, {c.length_unit}, {c.direction}"


def _intrinsics(options: ImportOptions, source: Path, required: bool) -> CameraIntrinsics | None:
    if options.intrinsics is not None and options.camera is not None:
        raise DatasetImportError("give --intrinsics or --camera, not both")
    if options.intrinsics is not None:
        return read_intrinsics(options.intrinsics, _first_image_size(source))
    if options.camera is not None:
        fx, fy, cx, cy, width, height = options.camera
        if width != int(width) or height != int(height):
            raise DatasetImportError(f"--camera: WIDTH and HEIGHT are whole pixels, got {width:g} {height:g}")
        try:
            return CameraIntrinsics(int(width), int(height), fx, fy, cx, cy)
        except ValueError as exc:
            raise DatasetImportError(f"--camera: {exc}") from None
    if required:
        raise DatasetImportError("the camera is needed to import images: give --intrinsics FILE or --camera")
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
