"""Reading a calibration result file (`hec calibrate --json`, format CALIBRATION_FORMAT): the mount
T_flange_cam, its covariance and what the run learned about the noise, validated once, with errors
naming the file and the field.

A `--method all` file holds one result per entry of 'results'; `method` picks one of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import ConfigDict, Field, PlainValidator, model_validator

from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.common.noise import LearnedNoiseLevels
from hec.estimator.common.setups import EYE_IN_HAND, HAND_EYE_NAMES, SETUPS
from hec.estimator.io.schema import FileFormat, Flag, Number, Positive, Text, validated

CALIBRATION_FORMAT = "hec-calibration"
CALIBRATION_VERSION = 1
ROTATION_TOLERANCE = 1e-5  # max |R^T R - I| entry accepted for a rotation read from a file


class CalibrationFileError(ValueError):
    """A calibration file is missing, of another format, or has a bad field."""


def _matrix(value: object, shape: tuple[int, int]) -> np.ndarray:
    """value as a finite float array of the given shape; a ValueError saying what it must be."""
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"must be a {shape[0]}x{shape[1]} list of numbers") from None
    if matrix.shape != shape or not np.all(np.isfinite(matrix)):
        raise ValueError(f"must be a {shape[0]}x{shape[1]} list of finite numbers, got shape {matrix.shape}")
    return matrix


def _pose(value: object) -> np.ndarray:
    """value as a (4, 4) rigid transform, its rotation re-orthonormalised; a ValueError when it is not one."""
    T = _matrix(value, (4, 4))
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) < 0:
        raise ValueError("must have a rotation (orthonormal, determinant +1) in its upper-left 3x3")
    if np.abs(T[3] - [0, 0, 0, 1]).max() > 0:
        raise ValueError("must have the last row 0 0 0 1")
    U, _, Vt = np.linalg.svd(R)
    T[:3, :3] = U @ Vt
    return T


def _covariance(value: object) -> np.ndarray:
    """value as a (6, 6) symmetric positive definite matrix; a ValueError when it is not one."""
    cov = _matrix(value, (6, 6))
    if np.abs(cov - cov.T).max() > 1e-9 * np.abs(cov).max() or np.linalg.eigvalsh(cov)[0] <= 0:
        raise ValueError("must be symmetric positive definite")
    return cov


# A (4, 4) rigid transform and a (6, 6) covariance in a JSON file, read to arrays.
Pose = Annotated[Any, PlainValidator(_pose)]
Covariance = Annotated[Any, PlainValidator(_covariance)]


def pose_field(data: dict, key: str, path: Path, error: type[Exception]) -> np.ndarray:
    """data[key] as a (4, 4) rigid transform (its rotation re-orthonormalised); raises error naming
    path and key when it is not one."""
    return _field(_pose, data, key, path, error)


def covariance_field(data: dict, key: str, path: Path, error: type[Exception]) -> np.ndarray:
    """data[key] as a (6, 6) symmetric positive definite matrix; raises error naming path and key."""
    return _field(_covariance, data, key, path, error)


def _field(
    read: Callable[[object], np.ndarray], data: dict, key: str, path: Path, error: type[Exception]
) -> np.ndarray:
    try:
        return read(data[key])
    except ValueError as exc:
        raise error(f"{path}: field '{key}' {exc}") from None


class LearnedLevelsEntry(FileFormat):
    """'noise.learned': the scales learned on the pixel and depth noise, the robot's sigmas."""

    model_config = ConfigDict(extra="allow")

    pixel_scale: Positive = Field(description="should be a number > 0")
    depth_scale: Positive = Field(description="should be a number > 0")
    robot_translation_sigma_m: Number = Field(description="should be a number (metres)")
    robot_rotation_sigma_rad: Number = Field(description="should be a number (radians)")


class LearnedValueEntry(FileFormat):
    model_config = ConfigDict(extra="allow")

    value: Number = Field(description="should be a number")


class SelfCalibrationEntry(FileFormat):
    model_config = ConfigDict(extra="allow")

    values: dict[str, LearnedValueEntry] = {}


class DepthCheckEntry(FileFormat):
    model_config = ConfigDict(extra="allow")

    used: Flag = Field(True, description="should be true or false")


class NoiseEntry(FileFormat):
    """'noise': what the run learned (hec.estimator.solve.noise_learning.LearnedNoise's to_dict)."""

    model_config = ConfigDict(extra="allow")

    learned: LearnedLevelsEntry
    self_calibration: SelfCalibrationEntry | None = None
    depth_check: DepthCheckEntry | None = None

    def levels(self) -> LearnedNoiseLevels:
        values = self.self_calibration.values if self.self_calibration else {}
        return LearnedNoiseLevels(
            self.learned.pixel_scale,
            self.learned.depth_scale,
            self.learned.robot_translation_sigma_m,
            self.learned.robot_rotation_sigma_rad,
            {name: v.value for name, v in values.items()},
            self.depth_check.used if self.depth_check else True,
        )


