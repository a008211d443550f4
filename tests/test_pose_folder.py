"""A folder of pose files, one per image: each file's numbers read by their names when named, paired
with the image of the same number, and every way such a folder goes wrong named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hec.estimator.io.pairing import PairingError, pair_images
from hec.estimator.io.pose_file import PoseConvention, columns_by_name
from hec.estimator.io.pose_folder import read_pose_folder
from hec.estimator.io.pose_table import PoseFileError, read_number_table

ROS_POSE = "position: {{x: {x}, y: 0.2, z: 0.3}}\norientation: {{x: 0.0, y: 0.0, z: 0.0, w: 1.0}}\n"


def _folder(tmp_path: Path, files: dict[str, str]) -> Path:
    folder = tmp_path / "poses"
    folder.mkdir(parents=True)
    for name, text in files.items():
        (folder / name).write_text(text)
    return folder


def test_named_numbers_in_any_order_read_as_the_convention_orders_them(tmp_path: Path) -> None:
    folder = _folder(
        tmp_path,
        {
            "0.yaml": "x: 0.1\ny: 0.2\nz: 0.3\nqz: 0.0\nqx: 0.0\nqw: 1.0\nqy: 0.0\n",
            "1.yaml": "qw: 0.0\nz: 0.6\nqx: 1.0\ny: 0.5\nqy: 0.0\nx: 0.4\nqz: 0.0\n",
        },
    )
    table = read_pose_folder(folder)
    assert table.numbers == [0, 1] and table.where == ["0.yaml", "1.yaml"]
    for rotation, expected in (
        ("quat-wxyz", [[0.1, 0.2, 0.3, 1, 0, 0, 0], [0.4, 0.5, 0.6, 0, 1, 0, 0]]),
        ("quat-xyzw", [[0.1, 0.2, 0.3, 0, 0, 0, 1], [0.4, 0.5, 0.6, 1, 0, 0, 0]]),
    ):
        np.testing.assert_array_equal(columns_by_name(table, PoseConvention(rotation)).values, expected)
    with pytest.raises(
        PoseFileError, match="named as a position and a quaternion .* pass --rotation quat-xyzw"
    ):
        columns_by_name(table, PoseConvention("rotvec"))


def test_ros_poses_text_matrices_and_csv_headers_are_read_by_their_names(tmp_path: Path) -> None:
    ros = read_pose_folder(
        _folder(tmp_path / "ros", {f"pose_{i}.yml": ROS_POSE.format(x=i) for i in range(3)})
    )
    np.testing.assert_array_equal(
        columns_by_name(ros, PoseConvention("quat-wxyz")).values[2], [2, 0.2, 0.3, 1, 0, 0, 0]
    )
    matrix = "1 0 0 0.1\n0 1 0 0.2\n0 0 1 0.3\n0 0 0 1\n"
    text = read_pose_folder(_folder(tmp_path / "txt", {"10.txt": matrix, "9.txt": matrix}))
    assert text.numbers == [9, 10] and text.values.shape == (2, 16) and text.columns is None
    csv = tmp_path / "poses.csv"
    csv.write_text("image,qw,qx,qy,qz,x_m,y_m,z_m\na.png,1,0,0,0,0.1,0.2,0.3\n")
    np.testing.assert_array_equal(
        columns_by_name(read_number_table(csv), PoseConvention("quat-xyzw")).values,
        [[0.1, 0.2, 0.3, 0, 0, 0, 1]],
    )


def test_images_pair_with_the_pose_file_of_their_number(tmp_path: Path) -> None:
    table = read_pose_folder(_folder(tmp_path, {f"{i}.yaml": ROS_POSE.format(x=i) for i in (0, 1, 2, 10)}))
    images = [tmp_path / f"img_{i:02d}.png" for i in (10, 2, 1, 0)]
    pairing = pair_images(images, table)
    assert pairing.key == "file-number" and [p.name for p in pairing.images] == [
        "img_00.png",
        "img_01.png",
        "img_02.png",
        "img_10.png",
    ]
    assert "by the number in each image's name and each pose file's name" in pairing.describe()
    with pytest.raises(
        PairingError, match=r"no pose file for image img_03.png; no image for pose file 10.yaml"
    ):
        pair_images([*images[1:], tmp_path / "img_03.png"], table)


@pytest.mark.parametrize(
    ("files", "message"),
    [
        ({}, "an empty pose folder"),
        ({"a.yaml": "x: 1"}, "'a.yaml' carries no number"),
        ({"1_2.yaml": "x: 1"}, "'1_2.yaml' carries several numbers"),
        ({"1.yaml": "x: 1", "01.txt": "1"}, "01.txt and 1.yaml carry the same number 1"),
        ({"0.txt": "1 2 3", "1.txt": "1 2"}, "1.txt holds 2 numbers, 0.txt 3 numbers: every pose file"),
        (
            {"0.yaml": "x: 1\ny: 2", "1.yaml": "x: 1\nq: 2"},
            "1.yaml holds 2 numbers named x, q, 0.yaml 2 numbers named x, y",
        ),
        ({"0.txt": "1 2 three"}, "0.txt: not a number: 'three'"),
        ({"0.yaml": "x: [1, 2\n"}, "0.yaml: not valid YAML/JSON"),
        ({"0.yaml": "x: fast"}, "0.yaml: x holds 'fast', not numbers"),
    ],
)
def test_a_bad_pose_folder_names_the_file(tmp_path: Path, files: dict[str, str], message: str) -> None:
    with pytest.raises(PoseFileError) as err:
        read_pose_folder(_folder(tmp_path, files))
    assert message in str(err.value)
