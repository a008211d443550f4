"""Real-cell files (TOML): the UR arm's address, motion limits and safety box, the RealSense
settings, the board and the noise to write into a recorded dataset.

Every key is optional; models/cells/ur5_d435.toml lists each with its default and unit.
Lengths are metres (keys end in ``_m``), angles degrees (``_deg``), times seconds (``_s``).
Command-line options (``--robot``, ``--camera``) override the file.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.cell_model import (
    CLEARANCE_M,
    FLANGE,
    UR_LINK_CAPSULES,
    Box,
    Capsule,
    CellModel,
)
from hec.estimator.geometry.kinematics import ROBOTS, forward
from hec.estimator.geometry.transforms import transform_from_xyz_rpy
from hec.estimator.io.tomlfile import Section, read_toml, validation_problems
from hec.estimator.observe.depth import DepthNoiseModel
from hec.hardware.camera_settings import FILTERS, RealSenseSettings
from hec.hardware.ur_robot import MotionSettings, SafetyLimits, URRobot

Vector3 = tuple[float, float, float]
Vector6 = tuple[float, float, float, float, float, float]
_UR_JOINT_LIMITS_DEG = (360.0, 360.0, 180.0, 360.0, 360.0, 360.0)  # UR5/UR5e: +-2 pi, elbow +-pi


class CellConfigError(ValueError):
    """A cell file cannot be read or has a bad key."""


class RobotSection(Section):
    """The arm: where it is, how fast it may move, where it may go, and how exact its reports are."""

    host: str | None = None
    model: Literal["ur5", "ur5e"] = "ur5"
    pose_frame: Literal["flange", "tcp"] = "flange"
    joint_speed_deg_s: float = Field(30.0, gt=0, le=180)
    joint_acceleration_deg_s2: float = Field(45.0, gt=0, le=360)
    settle_speed_deg_s: float = Field(0.06, gt=0)
    dwell_s: float = Field(0.5, ge=0)
    settle_timeout_s: float = Field(10.0, gt=0)
    workspace_lower_m: Vector3 = (-1.0, -1.0, -1.0)
    workspace_upper_m: Vector3 = (1.0, 1.0, 1.0)
    joint_lower_deg: Vector6 = tuple(-v for v in _UR_JOINT_LIMITS_DEG)
    joint_upper_deg: Vector6 = _UR_JOINT_LIMITS_DEG
    wrist_cable_limit_deg: float = Field(180.0, gt=0, le=720)
    pose_sigma_mm: float = Field(0.1, ge=0)
    pose_sigma_deg: float = Field(0.01, ge=0)

    @model_validator(mode="after")
    def _ordered(self) -> RobotSection:
        if any(lo >= hi for lo, hi in zip(self.workspace_lower_m, self.workspace_upper_m, strict=True)):
            raise ValueError("workspace_lower_m must be below workspace_upper_m on every axis")
        if any(lo >= hi for lo, hi in zip(self.joint_lower_deg, self.joint_upper_deg, strict=True)):
            raise ValueError("joint_lower_deg must be below joint_upper_deg for every joint")
        return self

    def motion(self) -> MotionSettings:
        return MotionSettings(
            joint_speed=float(np.radians(self.joint_speed_deg_s)),
            joint_acceleration=float(np.radians(self.joint_acceleration_deg_s2)),
            settle_speed_rad_s=float(np.radians(self.settle_speed_deg_s)),
            dwell_s=self.dwell_s,
            settle_timeout_s=self.settle_timeout_s,
        )

    def limits(self) -> SafetyLimits:
        return SafetyLimits(
            workspace_lower_m=self.workspace_lower_m,
            workspace_upper_m=self.workspace_upper_m,
            joint_lower_rad=tuple(float(v) for v in np.radians(self.joint_lower_deg)),
            joint_upper_rad=tuple(float(v) for v in np.radians(self.joint_upper_deg)),
        )

    def pose_noise(self) -> RobotPoseNoise:
        return RobotPoseNoise(self.pose_sigma_mm / 1000.0, float(np.radians(self.pose_sigma_deg)))


class CameraSection(Section):
    """The RealSense: which one, its streams, the capture burst, and its depth noise model."""

    serial: str | None = None
    colour_size: tuple[int, int] = (1280, 720)
    depth_size: tuple[int, int] = (848, 480)
    fps: int = Field(30, gt=0)
    burst: int = Field(10, ge=1, le=255)
    warmup_frames: int = Field(30, ge=0)
    timeout_s: float = Field(5.0, gt=0)
    filters: tuple[Literal[FILTERS], ...] = ()
    depth_units_m: float | None = Field(1e-4, gt=0, le=0.01)
    depth_subpixel: float = Field(0.08, ge=0)
    depth_baseline_m: float = Field(0.050, gt=0)
    depth_focal_px: float = Field(425.0, gt=0)
    depth_correlation_px: float = Field(1.0, ge=1)

    def realsense(self) -> RealSenseSettings:
        return RealSenseSettings(
            serial=self.serial,
            colour_size=self.colour_size,
            depth_size=self.depth_size,
            fps=self.fps,
            burst=self.burst,
            warmup_frames=self.warmup_frames,
            timeout_s=self.timeout_s,
            filters=self.filters,
            depth_units_m=self.depth_units_m,
        )

    def depth_noise(self, depth_scale_m: float) -> DepthNoiseModel:
        """The per-pixel depth noise written to the dataset, with the camera's depth step."""
        return DepthNoiseModel(
            self.depth_subpixel,
            self.depth_baseline_m,
            self.depth_focal_px,
            depth_scale_m,
            self.depth_correlation_px,
        )


