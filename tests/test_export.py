"""hec export: every format read back gives the transform to 1e-9; the URDF joint composed with a
RealSense's camera_link -> optical transform gives T_flange_cam back; bad calibration files are
refused naming the file and field."""

from __future__ import annotations

import ast
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from hec.cli import main
from hec.estimator.geometry.lie import so3_exp
from hec.estimator.geometry.transforms import (
    make_transform,
    transform_from_xyz_quat,
    transform_from_xyz_rpy,
    xyz_quat_from_transform,
)
from hec.estimator.io.calibration_file import CalibrationFileError, read_calibration
from hec.estimator.io.export import (
    REALSENSE_ROS_PARENTS,
    Export,
    export_text,
    realsense_link_optical,
    realsense_ros_parent,
)

T_FLANGE_CAM = make_transform(so3_exp(np.array([0.3, -1.2, 2.0])), np.array([0.012, -0.034, 0.056]))
COVARIANCE = np.diag([1e-8, 2e-8, 3e-8, 1e-6, 2e-6, 3e-6])


def _calibration_file(tmp_path: Path, **fields) -> Path:
    path = tmp_path / "cal.json"
    data = {"format": "hec-calibration", "version": 1, "method": "ekf", "T_flange_cam": T_FLANGE_CAM.tolist()}
    data |= {"covariance": COVARIANCE.tolist(), "covariance_convention": "lie"} | fields
    path.write_text(json.dumps(data))
    return path


def _from_xyzw(t, q) -> np.ndarray:
    x, y, z, w = q
    return transform_from_xyz_quat(np.asarray(t, float), np.array([w, x, y, z]))


def _publisher_transform(args: list[str]) -> tuple[np.ndarray, str, str]:
    named = dict(zip(args[::2], args[1::2], strict=True))
    t = [float(named[k]) for k in ("--x", "--y", "--z")]
    q = [float(named[k]) for k in ("--qx", "--qy", "--qz", "--qw")]
    return _from_xyzw(t, q), named["--frame-id"], named["--child-frame-id"]


@pytest.fixture
def export(tmp_path: Path) -> Export:
    return Export(read_calibration(_calibration_file(tmp_path)))


def test_ros2_launch_arguments_give_the_transform(export: Export) -> None:
    tree = ast.parse(export_text(export, "ros2-launch"))
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node")
    keywords = {k.arg: ast.literal_eval(k.value) for k in call.keywords}
    assert keywords["package"] == "tf2_ros" and keywords["executable"] == "static_transform_publisher"
    T, parent, child = _publisher_transform(keywords["arguments"])
    assert (parent, child) == ("tool0", "camera_color_optical_frame")
    assert np.abs(T - T_FLANGE_CAM).max() < 1e-9


def test_ros2_args_give_the_transform(export: Export) -> None:
    lines = export_text(export, "ros2-args").splitlines()
    assert all(line.startswith("#") for line in lines[:-1]) and "T_flange_cam" in lines[2]
    words = lines[-1].split()
    assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    assert np.abs(_publisher_transform(words[4:])[0] - T_FLANGE_CAM).max() < 1e-9


def test_easy_handeye2_calib_gives_the_transform(export: Export) -> None:
    data = yaml.safe_load(export_text(export, "easy_handeye2"))
    assert data["parameters"]["calibration_type"] == "eye_in_hand"
    assert data["parameters"]["robot_effector_frame"] == "tool0"
    assert data["parameters"]["tracking_base_frame"] == "camera_color_optical_frame"
    t, r = data["transform"]["translation"], data["transform"]["rotation"]
    T = _from_xyzw([t["x"], t["y"], t["z"]], [r["x"], r["y"], r["z"], r["w"]])
    assert np.abs(T - T_FLANGE_CAM).max() < 1e-9


