"""Pose files in other conventions: every convention reads back what it wrote, the numbers mean
what the module says (checked against hand-made poses), and bad files name the file and field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.lie import so3_exp
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.io.pose_file import (
    ROTATIONS,
    PoseConvention,
    PoseFileError,
    poses_from_values,
    read_pose_file,
    values_from_poses,
)


def _poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.array([make_transform(so3_exp(rng.normal(0, 1.0, 3)), rng.normal(0, 0.5, 3)) for _ in range(n)])


@pytest.mark.parametrize("rotation", ROTATIONS)
@pytest.mark.parametrize(
    ("angle", "length", "direction"), [("rad", "m", "base-to-flange"), ("deg", "mm", "flange-to-base")]
)
def test_every_convention_reads_back_what_it_wrote(
    rotation: str, angle: str, length: str, direction: str
) -> None:
    convention = PoseConvention(rotation, angle, length, direction)
    T = _poses(5)
    values = values_from_poses(T, convention)
    assert values.shape == (5, convention.values_per_pose)
    np.testing.assert_allclose(poses_from_values(values, convention), T, atol=1e-12)


def test_the_numbers_mean_what_the_module_says() -> None:
    # 90 degrees about z, then the flange 1 m along x: T_base_flange.
    T = make_transform(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), np.array([1.0, 0, 0]))
    s = np.sqrt(0.5)
    cases = [
        (PoseConvention("quat-wxyz"), [1, 0, 0, s, 0, 0, s]),
        (PoseConvention("quat-xyzw"), [1, 0, 0, 0, 0, s, s]),
        (PoseConvention("rotvec", "deg"), [1, 0, 0, 0, 0, 90]),
        (PoseConvention("euler-xyz", "rad", "mm"), [1000, 0, 0, 0, 0, np.pi / 2]),
        (PoseConvention("matrix"), T.ravel()),
        (PoseConvention("quat-wxyz", direction="flange-to-base"), [0, 1, 0, s, 0, 0, -s]),
    ]
    for convention, values in cases:
        np.testing.assert_allclose(poses_from_values(np.array([values]), convention)[0], T, atol=1e-12)


def test_euler_case_tells_fixed_from_moving_axes() -> None:
    angles = np.array([[0.0, 0, 0, 0.3, 0.5, 0.7]])
    fixed = poses_from_values(angles, PoseConvention("euler-xyz"))[0, :3, :3]
    moving = poses_from_values(angles, PoseConvention("euler-XYZ"))[0, :3, :3]
    assert np.abs(fixed - moving).max() > 0.1
    np.testing.assert_allclose(
        moving,
        poses_from_values(angles[:, [0, 1, 2, 5, 4, 3]], PoseConvention("euler-zyx"))[0, :3, :3],
        atol=1e-12,
    )


def test_csv_and_json_files_read_with_their_image_names(tmp_path: Path) -> None:
    T = _poses(3)
    convention = PoseConvention("quat-xyzw", length_unit="mm")
    values = values_from_poses(T, convention)
    csv_path = tmp_path / "poses.csv"
    lines = ["image,x,y,z,qx,qy,qz,qw"] + [
        f"img{i}.png," + ",".join(map(repr, v.tolist())) for i, v in enumerate(values)
    ]
    csv_path.write_text("\n".join(lines) + "\n")
    json_path = tmp_path / "poses.json"
    json_path.write_text(
        json.dumps([{"image": f"img{i}.png", "pose": v.tolist()} for i, v in enumerate(values)])
    )
    for path in (csv_path, json_path):
        names, read = read_pose_file(path, convention)
        assert names == ["img0.png", "img1.png", "img2.png"]
        np.testing.assert_allclose(read, T, atol=1e-12)


@pytest.mark.parametrize(
    ("text", "suffix", "message"),
    [
        ("image,x,y,z\na.png,1,2\n", ".csv", "line 2 has 3 fields, the header 4"),
        ("image,x,y,z,qw,qx,qy,qz\na.png,1,2,3,1,0,0,zero\n", ".csv", "line 2, column 'qz': not a number"),
        ("image,x,y,z,rx,ry,rz\na.png,1,2,3,0,0,0\n", ".csv", "a quat-wxyz pose has 7 numbers"),
        ("image,x,y,z,qw,qx,qy,qz\na.png,1,2,3,2,0,0,0\n", ".csv", "quaternion has norm 2"),
        (
            '[{"image": "a.png", "pose": "1 2 3"}]',
            ".json",
            "entry 0: field 'pose' should be a list of numbers",
        ),
        ("{not json", ".json", "not valid JSON"),
    ],
)
def test_bad_pose_files_name_the_file_and_the_field(
    tmp_path: Path, text: str, suffix: str, message: str
) -> None:
    path = tmp_path / f"poses{suffix}"
    path.write_text(text)
    with pytest.raises(PoseFileError, match=message) as info:
        read_pose_file(path, PoseConvention())
    assert str(path) in str(info.value)


def test_a_column_major_matrix_is_not_a_rigid_transform() -> None:
    T = _poses(1)[0]
    with pytest.raises(PoseFileError, match="not a rigid transform"):
        poses_from_values(T.T.reshape(1, 16), PoseConvention("matrix"))


def test_an_unknown_convention_is_named() -> None:
    with pytest.raises(PoseFileError, match="rotation must be one of"):
        PoseConvention("euler-xyx")
