"""Intrinsics from the files other tools write: ViSP's camera.xml, an OpenCV .npz, Kalibr's
camchain; each gives the same camera as the OpenCV YAML it was written from, and a bad file names
the file and the field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.io.intrinsics_file import IntrinsicsFileError, read_intrinsics
from hec.estimator.io.pose_file import PoseFileError
from hec.estimator.io.pose_table import read_number_table
from hec.estimator.observe.depth import DEPTH_CAMERAS

CAMERA = CameraIntrinsics(640, 480, 615.2, 614.8, 321.5, 238.25, (0.11, 0.0, 0.0, 0.0, 0.0))
VISP_XML = """<?xml version="1.0"?>
<root>
  <camera>
    <name>Camera</name>
    <image_width>640</image_width>
    <image_height>480</image_height>
    <model>
      <type>perspectiveProjWithoutDistortion</type>
      <px>600</px><py>600</py><u0>320</u0><v0>240</v0>
    </model>
    <model>
      <type>perspectiveProjWithDistortion</type>
      <px>615.2</px><py>614.8</py><u0>321.5</u0><v0>238.25</v0><kud>0.11</kud><kdu>-0.108</kdu>
    </model>
  </camera>
</root>
"""
KALIBR = """cam0:
  camera_model: pinhole
  intrinsics: [615.2, 614.8, 321.5, 238.25]
  distortion_model: radtan
  distortion_coeffs: [0.11, 0.0, 0.0, 0.0]
  resolution: [640, 480]
  rostopic: /camera/color/image_raw
"""


def test_visp_xml_and_kalibr_camchain_read_as_the_camera(tmp_path: Path) -> None:
    xml = tmp_path / "camera.xml"
    xml.write_text(VISP_XML)
    chain = tmp_path / "camchain.yaml"
    chain.write_text(KALIBR)
    assert read_intrinsics(xml) == CAMERA  # the model with distortion is preferred: kud is k1
    assert read_intrinsics(chain) == CAMERA


def test_an_opencv_npz_reads_with_or_without_its_size(tmp_path: Path) -> None:
    with_size = tmp_path / "calib.npz"
    np.savez(with_size, mtx=CAMERA.K, dist=np.array([[0.11, 0, 0, 0, 0]]), image_size=np.array([640, 480]))
    assert read_intrinsics(with_size) == CAMERA
    without = tmp_path / "bare.npz"
    np.savez(without, camera_matrix=CAMERA.K, dist_coeffs=np.array(CAMERA.dist))
    assert read_intrinsics(without, image_size=(640, 480)) == CAMERA
    with pytest.raises(IntrinsicsFileError, match=r"bare.npz: fields 'image_width' and 'image_height'"):
        read_intrinsics(without)


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("camera.xml", "<root><camera><image_width>640</image_width></camera></root>", "no <model> of type"),
        ("camera.xml", VISP_XML.replace("<u0>321.5</u0>", "<u0>x</u0>"), "field 'u0' should be a number"),
        ("camera.xml", "<root><camera>", "not valid XML"),
        ("chain.yaml", KALIBR.replace("radtan", "equidistant"), "'cam0.distortion_model' is 'equidistant'"),
        ("chain.yaml", KALIBR.replace("[640, 480]", "640"), r"'cam0.resolution' should be \[width, height\]"),
        ("chain.yaml", KALIBR.replace("pinhole", "omni"), "'cam0.camera_model' is 'omni'"),
    ],
)
def test_bad_intrinsics_files_name_the_file_and_the_field(
    tmp_path: Path, name: str, text: str, message: str
) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(IntrinsicsFileError, match=message) as info:
        read_intrinsics(path)
    assert str(path) in str(info.value)


def test_a_bad_npz_is_named(tmp_path: Path) -> None:
    path = tmp_path / "calib.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(IntrinsicsFileError, match="calib.npz: not a numpy .npz file"):
        read_intrinsics(path)


def test_depth_cameras_differ_where_their_stereo_does() -> None:
    at_1m = {name: float(model.sigma(1.0)) for name, model in DEPTH_CAMERAS.items()}
    # A shorter baseline is noisier at the same distance: D405 (18 mm) > D435 (50 mm) > D455 (95 mm).
    assert at_1m["d405"] > at_1m["d435"] > at_1m["d455"]


@pytest.mark.parametrize(
    ("name", "array", "message"),
    [
        ("poses.npy", None, r"poses.npy: not a numpy .npy/.npz file"),
        (
            "poses.npy",
            np.zeros((3, 4, 3)),
            r"a stack of poses should be \(N, 4, 4\), got \(3, 4, 3\)",
        ),
        ("poses.npy", np.array(["a", "b"]), r"poses.npy: expected an \(N, k\) array of numbers"),
        (
            "poses.npz",
            {"a": np.zeros((2, 7)), "b": np.zeros((2, 7))},
            r"poses.npz: holds arrays \['a', 'b'\]",
        ),
        ("poses.npy", np.full((2, 7), np.nan), r"poses.npy: entry 0: a NaN or infinite number"),
    ],
)
def test_bad_numpy_pose_files_name_the_file_and_what_is_wrong(
    tmp_path: Path, name: str, array: np.ndarray | dict | None, message: str
) -> None:
    path = tmp_path / name
    if array is None:
        path.write_bytes(b"not numpy")
    elif isinstance(array, dict):
        np.savez(path, **array)
    else:
        np.save(path, array)
    with pytest.raises(PoseFileError, match=message):
        read_number_table(path)
