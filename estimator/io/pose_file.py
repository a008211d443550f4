"""Robot poses in other people's conventions: what a pose file's numbers mean, and reading one.

A pose is written as a translation then a rotation, one pose per row (CSV) or entry (JSON):

- ``quat-wxyz`` / ``quat-xyzw``: x y z then a unit quaternion, scalar first / last (7 numbers);
- ``rotvec``: x y z then a rotation vector (axis times angle), as UR controllers report (6);
- ``euler-SEQ``: x y z then three angles about the axes SEQ in order, scipy's convention: lower
  case (``xyz``) about the fixed axes, upper case (``XYZ``) about the moving ones (6);
- ``matrix``: the 4x4 homogeneous matrix, row-major (16).

Angles in ``rad`` or ``deg`` (rotvec and Euler), lengths in ``m`` or ``mm``. Direction
``base-to-flange``: each pose is T_base_flange, the flange in the base frame (UR's and ROS tf's
base -> tool0); ``flange-to-base``: each is its inverse, T_flange_base.

The files (CSV with or without a header, JSON, numpy) are read as hec.estimator.io.pose_table
says: a column named ``image`` names the pose's image, the others are the pose's numbers, in order,
or by their names when those say which number each is (columns_by_name). A joint file is read the
same way, one row of joint angles per image.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.transforms import invert
from hec.estimator.io.pose_table import NumberTable, PoseFileError, read_number_table

EULER_SEQUENCES = tuple(
    s for case in (str.lower, str.upper) for s in map(case, ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx"))
)
ROTATIONS = ("quat-wxyz", "quat-xyzw", "rotvec", "matrix", *(f"euler-{s}" for s in EULER_SEQUENCES))
DIRECTIONS = ("base-to-flange", "flange-to-base")
# A rotation matrix whose R^T R is off identity by more than this is not one.
ORTHONORMAL_TOLERANCE = 1e-4
UNIT_QUATERNION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class PoseConvention:
    """What a pose file's numbers mean (module doc)."""

    rotation: str = "quat-wxyz"
    angle_unit: str = "rad"
    length_unit: str = "m"
    direction: str = "base-to-flange"

    def __post_init__(self) -> None:
        for name, value, allowed in (
            ("rotation", self.rotation, ROTATIONS),
            ("angle_unit", self.angle_unit, ("rad", "deg")),
            ("length_unit", self.length_unit, ("m", "mm")),
            ("direction", self.direction, DIRECTIONS),
        ):
            if value not in allowed:
                raise PoseFileError(
                    f"pose convention: {name} must be one of {', '.join(allowed)}, got {value!r}"
                )

    @property
    def values_per_pose(self) -> int:
        return {"matrix": 16, "quat-wxyz": 7, "quat-xyzw": 7}.get(self.rotation, 6)

    def to_dict(self) -> dict:
        return {
            "rotation": self.rotation,
            "angle_unit": self.angle_unit,
            "length_unit": self.length_unit,
            "direction": self.direction,
        }


# What a pose file's column names say, read without units ("x_m", "rx [rad]") and with ROS's nesting
# ("position.x", "orientation.w"): each names one number.
_ALIASES = {
    **{a: a for a in ("x", "y", "z")},
    **{f"{p}{a}": a for a in ("x", "y", "z") for p in ("t", "pos_", "position.", "translation.", "t_")},
    **{
        f"{p}{a}": f"q{a}"
        for a in ("x", "y", "z", "w")
        for p in ("q", "quat_", "q_", "orientation.", "rotation.")
    },
    **{f"{p}{a}": f"r{a}" for a in ("x", "y", "z") for p in ("r", "rot_", "rvec_", "r_")},
}
_UNIT = re.compile(r"\s*[_ ]?\[?(m|mm|rad|deg)\]?$")
_NAMED_ORDER = {
    "quat-wxyz": ("x", "y", "z", "qw", "qx", "qy", "qz"),
    "quat-xyzw": ("x", "y", "z", "qx", "qy", "qz", "qw"),
    "rotvec": ("x", "y", "z", "rx", "ry", "rz"),
}


def columns_by_name(table: NumberTable, convention: PoseConvention) -> NumberTable:
    """The table with its numbers in the convention's order when the columns' names say which is which
    (x y z with qx qy qz qw, or with rx ry rz for rotvec: _ALIASES), in whatever order they came; a
    table whose names are not all known keeps its order. PoseFileError when the names say a
    quaternion and the convention is not one."""
    if table.columns is None:
        return table
    named = [_ALIASES.get(_UNIT.sub("", c.strip().lower()).split("/")[-1]) for c in table.columns]
    if None in named or len(set(named)) != len(named):
        return table
    if set(named) == set(_NAMED_ORDER["quat-xyzw"]) and convention.rotation not in ("quat-wxyz", "quat-xyzw"):
        raise PoseFileError(
            f"{table.path}: the numbers are named as a position and a quaternion "
            f"({', '.join(table.columns)}) but the rotation is read as {convention.rotation}: pass "
            "--rotation quat-xyzw (the numbers are then read by their names, in any order)"
        )
    wanted = _NAMED_ORDER.get(convention.rotation)
    if wanted is None or set(named) != set(wanted):
        return table
    order = [named.index(name) for name in wanted]
    if order == list(range(len(order))):
        return table
    return replace(
        table,
        values=table.values[:, order],
        columns=[table.columns[i] for i in order],
        layout=f"{table.layout}, numbers read by their names ({', '.join(table.columns[i] for i in order)})",
    )


