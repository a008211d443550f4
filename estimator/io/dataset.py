"""Frames and the on-disk dataset format (hec-dataset, version 1).

One format serves the simulator, the real cell and imports. A dataset is a
folder a person can open without this project::

    dataset.json        format, version, source, frame count, camera intrinsics, depth scale, the depth noise
                        model ('depth_noise', see hec.estimator.observe.depth.DepthNoiseModel; optional), the
                        noise of the reported flange poses ('robot_pose_noise': translation_sigma_m,
                        rotation_sigma_rad, see hec.estimator.solve.problem.RobotPoseNoise; optional), the arm
                        whose nominal kinematics the joints are read with ('robot_model', 'ur5' or 'ur5e';
                        optional, a simulation's is its scenario's robot), (imports) 'provenance': the
                        layout, source files, conventions and when; 'pose_pairs_file' for a dataset of
                        pose pairs (camera and board_file may then be null); and (simulation) seed,
                        scenario, skipped waypoints
    board.json          the board definition (hec-board v1)
    pose_pairs.json     a dataset of imported pose pairs only (hec.estimator.observe.pose_pairs): its
                        observations, which nothing regenerates
    frames.csv          one row a frame: frame, time_s, rgb, depth, the reported T_base_flange as
                        x_m,y_m,z_m,qw,qx,qy,qz and joints q1_rad..qN_rad (any N, 0 too: N from the header;
                        6 for a UR arm); depth empty for a frame without depth, rgb empty in a dataset
                        of pose pairs (hec.estimator.observe.pose_pairs); a recorded session adds waypoint
                        (the waypoint's index) and depth_samples (its image, or empty)
    rgb/NNNNNN.png      colour, 8-bit RGB
    depth/NNNNNN.png    depth, 16-bit; metres = value * depth_scale_m, 0 = no depth
    depth_samples/NNNNNN.png  optional, 8-bit: valid depth samples averaged per pixel
    ground_truth.json   simulation only: T_flange_cam, T_base_board, T_world_base (eye-to-hand:
                        setup, T_base_cam, T_flange_board, T_world_base)
                        and per frame the true T_base_flange and joints
    detections.json     optional cache written by `hec detect` (hec.estimator.observe.observations)
    overlay/NNNNNN.png  optional detection pictures written by `hec detect --overlay`

Depth is aligned to the colour image and shares its intrinsics. A rendered dataset (DatasetWriter)
is written into a temporary sibling folder and renamed into place when it is complete, so a failed
run never leaves a folder that looks finished. A recorded session (hec.estimator.io.recorder) is
written in place frame by frame, so an interruption keeps every frame captured before it; dataset.json
'recording' says whether it is 'in progress', 'interrupted' or 'complete'.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from hec.estimator.common.depth_png import encode_depth
from hec.estimator.common.files import open_text, write_atomic
from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.common.setups import EYE_TO_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.transforms import transform_from_xyz_quat, xyz_quat_from_transform
from hec.estimator.io.board_file import board_to_dict, load_board
from hec.estimator.io.dataset_file import DatasetMeta, GroundTruthFile
from hec.estimator.io.lock import remove_dead_partials, writers_running
from hec.estimator.io.png import write_png
from hec.estimator.io.schema import validated
from hec.estimator.observe.frames import UR_JOINTS, Dataset, DatasetError, Frame, GroundTruth
from hec.estimator.targets.target import BoardDefinitionError, Target

FORMAT = "hec-dataset"
VERSION = 1
POSE_COLUMNS = ("frame", "time_s", "rgb", "depth", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz")


def frame_columns(joint_count: int = UR_JOINTS) -> tuple[str, ...]:
    """frames.csv's columns for an arm of joint_count joints (q1_rad..qN_rad)."""
    return (*POSE_COLUMNS, *(f"q{i}_rad" for i in range(1, joint_count + 1)))


FRAME_COLUMNS = frame_columns()
# The files of a dataset folder that hec reads (an output never replaces one).
DATASET_FILES = (
    "dataset.json",
    "frames.csv",
    "board.json",
    "ground_truth.json",
    "pose_pairs.json",
    "detections.json",
)
SESSION_COLUMNS = ("waypoint", "depth_samples")


def dataset_inputs(folder: str | Path) -> dict[str, Path]:
    """The files of the dataset at folder that hec reads and that exist, each named for a message
    ("dataset's frames.csv")."""
    return {f"dataset's {n}": Path(folder) / n for n in DATASET_FILES if (Path(folder) / n).is_file()}