@pytest.mark.parametrize("fmt", ["yaml", "json"])
def test_hec_yaml_and_json_give_the_transform_every_way(export: Export, fmt: str) -> None:
    text = export_text(export, fmt)
    data = yaml.safe_load(text) if fmt == "yaml" else json.loads(text)
    assert np.abs(np.array(data["matrix"]) - T_FLANGE_CAM).max() < 1e-9
    assert np.abs(_from_xyzw(data["translation_m"], data["quaternion_xyzw"]) - T_FLANGE_CAM).max() < 1e-9
    from_rpy = transform_from_xyz_rpy(np.array(data["translation_m"]), np.array(data["rpy_rad"]))
    assert np.abs(from_rpy - T_FLANGE_CAM).max() < 1e-9
    assert np.abs(np.array(data["covariance"]) - COVARIANCE).max() < 1e-20
    assert "Rz(yaw) Ry(pitch) Rx(roll)" in data["rpy_convention"] and "cam2gripper" in data["use"]


def _urdf_origin(text: str) -> tuple[np.ndarray, str, str]:
    """The joint's transform from its xyz and fixed-axis rpy (URDF: R = Rz(y) Ry(p) Rx(r)), by hand."""
    joint = ET.fromstring(text).find("joint")
    assert joint.get("type") == "fixed"
    origin = joint.find("origin")
    xyz = np.array(origin.get("xyz").split(), float)
    r, p, y = np.array(origin.get("rpy").split(), float)
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return (
        make_transform(Rz @ Ry @ Rx, xyz),
        joint.find("parent").get("link"),
        joint.find("child").get("link"),
    )


def test_urdf_joint_to_the_optical_frame_gives_the_transform(export: Export) -> None:
    T, parent, child = _urdf_origin(export_text(export, "urdf"))
    assert (parent, child) == ("tool0", "camera_color_optical_frame")
    assert np.abs(T - T_FLANGE_CAM).max() < 1e-9


def test_urdf_joint_to_camera_link_composed_with_the_realsense_optical_transform(tmp_path: Path) -> None:
    T_colour_depth = make_transform(
        so3_exp(np.array([0.002, -0.004, 0.001])), np.array([-0.015, 0.0003, 0.0001])
    )
    T_link_optical = realsense_link_optical(T_colour_depth)
    cal = read_calibration(_calibration_file(tmp_path))
    e = Export(cal, "tool0", "camera_link", T_link_optical, "test")
    T_tool0_link, _, child = _urdf_origin(export_text(e, "urdf"))
    assert child == "camera_link"
    assert np.abs(T_tool0_link @ T_link_optical - T_FLANGE_CAM).max() < 1e-9
    # the optical frame looks along camera_link's x, its x is the link's -y
    assert np.allclose(T_link_optical[:3, 2], [1, 0, 0], atol=0.01)
    assert np.allclose(T_link_optical[:3, 0], [0, -1, 0], atol=0.01)
    # the covariance is carried to the composed transform: the same spread along a direction
    data = yaml.safe_load(export_text(e, "yaml"))
    cov = np.array(data["covariance"])
    assert np.isclose(np.trace(cov[3:, 3:]), np.trace(COVARIANCE[3:, 3:]))


def test_export_command_link_values_and_out_file(tmp_path: Path, capsys) -> None:
    cal = _calibration_file(tmp_path)
    t, (w, x, y, z) = xyz_quat_from_transform(realsense_link_optical())
    out = tmp_path / "mount.urdf"
    values = [str(v) for v in (0.0, 0.015, 0.0, x, y, z, w)]
    assert (
        main(["export", str(cal), "--to", "urdf", "--out", str(out), "--link-optical-values", *values]) == 0
    )
    T_link_optical = transform_from_xyz_quat(np.array([0.0, 0.015, 0.0]), np.array([w, x, y, z]))
    T, _, child = _urdf_origin(out.read_text())
    assert child == "camera_link" and np.abs(T @ T_link_optical - T_FLANGE_CAM).max() < 1e-9
    assert main(["export", str(cal), "--to", "urdf", "--assume-zero-offset"]) == 0
    assert "ZERO offset" in capsys.readouterr().err


def _realsense_ros_tree(name: str = "camera") -> dict[str, str]:
    """child -> parent of every frame realsense-ros publishes for camera name `name`."""
    children = [name + suffix for suffix in REALSENSE_ROS_PARENTS]
    return {child: realsense_ros_parent(child) for child in children}