def poses_from_values(values: np.ndarray, convention: PoseConvention, where: str = "poses") -> np.ndarray:
    """(N, 4, 4) T_base_flange (metres) from (N, k) numbers in a convention; where: what the
    numbers are, for the errors (which name the row)."""
    values = np.asarray(values, dtype=np.float64)
    k = convention.values_per_pose
    if values.ndim != 2 or values.shape[1] != k:
        hint = " (4x4 matrices? pass --rotation matrix)" if values.ndim == 2 and values.shape[1] == 16 else ""
        raise PoseFileError(
            f"{where}: a {convention.rotation} pose has {k} numbers, got shape {values.shape}{hint}"
        )
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        raise PoseFileError(f"{where}: pose {int(np.argmax(bad))} has a NaN or infinite number")
    scale = 1e-3 if convention.length_unit == "mm" else 1.0
    T = np.tile(np.eye(4), (len(values), 1, 1))
    if convention.rotation == "matrix":
        T[:] = values.reshape(-1, 4, 4)
        T[:, :3, 3] *= scale
        _check_matrices(T, where)
    else:
        T[:, :3, 3] = scale * values[:, :3]
        T[:, :3, :3] = _rotations(values[:, 3:], convention, where)
    return T if convention.direction == "base-to-flange" else np.array([invert(t) for t in T])


def values_from_poses(T_base_flange: np.ndarray, convention: PoseConvention) -> np.ndarray:
    """(N, k) the numbers of (N, 4, 4) T_base_flange (metres) in a convention: poses_from_values'
    inverse (quaternions with a non-negative scalar)."""
    T = np.asarray(T_base_flange, dtype=np.float64)
    if convention.direction == "flange-to-base":
        T = np.array([invert(t) for t in T])
    scale = 1e3 if convention.length_unit == "mm" else 1.0
    if convention.rotation == "matrix":
        out = T.copy()
        out[:, :3, 3] *= scale
        return out.reshape(-1, 16)
    rotation, degrees = Rotation.from_matrix(T[:, :3, :3]), convention.angle_unit == "deg"
    if convention.rotation.startswith("quat"):
        wxyz = convention.rotation == "quat-wxyz"
        angles = rotation.as_quat(canonical=True, scalar_first=wxyz)
    elif convention.rotation == "rotvec":
        angles = rotation.as_rotvec(degrees=degrees)
    else:
        angles = rotation.as_euler(convention.rotation.removeprefix("euler-"), degrees=degrees)
    return np.column_stack([scale * T[:, :3, 3], angles])


def _rotations(angles: np.ndarray, convention: PoseConvention, where: str) -> np.ndarray:
    """(N, 3, 3) from the rotation numbers (N, 3) or (N, 4)."""
    rotation, degrees = convention.rotation, convention.angle_unit == "deg"
    if rotation.startswith("quat"):
        norm = np.linalg.norm(angles, axis=1)
        off = np.abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE
        if off.any():
            i = int(np.argmax(off))
            raise PoseFileError(
                f"{where}: pose {i}'s quaternion has norm {norm[i]:.4g}, not 1 (is it another rotation kind?)"
            )
        return Rotation.from_quat(angles, scalar_first=rotation == "quat-wxyz").as_matrix()
    if rotation == "rotvec":
        return Rotation.from_rotvec(angles, degrees=degrees).as_matrix()
    return Rotation.from_euler(rotation.removeprefix("euler-"), angles, degrees=degrees).as_matrix()


def _check_matrices(T: np.ndarray, where: str) -> None:
    R = T[:, :3, :3]
    error = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
    bottom = np.abs(T[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1)
    bad = (error > ORTHONORMAL_TOLERANCE) | (bottom > 1e-9) | (np.linalg.det(R) < 0.0)
    if bad.any():
        i = int(np.argmax(bad))
        raise PoseFileError(
            f"{where}: pose {i} is not a rigid transform (rotation part off orthonormal by {error[i]:.2g}, "
            f"last row {T[i, 3].tolist()}); is the matrix column-major or scaled?"
        )


def read_pose_file(path: str | Path, convention: PoseConvention) -> tuple[list[str] | None, np.ndarray]:
    """The image names (None without an image column) and the (N, 4, 4) T_base_flange of a pose
    file (hec.estimator.io.pose_table) in a convention."""
    table = read_number_table(path)
    return table.names, poses_from_values(table.values, convention, where=str(path))
