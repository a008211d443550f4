"""hec import with joints and no poses: the flange poses are the joints through hec's kinematics
(a UR arm by name, or any DH table in a file), the ROS driver's joint names decide the order, and
the import calibrates like one with the robot's reported poses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hec.cli import main
from hec.estimator.geometry.kinematics import ARMS, UR5, forward
from hec.estimator.io.arm_file import ArmFileError, read_arm
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.intrinsics_file import write_opencv_intrinsics
from hec.estimator.io.layouts import JointFile, read_folder
from hec.estimator.io.pose_file import PoseConvention
from hec.estimator.solve.problem import dataset_arm
from tests.test_pairing import copy_images

# The ROS driver's /joint_states order (names sorted), with a robot prefix.
DRIVER_NAMES = ("elbow", "shoulder_lift", "shoulder_pan", "wrist_1", "wrist_2", "wrist_3")
DRIVER_COLUMNS = [2, 1, 0, 3, 4, 5]


@pytest.fixture(scope="module")
def joint_folder(default_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The default rendered dataset's images (frame_0.png ..) and its reported joints in the ROS
    driver's order under their joint names, in degrees."""
    root = tmp_path_factory.mktemp("joints")
    source = copy_images(default_dataset, root / "images", "frame_{}.png")
    q = np.array([row["joints"] for row in source.rows])
    header = ",".join(f"ur_{name}_joint" for name in DRIVER_NAMES)
    rows = [",".join(repr(float(v)) for v in np.degrees(qi[DRIVER_COLUMNS])) for qi in q]
    (root / "joints.csv").write_text("\n".join([header, *rows]) + "\n")
    return {
        "root": root,
        "q": q,
        "camera": write_opencv_intrinsics(root / "camera.yaml", source.intrinsics),
        "reference": default_dataset,
    }


def test_flange_poses_are_the_joints_through_the_arm(joint_folder: dict) -> None:
    frames = read_folder(
        joint_folder["root"] / "images",
        None,
        PoseConvention(),
        joint_file=JointFile(joint_folder["root"] / "joints.csv", unit="deg"),
        kinematics=UR5,
    )
    np.testing.assert_allclose(frames.joints, joint_folder["q"], rtol=0, atol=1e-12)
    expected = np.array([forward(UR5, q) for q in joint_folder["q"]])
    np.testing.assert_allclose(frames.T_base_flange, expected, rtol=0, atol=1e-12)


def test_a_dh_table_file_reads_as_the_arm_it_describes(tmp_path: Path) -> None:
    toml = tmp_path / "my_ur5.toml"
    toml.write_text(f"d = {list(UR5.d)}\na = {list(UR5.a)}\nalpha = {list(UR5.alpha)}\n")
    arm = read_arm(toml)
    assert arm.name == "my_ur5"
    q = np.array([0.3, -1.2, 1.4, -0.7, 1.1, 0.2])
    np.testing.assert_array_equal(forward(arm, q), forward(UR5, q))
    assert read_arm("ur16e") is ARMS["ur16e"]
    bad = tmp_path / "bad.yaml"
    bad.write_text("d: [0, 0, 0]\na: [0, 0, 0, 0, 0, 0]\nalpha: [0, 0, 0, 0, 0, 0]\n")
    with pytest.raises(ArmFileError, match=r"bad.yaml: field 'd' should be 6 finite numbers \(metres\)"):
        read_arm(bad)
    with pytest.raises(ArmFileError, match="neither a known arm"):
        read_arm(tmp_path / "ur6.toml")


def test_import_from_joints_calibrates_with_the_arm_kept(joint_folder: dict, tmp_path: Path, capsys) -> None:
    out = tmp_path / "dataset"
    dh = tmp_path / "arm.json"
    dh.write_text(json.dumps({"name": "lab_arm", "d": UR5.d, "a": UR5.a, "alpha": UR5.alpha}))
    argv = ["import", "folder", str(joint_folder["root"] / "images"), "--out", str(out), "--quiet"]
    argv += ["--joints", str(joint_folder["root"] / "joints.csv"), "--joint-unit", "deg"]
    argv += ["--robot-model", str(dh), "--board", "hec_8qr", "--intrinsics", str(joint_folder["camera"])]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "flange poses computed from the joints with lab_arm's kinematics" in printed
    assert "convention check:" in printed
    dataset = load_dataset(out)
    arm = dataset_arm(dataset)
    assert arm is not None and arm.kinematics.d == UR5.d and arm.kinematics.name == "lab_arm"
    assert main(["calibrate", str(out), "--no-loo", "--quiet", "--verbose"]) == 0
    assert "T_flange_cam" in capsys.readouterr().out


def test_a_joint_read_with_an_offset_is_named_not_absorbed(
    joint_folder: dict, tmp_path: Path, capsys
) -> None:
    """Joint 2 read 0.8 degrees off on every frame, the flange poses computed from the joints: the
    arm's self-calibration moves joint 2's zero by more than a real arm's ever is, and calibrate
    says so instead of only absorbing it."""
    q = joint_folder["q"].copy()
    q[:, 1] += np.radians(0.8)
    joints = tmp_path / "joints.csv"
    joints.write_text(
        "\n".join(["j1,j2,j3,j4,j5,j6", *(",".join(repr(float(v)) for v in r) for r in q)]) + "\n"
    )
    out = tmp_path / "dataset"
    argv = ["import", "folder", str(joint_folder["root"] / "images"), "--out", str(out), "--quiet"]
    argv += ["--joints", str(joints), "--robot-model", "ur5", "--board", "hec_8qr"]
    assert main([*argv, "--intrinsics", str(joint_folder["camera"]), "--no-check"]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(out), "--no-loo", "--quiet", "--verbose"]) == 0
    printed = capsys.readouterr().out
    assert "the arm's self-calibration moves the zero of joint2 by -0.7" in printed, printed
    assert "check the joint readings before trusting this mount" in printed