def test_the_default_export_gives_no_realsense_ros_frame_a_second_parent(tmp_path: Path, capsys) -> None:
    """Every format's default child is camera_link, which realsense-ros publishes no parent for; the
    TF tree with the export added still has one parent per frame and reaches the optical frame at
    T_flange_cam."""
    cal = _calibration_file(tmp_path)
    T_link_optical = realsense_link_optical(
        make_transform(so3_exp(np.array([0.001, 0.002, -0.003])), np.array([-0.0148, 0.0002, 0.0004]))
    )
    t, (w, x, y, z) = xyz_quat_from_transform(T_link_optical)
    values = [repr(float(v)) for v in (*t, x, y, z, w)]
    assert main(["export", str(cal), "--to", "ros2-args", "--link-optical-values", *values]) == 0
    out = capsys.readouterr()
    assert "second parent" not in out.err
    T_parent_child, parent, child = _publisher_transform(out.out.splitlines()[-1].split()[4:])
    tree = _realsense_ros_tree()
    assert (parent, child) == ("tool0", "camera_link") and child not in tree and parent not in tree
    assert realsense_ros_parent("camera_color_optical_frame") == "camera_color_frame"
    assert tree["camera_color_frame"] == "camera_link"
    assert np.abs(T_parent_child @ T_link_optical - T_FLANGE_CAM).max() < 1e-9
    assert main(["export", str(cal), "--to", "urdf", "--link-optical-values", *values]) == 0
    assert _urdf_origin(capsys.readouterr().out)[2] == "camera_link"
    assert main(["export", str(cal), "--to", "easy_handeye2", "--link-optical-values", *values]) == 0
    assert yaml.safe_load(capsys.readouterr().out)["parameters"]["tracking_base_frame"] == "camera_link"


def test_camera_link_without_a_known_offset_is_refused_unless_asked(tmp_path: Path, capsys) -> None:
    cal = _calibration_file(tmp_path)
    out = tmp_path / "mount.launch.py"
    assert main(["export", str(cal), "--to", "ros2-launch", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "transform to the optical frame is not known" in err and "--assume-zero-offset" in err
    assert "tf2_echo camera_link camera_color_optical_frame" in err and not out.exists()
    assert main(["export", str(cal), "--to", "ros2-launch", "--out", str(out), "--assume-zero-offset"]) == 0
    assert "ZERO offset" in capsys.readouterr().err and out.is_file()


def test_an_optical_child_says_when_it_clashes(tmp_path: Path, capsys) -> None:
    cal = _calibration_file(tmp_path)
    assert main(["export", str(cal), "--to", "ros2-args", "--child", "camera_color_optical_frame"]) == 0
    out = capsys.readouterr()
    assert "publishes camera_color_frame -> camera_color_optical_frame" in out.err
    assert "publish_tf:=false" in out.err
    T, _, child = _publisher_transform(out.out.splitlines()[-1].split()[4:])
    assert child == "camera_color_optical_frame" and np.abs(T - T_FLANGE_CAM).max() < 1e-9
    assert main(["export", str(cal), "--to", "ros2-args", "--child", "tracker_optical_frame"]) == 0
    assert "second parent" not in capsys.readouterr().err


@pytest.mark.parametrize(
    ("content", "words"),
    [
        ({"format": "hec-detections", "version": 1, "frames": []}, "is a 'hec-detections' file"),
        ({"dataset": "x"}, "no field 'T_flange_cam'"),
        (
            {"format": "hec-calibration", "version": 1, "T_flange_cam": [[1, 0], [0, 1]]},
            "field 'T_flange_cam'",
        ),
        ({"results": [{"method": "ekf", "T_flange_cam": np.eye(4).tolist()}]}, "name one with --method"),
        (
            {"T_flange_cam": np.eye(4).tolist(), "covariance": (-np.eye(6)).tolist()},
            "field 'covariance' must be symmetric positive definite",
        ),
    ],
)
def test_a_bad_calibration_file_is_refused_naming_file_and_field(
    tmp_path: Path, capsys, content: dict, words: str
) -> None:
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    with pytest.raises(CalibrationFileError, match=words):
        read_calibration(path)
    assert main(["export", str(path), "--to", "yaml"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and words in err