def _matrix(T: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in T]


def dump_json(path: Path, data: dict) -> None:
    write_atomic(path, json.dumps(data, indent=2) + "\n")


class DatasetWriter:
    """Write a dataset; use as a context manager. Nothing appears at ``out_dir``
    until ``finish`` succeeds. An existing ``out_dir`` is replaced only with force.
    Temporary folders of out_dir left by killed runs are removed (listed in ``removed``).
    A dataset of pose pairs (no images: add_pose) may have no intrinsics and no board."""

    def __init__(
        self,
        out_dir: str | Path,
        intrinsics: CameraIntrinsics | None,
        board: Target | None,
        depth_scale_m: float,
        source: str,
        force: bool = False,
    ) -> None:
        self.out_dir = Path(out_dir)
        if self.out_dir.exists() and not force:
            raise FileExistsError(f"{self.out_dir} already exists; use --force to replace it")
        if self.out_dir.exists():
            refuse_replacing_other_files(self.out_dir)
        self.intrinsics = intrinsics
        self.board = board
        self.depth_scale_m = depth_scale_m
        self.source = source
        self.force = force
        self.removed = remove_dead_partials(self.out_dir)
        self.tmp_dir = self.out_dir.parent / f".{self.out_dir.name}.partial-{os.getpid()}"
        if self.tmp_dir.exists():
            shutil.rmtree(self.tmp_dir)
        self.tmp_dir.mkdir(parents=True)
        others = writers_running(self.out_dir)
        if others:
            shutil.rmtree(self.tmp_dir)
            raise FileExistsError(
                f"{self.out_dir}: another hec run (process {others[0]}) is writing it now; wait for it to "
                "end or choose another output folder"
            )
        self.rows: list[list[str]] = []
        self.joint_count: int | None = None

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type: object, *_: object) -> None:
        if self.tmp_dir.exists():
            shutil.rmtree(self.tmp_dir)

    def add_frame(self, frame: Frame) -> int:
        """Write one frame's images now and keep its row; returns the frame number."""
        index = len(self.rows)
        if self.joint_count is None:
            self.joint_count = len(frame.joints)
        elif len(frame.joints) != self.joint_count:
            raise DatasetError(
                f"frame {index} has {len(frame.joints)} joints, the frames before it {self.joint_count}"
            )
        self.rows.append(write_frame_files(self.tmp_dir, index, frame, self.intrinsics, self.depth_scale_m))
        return index

    def add_pose(self, T_base_flange: np.ndarray, time_s: float) -> int:
        """A frame without images (a pose pair's robot pose); returns the frame number."""
        index = len(self.rows)
        self.joint_count = 0
        t, q = xyz_quat_from_transform(T_base_flange)
        self.rows.append([str(index), repr(float(time_s)), "", "", *(repr(float(v)) for v in (*t, *q))])
        return index

    def add_file(self, name: str, text: str) -> None:
        """Another file of the dataset (name relative to its folder), written with it."""
        write_atomic(self.tmp_dir / name, text)

    def finish(
        self,
        ground_truth: GroundTruth | None = None,
        extra: dict | None = None,
        check: Callable[[Path], None] | None = None,
    ) -> Path:
        """Write the tables and metadata, run check on the complete temporary folder (an import's
        detection and checks: if it fails or is stopped, nothing appears), then move the dataset
        into place. A folder that appeared at out_dir meanwhile (another run) is replaced only with
        force, and only if it is a dataset."""
        with open_text(self.tmp_dir / "frames.csv", "w") as f:
            writer = csv.writer(f, lineterminator="\n")
            writer.writerow(frame_columns(UR_JOINTS if self.joint_count is None else self.joint_count))
            writer.writerows(self.rows)
        if self.board is not None:
            dump_json(self.tmp_dir / "board.json", board_to_dict(self.board))
        if ground_truth is not None:
            dump_json(self.tmp_dir / "ground_truth.json", ground_truth_dict(ground_truth))
        meta = dataset_json(self.intrinsics, self.depth_scale_m, self.source, len(self.rows), ground_truth)
        if self.board is None:
            meta["board_file"] = None
        dump_json(self.tmp_dir / "dataset.json", meta | (extra or {}))
        if check is not None:
            check(self.tmp_dir)
        if self.out_dir.exists():
            if not self.force:
                raise FileExistsError(
                    f"{self.out_dir}: appeared while this run wrote it (another run?); it is kept and "
                    "nothing was written; choose another output folder or pass --force"
                )
            refuse_replacing_other_files(self.out_dir)
            trash = self.out_dir.parent / f".{self.out_dir.name}.old-{os.getpid()}"
            self.out_dir.rename(trash)
            self.tmp_dir.rename(self.out_dir)
            shutil.rmtree(trash)
        else:
            self.tmp_dir.rename(self.out_dir)
        return self.out_dir


