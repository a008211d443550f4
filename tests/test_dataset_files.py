"""A dataset's JSON files with a bad field are refused in one line naming the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.io.board_file import find_board
from hec.estimator.io.dataset import DatasetWriter, load_dataset
from hec.estimator.observe.frames import DatasetError

CAMERA = CameraIntrinsics(640, 480, 600.0, 600.0, 319.5, 239.5)


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    with DatasetWriter(tmp_path / "ds", CAMERA, find_board("hec_8qr"), 0.001, "test") as writer:
        for k in range(3):
            T = np.eye(4)
            T[:3, 3] = [0.1 * k, 0.0, 0.5]
            writer.add_pose(T, float(k))
        return writer.finish(None, {})


def test_a_written_dataset_reads_back(dataset: Path) -> None:
    loaded = load_dataset(dataset)
    assert loaded.intrinsics == CAMERA and len(loaded) == 3 and loaded.depth_scale_m == 0.001


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"camera": {"fx": "600"}}, "camera.fx should be a number > 0 (pixels), got '600'"),
        ({"camera": {"width": 0}}, "camera.width should be an integer > 0 (pixels), got 0"),
        ({"depth_scale_m": -0.001}, "field 'depth_scale_m' should be a number > 0"),
        ({"frame_count": "3"}, "field 'frame_count' should be an integer >= 0, got '3'"),
        ({"camera": None}, "field 'camera' is null; only a dataset of pose pairs may leave it out"),
    ],
)
def test_a_bad_dataset_field_is_named(dataset: Path, change: dict, message: str) -> None:
    meta_path = dataset / "dataset.json"
    meta = json.loads(meta_path.read_text())
    for key, value in change.items():
        meta[key] = meta[key] | value if isinstance(value, dict) else value
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(DatasetError) as error:
        load_dataset(dataset)
    assert str(error.value).startswith(f"{meta_path}: ") and "\n" not in str(error.value)
    assert message in str(error.value)


def test_a_ground_truth_without_the_mount_is_named(dataset: Path) -> None:
    meta_path = dataset / "dataset.json"
    meta = json.loads(meta_path.read_text()) | {"ground_truth_file": "ground_truth.json"}
    meta_path.write_text(json.dumps(meta))
    truth = {"T_world_base": np.eye(4).tolist(), "T_base_board": np.eye(4).tolist(), "frames": []}
    (dataset / "ground_truth.json").write_text(json.dumps(truth))
    with pytest.raises(DatasetError, match="ground_truth.json: missing field 'T_flange_cam'"):
        load_dataset(dataset)


def test_an_import_record_read_back_is_checked(dataset: Path) -> None:
    """The checks of an import read the pose convention back from dataset.json: a bad one is named
    when the dataset is opened, not met later as a traceback."""
    meta_path = dataset / "dataset.json"
    convention = dict(rotation="rotvec", angle_unit="rad", length_unit="m", direction="base-to-flange")
    record = {"layout": "folder", "pose_convention": convention, "pose_values": [[0.0] * 6] * 3}
    meta = json.loads(meta_path.read_text())
    meta_path.write_text(json.dumps(meta | {"provenance": record}))
    assert load_dataset(dataset).metadata["provenance"] == record
    bad = record | {"pose_convention": convention | {"rotation": "quaternion"}}
    meta_path.write_text(json.dumps(meta | {"provenance": bad}))
    with pytest.raises(DatasetError) as error:
        load_dataset(dataset)
    assert f"{meta_path}: provenance.pose_convention.rotation should be one of quat-wxyz" in str(error.value)
    meta_path.write_text(json.dumps(meta | {"provenance": {"layout": "folder", "joints": {"unit": "deg"}}}))
    with pytest.raises(DatasetError, match="provenance.joints.order is missing; it should be one of arm"):
        load_dataset(dataset)