class CalibrationResultEntry(FileFormat):
    """One result of a calibration file (CalibrationFile's fields); the run's other figures are
    allowed and passed on as they are."""

    model_config = ConfigDict(extra="allow")

    method: Text = "?"
    setup: Literal["eye-in-hand", "eye-to-hand"] = Field(
        EYE_IN_HAND, description=f"should be one of {', '.join(SETUPS)}"
    )
    T_flange_cam: Pose | None = None
    T_base_cam: Pose | None = None
    covariance: Covariance | None = None
    noise: NoiseEntry | None = None
    depth_scale: Number | None = Field(None, description="should be a number")
    use_depth: Flag = Field(True, description="should be true or false")
    pose_frame: Text = Field("flange", description="should be a string")
    dataset: Text | None = Field(None, description="should be a string")

    @model_validator(mode="after")
    def _transform_given(self) -> CalibrationResultEntry:
        key = HAND_EYE_NAMES[self.setup]
        if getattr(self, key) is None:
            raise ValueError(f"missing field '{key}' (a 4x4 matrix, metres)")
        return self


def learned_noise_levels(noise: dict | None, path: Path) -> LearnedNoiseLevels | None:
    """The levels of a calibration's 'noise' object (hec.estimator.solve.noise_learning.LearnedNoise's
    to_dict), None without one; raises CalibrationFileError naming path and the field when it is
    malformed."""
    if noise is None:
        return None
    return validated(NoiseEntry, noise, f"{path}: field 'noise'", CalibrationFileError).levels()


@dataclass(frozen=True)
class CalibrationFile:
    """One result of a calibration file. T_flange_cam: (4, 4), metres (the camera optical frame in the
    flange frame). covariance: (6, 6) in the file's 'covariance_convention', None when the method gave
    none. noise: the learned levels, None when the method did not learn them. pose_frame: 'flange' or
    'tcp' (what the robot reported). data: the result's JSON object as read (with the file's context
    keys), for the figures passed on as they are. setup: 'eye-in-hand', or 'eye-to-hand', whose file
    names the transform T_base_cam (the camera fixed in the base frame): T_flange_cam then holds it,
    as the calibration's result did (hec.estimator.solve.setup_roles), and its covariance's dt is
    along the base axes."""

    path: Path
    method: str
    T_flange_cam: np.ndarray
    covariance: np.ndarray | None
    noise: LearnedNoiseLevels | None
    depth_scale: float | None
    use_depth: bool
    pose_frame: str
    dataset: str | None
    data: dict
    setup: str = EYE_IN_HAND

    @property
    def hand_eye_name(self) -> str:
        """The name of the transform T_flange_cam holds: 'T_flange_cam' or 'T_base_cam'."""
        return HAND_EYE_NAMES[self.setup]


def _pick_result(data: dict, path: Path, method: str | None) -> dict:
    if "results" not in data:
        if method is not None and data.get("method") != method:
            raise CalibrationFileError(f"{path}: holds a '{data.get('method')}' result, not '{method}'")
        return data
    names = set(HAND_EYE_NAMES.values())
    results = [r for r in data["results"] if isinstance(r, dict) and names & set(r)]
    names = [r.get("method") for r in results]
    if method is None:
        raise CalibrationFileError(
            f"{path}: holds the results of several methods ({', '.join(map(str, names))}); name one "
            "with --method"
        )
    if method not in names:
        raise CalibrationFileError(f"{path}: no result of method '{method}' (it has {', '.join(names)})")
    context = {k: v for k, v in data.items() if k != "results"}
    return context | results[names.index(method)]


def read_calibration(path: Path, method: str | None = None) -> CalibrationFile:
    """The calibration in a `hec calibrate --json` file (with several methods' results: method's).
    Raises CalibrationFileError naming the file and field: missing, not JSON, another format (a
    dataset, detections, a sweep's rows), a bad T_flange_cam or covariance."""
    path = Path(path)
    data = read_json_object(path, CalibrationFileError)
    fmt = data.get("format")
    if fmt is not None and fmt != CALIBRATION_FORMAT:
        raise CalibrationFileError(
            f"{path}: is a '{fmt}' file, not a calibration (expected the output of hec calibrate --json)"
        )
    if fmt is None and not set(HAND_EYE_NAMES.values()) & set(data) and "results" not in data:
        raise CalibrationFileError(
            f"{path}: not a calibration: no field 'T_flange_cam' "
            "(expected the output of hec calibrate --json)"
        )
    if data.get("version", CALIBRATION_VERSION) != CALIBRATION_VERSION:
        raise CalibrationFileError(
            f"{path}: calibration version {data.get('version')!r}, this hec reads {CALIBRATION_VERSION}"
        )
    result = _pick_result(data, path, method)
    entry = validated(CalibrationResultEntry, result, str(path), CalibrationFileError)
    return CalibrationFile(
        path=path,
        method=entry.method,
        T_flange_cam=getattr(entry, HAND_EYE_NAMES[entry.setup]),
        covariance=entry.covariance,
        noise=None if entry.noise is None else entry.noise.levels(),
        depth_scale=entry.depth_scale,
        use_depth=entry.use_depth,
        pose_frame=entry.pose_frame,
        dataset=entry.dataset,
        data=result,
        setup=entry.setup,
    )