def refuse_replacing_other_files(out_dir: Path) -> None:
    """FileExistsError unless out_dir is empty or a hec dataset (its dataset.json says so): --force
    replaces only what hec wrote, never a user's other files."""
    if out_dir.is_dir() and not any(out_dir.iterdir()):
        return
    try:
        format_ = json.loads((out_dir / "dataset.json").read_text()).get("format")
    except (OSError, ValueError, AttributeError):
        format_ = None
    if format_ != FORMAT:
        raise FileExistsError(
            f"{out_dir}: exists and is not a hec dataset; --force replaces only a dataset hec wrote: "
            "choose another output folder or move this one away"
        )


def write_frame_files(
    root: Path, index: int, frame: Frame, intrinsics: CameraIntrinsics, depth_scale_m: float
) -> list[str]:
    """Check the frame against the intrinsics, write its images under root and return its
    frames.csv row (frame_columns of its joints; no depth image, and an empty depth field, for a
    frame without depth)."""
    k = intrinsics
    if frame.rgb.shape != (k.height, k.width, 3) or frame.rgb.dtype != np.uint8:
        raise DatasetError(
            f"rgb must be ({k.height}, {k.width}, 3) uint8, got {frame.rgb.shape} {frame.rgb.dtype}"
        )
    if frame.depth_m is not None and frame.depth_m.shape != (k.height, k.width):
        raise DatasetError(f"depth must be ({k.height}, {k.width}), got {frame.depth_m.shape}")
    rgb_name = f"rgb/{index:06d}.png"
    (root / "rgb").mkdir(exist_ok=True)
    write_png(root / rgb_name, cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
    depth_name = ""
    if frame.depth_m is not None:
        depth_name = f"depth/{index:06d}.png"
        (root / "depth").mkdir(exist_ok=True)
        write_png(root / depth_name, encode_depth(frame.depth_m, depth_scale_m))
    t, q = xyz_quat_from_transform(frame.T_base_flange)
    values = [*t, *q, *frame.joints]
    return [str(index), repr(float(frame.time_s)), rgb_name, depth_name, *(repr(float(v)) for v in values)]


def ground_truth_dict(truth: GroundTruth) -> dict:
    """ground_truth.json: eye-in-hand T_flange_cam and T_base_board, eye-to-hand (with 'setup')
    T_base_cam and T_flange_board."""
    if truth.setup == EYE_TO_HAND:
        unknowns = {
            "setup": EYE_TO_HAND,
            "T_base_cam": _matrix(truth.T_base_cam),
            "T_flange_board": _matrix(truth.T_flange_board),
        }
    else:
        unknowns = {"T_flange_cam": _matrix(truth.T_flange_cam), "T_base_board": _matrix(truth.T_base_board)}
    data = {
        **unknowns,
        "T_world_base": _matrix(truth.T_world_base),
        "frames": [
            {"frame": i, "T_base_flange": _matrix(T), "joints_rad": [float(v) for v in q]}
            for i, (T, q) in enumerate(zip(truth.T_base_flange, truth.joints, strict=True))
        ],
    }
    if truth.model_errors is not None:
        data["model_errors"] = truth.model_errors
    return data


def dataset_json(
    intrinsics: CameraIntrinsics | None,
    depth_scale_m: float,
    source: str,
    frame_count: int,
    ground_truth: GroundTruth | None,
) -> dict:
    """The dataset.json fields every dataset has (DatasetWriter, DatasetRecorder, hec.estimator.io.memory)."""
    return {
        "format": FORMAT,
        "version": VERSION,
        "source": source,
        "frame_count": frame_count,
        "camera": None if intrinsics is None else intrinsics.to_dict(),
        "depth_scale_m": depth_scale_m,
        "depth": "aligned to the colour image, along the optical axis; 0 = no depth",
        "flange_pose": "reported T_base_flange: tool0 in the base frame; metres, quaternion w x y z",
        "board_file": "board.json",
        "frames_file": "frames.csv",
        "ground_truth_file": "ground_truth.json" if ground_truth is not None else None,
    }


def load_dataset(path: str | Path) -> Dataset:
    """Open and validate a dataset folder; errors name the file and the field."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such dataset folder")
    meta_path = root / "dataset.json"
    meta = read_json_object(meta_path, DatasetError)
    fields = validated(DatasetMeta, meta, str(meta_path), DatasetError)
    intrinsics = None if fields.camera is None else fields.camera.intrinsics()
    try:
        board = None if fields.board_file is None else load_board(root / fields.board_file)
    except BoardDefinitionError as exc:
        raise DatasetError(str(exc)) from None
    rows = read_frames(root / fields.frames_file)
    if len(rows) != fields.frame_count:
        raise DatasetError(
            f"{meta_path}: 'frame_count' is {fields.frame_count} but frames.csv has {len(rows)} rows"
        )
    truth = None
    if fields.ground_truth_file:
        truth = read_ground_truth(root / fields.ground_truth_file)
    return Dataset(root, meta, intrinsics, board, fields.depth_scale_m, rows, truth)


def read_ground_truth(path: Path) -> GroundTruth:
    """The ground truth of a simulated dataset (ground_truth.json); errors name the file and field."""
    gt = validated(GroundTruthFile, read_json_object(path, DatasetError), str(path), DatasetError)
    unknowns = {}
    if gt.setup == EYE_TO_HAND:
        unknowns = {"T_base_cam": gt.T_base_cam, "T_flange_board": gt.T_flange_board}
    return GroundTruth(
        gt.T_flange_cam,
        gt.T_base_board,
        gt.T_world_base,
        gt.model_errors,
        [f.T_base_flange for f in gt.frames],
        [np.array(f.joints_rad) for f in gt.frames],
        **unknowns,
    )


def joint_columns(fieldnames: list[str]) -> tuple[str, ...]:
    """The joint columns of a frames.csv header: q1_rad, q2_rad, ... as far as they run unbroken."""
    count = 0
    while f"q{count + 1}_rad" in fieldnames:
        count += 1
    return frame_columns(count)[len(POSE_COLUMNS) :]


def read_frames(path: Path) -> list[dict]:
    """frames.csv's rows: frame, time_s, rgb and depth (file names, '' when absent), T_base_flange
    (4, 4), joints (N,), waypoint (or None); errors name the file and the line."""
    if not path.is_file():
        raise DatasetError(f"{path}: file missing")
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        fieldnames = reader.fieldnames or []
        missing = [c for c in POSE_COLUMNS if c not in fieldnames]
        if missing:
            raise DatasetError(f"{path}: missing columns {missing}")
        number_columns = (*POSE_COLUMNS[4:], *joint_columns(list(fieldnames)))
        rows = []
        for line, raw in enumerate(reader, start=2):
            try:
                values = [float(raw[c]) for c in number_columns]
                if not np.all(np.isfinite([*values, float(raw["time_s"])])):
                    raise DatasetError(f"{path}: line {line}: values must be finite")
                if int(raw["frame"]) != len(rows):
                    raise DatasetError(f"{path}: line {line}: frame {raw['frame']}, expected {len(rows)}")
                rows.append(
                    {
                        "frame": int(raw["frame"]),
                        "time_s": float(raw["time_s"]),
                        "rgb": raw["rgb"],
                        "depth": raw["depth"],
                        "T_base_flange": transform_from_xyz_quat(np.array(values[:3]), np.array(values[3:7])),
                        "joints": np.array(values[7:]),
                        "waypoint": int(raw["waypoint"]) if raw.get("waypoint") else None,
                    }
                )
            except (TypeError, ValueError) as exc:
                raise DatasetError(f"{path}: line {line}: bad value ({exc})") from None
    _refuse_shared_images(path, rows)
    return rows


def _refuse_shared_images(path: Path, rows: list[dict]) -> None:
    """DatasetError when two frames name one image (a row pointing at another frame's picture, or a
    row written twice): each frame's image is its own."""
    seen: dict[str, int] = {}
    for row in rows:
        for column in ("rgb", "depth"):
            name = row[column]
            if not name:
                continue
            if name in seen:
                raise DatasetError(
                    f"{path}: frames {seen[name]} and {row['frame']} both name {name} (lines "
                    f"{seen[name] + 2} and {row['frame'] + 2}); each frame has its own image: correct the "
                    f"{column} of the wrong one"
                )
            seen[name] = row["frame"]
