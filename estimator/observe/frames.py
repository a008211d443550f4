"""The data every layer passes around: a frame (RGB-D with the robot's report), a cell's capture,
the simulation's ground truth, and a dataset opened for reading (hec.estimator.io.dataset reads and
writes its folder format)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from hec.estimator.common.depth_png import decode_depth
from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.targets.target import Target

UR_JOINTS = 6


class DatasetError(ValueError):
    """A dataset folder is missing a file or has a bad field."""


@dataclass
class Frame:
    """One RGB-D capture with the robot's report.

    rgb: (H, W, 3) uint8, RGB order. depth_m: (H, W) float32 metres along the
    optical axis, aligned to rgb, 0 = no depth; None for a camera without depth. T_base_flange:
    (4, 4) reported flange pose. joints: (N,) reported joint angles, radians (6 for a UR arm, N = 0
    when unknown). time_s: capture time.
    """

    rgb: np.ndarray
    depth_m: np.ndarray | None
    intrinsics: CameraIntrinsics
    T_base_flange: np.ndarray
    joints: np.ndarray
    time_s: float


@dataclass
class Capture:
    """One view as a cell returns it: the frame; depth_samples (H, W) uint8, the valid depth
    samples averaged per pixel (a camera burst; None when not averaged); and, in simulation,
    the true T_base_flange (4, 4) and joints (6,)."""

    frame: Frame
    depth_samples: np.ndarray | None = None
    true_T_base_flange: np.ndarray | None = None
    true_joints: np.ndarray | None = None


@dataclass
class GroundTruth:
    """Simulation truth: the mount, the board pose and per-frame true flange poses. model_errors:
    the true cell where it differs from what the dataset reports (true kinematics, intrinsics,
    depth registration, printed board; hec.sim.model_errors.TrueCell.to_dict), or None.
    Eye-in-hand: T_flange_cam and T_base_board (4, 4); eye-to-hand: T_base_cam and T_flange_board
    (4, 4) instead, the other two None."""

    T_flange_cam: np.ndarray | None
    T_base_board: np.ndarray | None
    T_world_base: np.ndarray
    model_errors: dict | None = None
    T_base_flange: list[np.ndarray] = field(default_factory=list)
    joints: list[np.ndarray] = field(default_factory=list)
    T_base_cam: np.ndarray | None = None
    T_flange_board: np.ndarray | None = None

    @property
    def setup(self) -> str:
        return EYE_TO_HAND if self.T_base_cam is not None else EYE_IN_HAND

    @property
    def hand_eye(self) -> np.ndarray:
        """(4, 4) the transform a calibration estimates: T_flange_cam (eye-in-hand) or T_base_cam
        (eye-to-hand)."""
        return self.T_base_cam if self.T_base_cam is not None else self.T_flange_cam

    @property
    def board_pose(self) -> np.ndarray:
        """(4, 4) the other unknown: T_base_board (eye-in-hand) or T_flange_board (eye-to-hand)."""
        return self.T_flange_board if self.T_base_cam is not None else self.T_base_board

    def T_cam_board(self, frame: int) -> np.ndarray:
        """(4, 4) the board in the true camera frame of one frame."""
        F = self.T_base_flange[frame]
        if self.T_base_cam is not None:
            return np.linalg.inv(self.T_base_cam) @ F @ self.T_flange_board
        return np.linalg.inv(F @ self.T_flange_cam) @ self.T_base_board


@dataclass
class Dataset:
    """A dataset opened for reading; ``frame(i)`` loads images on demand (held in memory: from frames).
    A dataset of pose pairs (dataset.json 'pose_pairs_file') may have no intrinsics and no board
    (None)."""

    root: Path
    metadata: dict
    intrinsics: CameraIntrinsics | None
    board: Target | None
    depth_scale_m: float
    rows: list[dict]
    ground_truth: GroundTruth | None
    frames: list[Frame] | None = None

    def __len__(self) -> int:
        return len(self.rows)

    def frame(self, i: int) -> Frame:
        if self.frames is not None:
            return self.frames[i]
        row = self.rows[i]
        if not row["rgb"]:
            raise DatasetError(
                f"{self.root / 'frames.csv'}: frame {i} has no image (a dataset of pose pairs: "
                "its observations are pose_pairs.json)"
            )
        rgb = _read_image(self.root / row["rgb"], cv2.IMREAD_COLOR)
        depth_m = None
        if row["depth"]:
            depth = _read_image(self.root / row["depth"], cv2.IMREAD_UNCHANGED)
            if depth.dtype != np.uint16 or depth.ndim != 2:
                raise DatasetError(f"{self.root / row['depth']}: expected a 16-bit single-channel PNG")
            depth_m = decode_depth(depth, self.depth_scale_m)
        return Frame(
            rgb=cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB),
            depth_m=depth_m,
            intrinsics=self.intrinsics,
            T_base_flange=row["T_base_flange"],
            joints=row["joints"],
            time_s=row["time_s"],
        )


def _read_image(path: Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise DatasetError(f"{path}: image file missing")
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DatasetError(f"{path}: not a readable PNG image")
    return image
