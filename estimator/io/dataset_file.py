"""The JSON files of a dataset folder (the format: hec.estimator.io.dataset): dataset.json's
fields hec reads, its camera, and ground_truth.json, declared once as pydantic models.

dataset.json carries notes for a person (what the depth and the flange poses are) and what made
the dataset (scenario, cell file, noise settings, an import's conventions); those keys are
allowed and kept as they are in Dataset.meta.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import ConfigDict, Field, PlainValidator, model_validator

from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND, SETUPS
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import JOINT_ORDERS
from hec.estimator.io.pose_file import DIRECTIONS, ROTATIONS
from hec.estimator.io.schema import FileFormat, Integer, Number, Positive, Text


def _transform(value: object) -> np.ndarray:
    """value as a (4, 4) float array of finite numbers, as written (ground truth is exact)."""
    try:
        T = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("must be a 4x4 list of numbers") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"must be a 4x4 list of finite numbers, got shape {T.shape}")
    return T


Transform = Annotated[Any, PlainValidator(_transform)]


class CameraEntry(FileFormat):
    """dataset.json's 'camera': pixels, OpenCV's pinhole model and its distortion (k1 k2 p1 p2 k3)."""

    model_config = ConfigDict(extra="allow")

    width: Integer = Field(gt=0, description="should be an integer > 0 (pixels)")
    height: Integer = Field(gt=0, description="should be an integer > 0 (pixels)")
    fx: Positive = Field(description="should be a number > 0 (pixels)")
    fy: Positive = Field(description="should be a number > 0 (pixels)")
    cx: Number = Field(description="should be a number (pixels)")
    cy: Number = Field(description="should be a number (pixels)")
    dist: list[Number] = Field([0.0] * 5, description="should be a list of numbers (k1 k2 p1 p2 k3 ...)")

    def intrinsics(self) -> CameraIntrinsics:
        return CameraIntrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy, tuple(self.dist))


class PoseConventionEntry(FileFormat):
    """What the imported pose file's numbers meant (hec.estimator.io.pose_file.PoseConvention)."""

    rotation: Literal[ROTATIONS] = Field(description=f"should be one of {', '.join(ROTATIONS)}")
    angle_unit: Literal["rad", "deg"] = Field(description="should be 'rad' or 'deg'")
    length_unit: Literal["m", "mm"] = Field(description="should be 'm' or 'mm'")
    direction: Literal[DIRECTIONS] = Field(description=f"should be one of {', '.join(DIRECTIONS)}")


class JointsEntry(FileFormat):
    """How the imported joint file wrote its angles."""

    unit: Literal["rad", "deg"] = Field(description="should be 'rad' or 'deg'")
    order: Literal[JOINT_ORDERS] = Field(description=f"should be one of {', '.join(JOINT_ORDERS)}")


class ImportProvenance(FileFormat):
    """dataset.json's 'provenance' of an import (hec.estimator.io.importer.provenance): what the
    checks of an import read back (the pose convention and numbers, the joints' order) declared;
    the record's other entries (sources, images, pairing, version, time) allowed as written."""

    model_config = ConfigDict(extra="allow")

    layout: Text = Field(description="should be the layout's name")
    pose_convention: PoseConventionEntry | None = None
    pose_values: list[list[Number]] | None = Field(None, description="should be a list of rows of numbers")
    joints: JointsEntry | None = None

    @model_validator(mode="after")
    def _values_with_convention(self) -> ImportProvenance:
        if (self.pose_values is None) != (self.pose_convention is None):
            raise ValueError("field 'provenance': 'pose_values' and 'pose_convention' come together")
        return self


class DatasetMeta(FileFormat):
    """What hec reads of dataset.json. A dataset of pose pairs (an import of hand-eye pairs, no
    images) may have no camera and no board."""

    model_config = ConfigDict(extra="allow")

    format: Literal["hec-dataset"] = Field(description="should be 'hec-dataset'")
    version: Literal[1] = Field(description="should be 1")
    camera: CameraEntry | None = Field(description="should be the camera's intrinsics")
    depth_scale_m: Positive = Field(description="should be a number > 0 (metres per depth unit)")
    frame_count: Integer = Field(ge=0, description="should be an integer >= 0")
    board_file: Text | None = Field("board.json", description="should be a file name")
    frames_file: Text = Field("frames.csv", description="should be a file name")
    ground_truth_file: Text | None = Field(None, description="should be a file name")
    pose_pairs_file: Text | None = Field(None, description="should be a file name")
    provenance: ImportProvenance | None = None

    @model_validator(mode="after")
    def _images_described(self) -> DatasetMeta:
        if not self.pose_pairs_file:
            for key in ("camera", "board_file"):
                if getattr(self, key) is None:
                    raise ValueError(f"field '{key}' is null; only a dataset of pose pairs may leave it out")
        return self


class GroundTruthFrame(FileFormat):
    model_config = ConfigDict(extra="allow")

    frame: Integer = Field(ge=0, description="should be an integer >= 0")
    T_base_flange: Transform
    joints_rad: list[Number] = Field(description="should be a list of numbers (radians)")


class GroundTruthFile(FileFormat):
    """ground_truth.json: eye-in-hand T_flange_cam and T_base_board, eye-to-hand (with 'setup')
    T_base_cam and T_flange_board; the world's base pose and each frame's true flange pose and
    joints; model_errors: the simulated cell's departures from its model, when it had some."""

    model_config = ConfigDict(extra="allow")

    setup: Literal["eye-in-hand", "eye-to-hand"] = Field(
        EYE_IN_HAND, description=f"should be one of {', '.join(SETUPS)}"
    )
    T_flange_cam: Transform | None = None
    T_base_board: Transform | None = None
    T_base_cam: Transform | None = None
    T_flange_board: Transform | None = None
    T_world_base: Transform
    model_errors: dict | None = None
    frames: list[GroundTruthFrame]

    @model_validator(mode="after")
    def _unknowns_given(self) -> GroundTruthFile:
        keys = (
            ("T_base_cam", "T_flange_board")
            if self.setup == EYE_TO_HAND
            else ("T_flange_cam", "T_base_board")
        )
        for key in keys:
            if getattr(self, key) is None:
                raise ValueError(f"missing field '{key}' (a 4x4 matrix, metres)")
        return self