class FlangePartSection(Section):
    """Something carried by the flange (the camera, its cable): a capsule, the points within
    radius_m of the segment from_m..to_m in the flange frame (tool0), metres."""

    name: str
    from_m: Vector3
    to_m: Vector3
    radius_m: float = Field(gt=0)


class ObstacleSection(Section):
    """Something in the cell the arm must not touch: a box in the base frame, its centre, its half
    sizes along its axes, and its axes turned by roll-pitch-yaw (fixed x, y, z) from the base's."""

    name: str
    centre_m: Vector3
    half_size_m: Vector3
    rotation_rpy_deg: Vector3 = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _positive(self) -> ObstacleSection:
        if min(self.half_size_m) <= 0:
            raise ValueError("half_size_m must be positive on every axis")
        return self


# The simulated cell's camera at its default mount (hec.estimator.geometry.cell_model.camera_parts,
# rounded up to the millimetre) and its cable, in the flange frame.
_DEFAULT_FLANGE_PARTS = (
    FlangePartSection(
        name="camera", from_m=(-0.045, 0.006, 0.026), to_m=(0.045, 0.006, 0.026), radius_m=0.018
    ),
    FlangePartSection(
        name="camera cable", from_m=(0.045, 0.006, 0.026), to_m=(0.045, 0.006, -0.074), radius_m=0.01
    ),
)
# The simulated cell's (models/cell.xml with the default scenario's board on its table), in the base
# frame: y up, z out of the wall.
_DEFAULT_OBSTACLES = (
    ObstacleSection(name="wall", centre_m=(0.0, 0.05, -0.05), half_size_m=(1.5, 1.5, 0.05)),
    ObstacleSection(name="floor", centre_m=(0.0, -1.46, 1.5), half_size_m=(1.5, 0.01, 1.5)),
    ObstacleSection(name="table top", centre_m=(0.15, -0.723, 0.45), half_size_m=(0.5, 0.02, 0.32)),
    ObstacleSection(name="table leg", centre_m=(0.15, -1.0965, 0.45), half_size_m=(0.04, 0.3535, 0.04)),
    ObstacleSection(name="board", centre_m=(0.15, -0.702, 0.45), half_size_m=(0.2, 0.001, 0.11)),
)


class CellModelSection(Section):
    """What the planner checks every move's path against before the arm moves
    (hec.estimator.geometry.cell_model): the arm's links, flange_parts and obstacles, every part
    kept clearance_m from every obstacle."""

    clearance_m: float = Field(CLEARANCE_M, ge=0)
    flange_parts: tuple[FlangePartSection, ...] = _DEFAULT_FLANGE_PARTS
    obstacles: tuple[ObstacleSection, ...] = _DEFAULT_OBSTACLES

    def cell_model(self, model: str) -> CellModel:
        """The cell model of the arm `model` (a name in ROBOTS) with these parts and obstacles."""
        parts = tuple(Capsule(p.name, FLANGE, p.from_m, p.to_m, p.radius_m) for p in self.flange_parts)
        obstacles = tuple(
            Box(
                o.name,
                transform_from_xyz_rpy(np.array(o.centre_m), np.radians(o.rotation_rpy_deg)),
                o.half_size_m,
            )
            for o in self.obstacles
        )
        return CellModel(ROBOTS[model], UR_LINK_CAPSULES + parts, obstacles, self.clearance_m)


class CellConfig(Section):
    """board: the printed board. setup: 'eye-in-hand' (the camera on the flange) or 'eye-to-hand' (the
    camera fixed in the cell, the board on the flange; recorded in the dataset)."""

    board: str = "hec_8qr"
    setup: Literal["eye-in-hand", "eye-to-hand"] = "eye-in-hand"
    robot: RobotSection = RobotSection()
    camera: CameraSection = CameraSection()
    cell_model: CellModelSection = CellModelSection()

    def to_dict(self) -> dict:
        return self.model_dump(mode="json")

    def robot_host(self, option: str | None) -> str:
        """--robot HOST, else robot.host; CellConfigError when neither gives one."""
        host = option or self.robot.host
        if not host:
            raise CellConfigError("no robot address: give --robot HOST or robot.host in the cell file")
        return host

    def open_robot(self, host: str, read_only: bool = False) -> URRobot:
        """The arm at host with this file's limits, workspace checked with its model's kinematics."""
        kinematics = ROBOTS[self.robot.model]
        return URRobot(
            host,
            self.robot.motion(),
            self.robot.limits(),
            forward=lambda q: forward(kinematics, q),
            read_only=read_only,
        )

    def camera_settings(self, serial_option: str | None) -> RealSenseSettings:
        """The camera settings with --camera [SERIAL] applied: a serial, "" for the first
        camera found, None to keep camera.serial."""
        settings = self.camera.realsense()
        return settings if serial_option is None else replace(settings, serial=serial_option or None)


def load_cell_config(path: str | Path | None) -> CellConfig:
    """Read and validate a cell file; None gives the defaults."""
    if path is None:
        return CellConfig()
    path = Path(path)
    data = read_toml(path, CellConfigError, "cell")
    try:
        return CellConfig(**data)
    except ValidationError as exc:
        raise CellConfigError(validation_problems(exc, str(path))) from None
