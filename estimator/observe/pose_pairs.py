"""Pose-pair observations: per frame, the flange pose and the board's pose in the camera.

What tools such as easy_handeye2 store instead of images: each sample is a reported
T_base_flange and a T_cam_board that the tool's own detector measured. A dataset whose
observations are pose pairs holds them in ``pose_pairs.json`` (format hec-pose-pairs,
version 1) beside ``dataset.json``; it may have no images at all. These observations were
imported, so they are the dataset's own data: nothing regenerates them.

File layout::

    {"format": "hec-pose-pairs", "version": 1,
     "source": {...},                        # where the pairs came from (free-form, kept as read)
     "pairs": [{"frame": 0,
                "T_base_flange": [[...4...] x 4],
                "T_cam_board": [[...4...] x 4],
                "covariance": null | [[...6...] x 6]}, ...]}

covariance: of T_cam_board, (6, 6) over the perturbation (dt, dtheta) of
hec.estimator.geometry.lie (dt in the camera frame, metres; dtheta about the board's axes,
radians), or null when the source gave none (the estimators then learn it).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_json_object

POSE_PAIRS_FILE = "pose_pairs.json"
POSE_PAIRS_FORMAT = "hec-pose-pairs"
POSE_PAIRS_VERSION = 1


class PosePairError(ValueError):
    """A pose-pair file is missing, malformed or holds a pose that is not rigid."""


@dataclass(frozen=True)
class PosePair:
    """One sample. frame: its index in the dataset. T_base_flange, T_cam_board: (4, 4).
    covariance: (6, 6) of T_cam_board (module doc), or None when unknown."""

    frame: int
    T_base_flange: np.ndarray
    T_cam_board: np.ndarray
    covariance: np.ndarray | None = None


def pose_pairs_json(pairs: list[PosePair], source: dict) -> str:
    """The text of a pose_pairs.json holding pairs. source: where the pairs came from."""
    data = {
        "format": POSE_PAIRS_FORMAT,
        "version": POSE_PAIRS_VERSION,
        "source": source,
        "pairs": [
            {
                "frame": p.frame,
                "T_base_flange": np.asarray(p.T_base_flange, dtype=float).tolist(),
                "T_cam_board": np.asarray(p.T_cam_board, dtype=float).tolist(),
                "covariance": None
                if p.covariance is None
                else np.asarray(p.covariance, dtype=float).tolist(),
            }
            for p in pairs
        ],
    }
    return json.dumps(data, indent=1) + "\n"


def write_pose_pairs(path: str | Path, pairs: list[PosePair], source: dict) -> Path:
    """Write pose_pairs.json (through a temporary name). source: where the pairs came from."""
    return write_atomic(Path(path), pose_pairs_json(pairs, source))


def read_pose_pairs(path: str | Path) -> tuple[list[PosePair], dict]:
    """The pairs of a pose_pairs.json and its source; PosePairError naming the file and the field."""
    path = Path(path)
    data = read_json_object(path, PosePairError, "pose-pair file not found")
    if data.get("format") != POSE_PAIRS_FORMAT or data.get("version") != POSE_PAIRS_VERSION:
        raise PosePairError(
            f"{path}: expected 'format': '{POSE_PAIRS_FORMAT}' and 'version': {POSE_PAIRS_VERSION}, "
            f"got {data.get('format')!r} version {data.get('version')!r}"
        )
    entries = data.get("pairs")
    if not isinstance(entries, list) or not entries:
        raise PosePairError(f"{path}: field 'pairs' should be a non-empty list")
    source = data.get("source", {})
    if not isinstance(source, dict):
        raise PosePairError(f"{path}: field 'source' should be an object, got {source!r}")
    pairs = [_pair(entry, f"{path}: pairs[{k}]") for k, entry in enumerate(entries)]
    frames = [p.frame for p in pairs]
    if len(set(frames)) != len(frames):
        raise PosePairError(f"{path}: two pairs have the same 'frame'")
    return pairs, source


def _pair(entry: object, where: str) -> PosePair:
    if not isinstance(entry, dict):
        raise PosePairError(f"{where}: expected an object, got {entry!r}")
    frame = entry.get("frame")
    if not isinstance(frame, int) or isinstance(frame, bool) or frame < 0:
        raise PosePairError(f"{where}.frame: expected an integer >= 0, got {frame!r}")
    covariance = entry.get("covariance")
    if covariance is not None:
        covariance = _matrix(covariance, (6, 6), f"{where}.covariance")
        if not np.allclose(covariance, covariance.T) or np.linalg.eigvalsh(covariance).min() <= 0:
            raise PosePairError(f"{where}.covariance: expected a symmetric positive definite 6x6 matrix")
    return PosePair(
        frame=frame,
        T_base_flange=rigid_transform(entry.get("T_base_flange"), f"{where}.T_base_flange"),
        T_cam_board=rigid_transform(entry.get("T_cam_board"), f"{where}.T_cam_board"),
        covariance=covariance,
    )


def _matrix(value: object, shape: tuple[int, int], where: str) -> np.ndarray:
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        matrix = None
    if matrix is None or matrix.shape != shape or not np.all(np.isfinite(matrix)):
        raise PosePairError(
            f"{where}: expected a {shape[0]}x{shape[1]} matrix of finite numbers, got {value!r}"
        )
    return matrix


# How far a read rotation may be from orthonormal (files hold 6-17 significant digits).
RIGID_TOLERANCE = 1e-6


def rigid_transform(value: object, where: str) -> np.ndarray:
    """A (4, 4) rigid transform from nested lists; PosePairError naming ``where`` if it is not one
    (not 4x4, not finite, last row not 0 0 0 1, rotation not orthonormal with determinant 1)."""
    T = _matrix(value, (4, 4), where)
    R = T[:3, :3]
    if (
        not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=RIGID_TOLERANCE)
        or not np.allclose(R.T @ R, np.eye(3), atol=RIGID_TOLERANCE)
        or np.linalg.det(R) <= 0
    ):
        raise PosePairError(
            f"{where}: not a rigid transform (rotation not orthonormal, or last row not 0 0 0 1)"
        )
    return T
