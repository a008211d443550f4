"""Reading a calibration result file (`hec calibrate --json`, format CALIBRATION_FORMAT): the mount
T_flange_cam, its covariance and what the run learned about the noise, validated once, with errors
naming the file and the field.

A `--method all` file holds one result per entry of 'results'; `method` picks one of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.common.noise import LearnedNoiseLevels
from hec.estimator.common.setups import EYE_IN_HAND, HAND_EYE_NAMES, SETUPS

CALIBRATION_FORMAT = "hec-calibration"
CALIBRATION_VERSION = 1
ROTATION_TOLERANCE = 1e-5  # max |R^T R - I| entry accepted for a rotation read from a file


class CalibrationFileError(ValueError):
    """A calibration file is missing, of another format, or has a bad field."""


def matrix_field(
    data: dict, key: str, shape: tuple[int, int], path: Path, error: type[Exception]
) -> np.ndarray:
    """data[key] as a finite float array of the given shape; raises error naming path and key."""
    try:
        value = np.array(data[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{path}: field '{key}' must be a {shape[0]}x{shape[1]} list of numbers") from None
    if value.shape != shape or not np.all(np.isfinite(value)):
        raise error(
            f"{path}: field '{key}' must be a {shape[0]}x{shape[1]} list of finite numbers, "
            f"got shape {value.shape}"
        )
    return value


def pose_field(data: dict, key: str, path: Path, error: type[Exception]) -> np.ndarray:
    """data[key] as a (4, 4) rigid transform (its rotation re-orthonormalised); raises error naming
    path and key when it is not one."""
    T = matrix_field(data, key, (4, 4), path, error)
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) < 0:
        raise error(
            f"{path}: field '{key}' must have a rotation (orthonormal, determinant +1) in its upper-left 3x3"
        )
    if np.abs(T[3] - [0, 0, 0, 1]).max() > 0:
        raise error(f"{path}: field '{key}' must have the last row 0 0 0 1")
    U, _, Vt = np.linalg.svd(R)
    T[:3, :3] = U @ Vt
    return T


def covariance_field(data: dict, key: str, path: Path, error: type[Exception]) -> np.ndarray:
    """data[key] as a (6, 6) symmetric positive definite matrix; raises error naming path and key."""
    cov = matrix_field(data, key, (6, 6), path, error)
    if np.abs(cov - cov.T).max() > 1e-9 * np.abs(cov).max() or np.linalg.eigvalsh(cov)[0] <= 0:
        raise error(f"{path}: field '{key}' must be symmetric positive definite")
    return cov


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


def learned_noise_levels(noise: dict | None, path: Path) -> LearnedNoiseLevels | None:
    """The levels of a calibration's 'noise' object (hec.estimator.solve.noise_learning.LearnedNoise's
    to_dict), None without one; raises CalibrationFileError naming path when it is malformed."""
    if noise is None:
        return None
    try:
        learned = noise["learned"]
        values = (noise.get("self_calibration") or {}).get("values", {})
        levels = LearnedNoiseLevels(
            float(learned["pixel_scale"]),
            float(learned["depth_scale"]),
            float(learned["robot_translation_sigma_m"]),
            float(learned["robot_rotation_sigma_rad"]),
            {str(name): float(v["value"]) for name, v in values.items()},
            bool((noise.get("depth_check") or {}).get("used", True)),
        )
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CalibrationFileError(f"{path}: field 'noise.learned' is malformed ({exc})") from None
    if not all(np.isfinite(x) and x > 0 for x in (levels.pixel_scale, levels.depth_scale)):
        raise CalibrationFileError(f"{path}: field 'noise.learned' must have positive scales")
    return levels


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
    setup = result.get("setup", EYE_IN_HAND)
    if setup not in HAND_EYE_NAMES:
        raise CalibrationFileError(
            f"{path}: field 'setup' should be one of {', '.join(SETUPS)}, got {setup!r}"
        )
    key = HAND_EYE_NAMES[setup]
    if key not in result:
        raise CalibrationFileError(f"{path}: missing field '{key}' (a 4x4 matrix, metres)")
    covariance = None
    if result.get("covariance") is not None:
        covariance = covariance_field(result, "covariance", path, CalibrationFileError)
    depth_scale = result.get("depth_scale")
    return CalibrationFile(
        path=path,
        method=str(result.get("method", "?")),
        T_flange_cam=pose_field(result, key, path, CalibrationFileError),
        covariance=covariance,
        noise=learned_noise_levels(result.get("noise"), path),
        depth_scale=None if depth_scale is None else float(depth_scale),
        use_depth=bool(result.get("use_depth", True)),
        pose_frame=str(result.get("pose_frame", "flange")),
        dataset=result.get("dataset"),
        data=result,
        setup=setup,
    )
