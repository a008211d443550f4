"""hec import: a rendered dataset written out in each layout and imported back calibrates the same,
the convention check names each mistake made on the way in (and none on a correct import), and bad
sources are errors that name the file and the field."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hec.cli import main
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.io.dataset import DatasetWriter, load_dataset
from hec.estimator.io.intrinsics_file import write_opencv_intrinsics
from hec.estimator.io.layouts import (
    JointFile,
    LayoutError,
    read_easy_handeye_samples,
    read_folder,
    write_easy_handeye_samples,
    write_folder,
    write_visp,
)
from hec.estimator.io.pairing import PairingError
from hec.estimator.io.pose_file import PoseConvention, PoseFileError, read_pose_file, values_from_poses
from hec.estimator.observe.observations import observe_dataset
from hec.estimator.observe.pose_pairs import PosePair, read_pose_pairs
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import solve
from hec.estimator.solve.problem import build_problem, dataset_robot_noise

CONVENTION = PoseConvention("euler-xyz", "deg", "mm", "flange-to-base")


@pytest.fixture(scope="module")
def exported(default_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The default rendered dataset without its depth (what the layouts hold), and it written out
    as an image folder with poses in CONVENTION, as ViSP's layout, and its camera as OpenCV YAML."""
    root = tmp_path_factory.mktemp("exported")
    source = load_dataset(default_dataset)
    with DatasetWriter(
        root / "reference", source.intrinsics, source.board, source.depth_scale_m, "sim"
    ) as writer:
        for i in range(len(source)):
            writer.add_frame(replace(source.frame(i), depth_m=None))
        reference = writer.finish()
    pngs = [(source.root / row["rgb"]).read_bytes() for row in source.rows]
    T_base_flange = np.array([row["T_base_flange"] for row in source.rows])
    joints = np.array([row["joints"] for row in source.rows])
    return {
        "reference": reference,
        "folder": write_folder(root / "folder", pngs, T_base_flange, CONVENTION, joints),
        "visp": write_visp(root / "visp", pngs, T_base_flange),
        "camera": write_opencv_intrinsics(root / "camera.yaml", source.intrinsics),
    }


def _calibrate(path: Path, method: str) -> np.ndarray:
    dataset = load_dataset(path)
    observations = observe_dataset(dataset)
    problem = build_problem(observations, dataset.board, dataset.intrinsics, dataset_robot_noise(dataset))
    return solve(method, problem, MethodOptions(), observations).T_flange_cam


def _import(exported: dict[str, Path], out: Path, layout: str, *options: str) -> list[str]:
    source = exported[layout] / "images" if layout == "folder" else exported[layout]
    argv = ["import", layout, str(source), "--out", str(out), "--board", "hec_8qr"]
    argv += ["--intrinsics", str(exported["camera"]), "--quiet", *options]
    if layout == "folder":
        argv += ["--poses", str(exported["folder"] / "poses.csv")]
    return argv


FOLDER_OPTIONS = ("--rotation", "euler-xyz", "--angle-unit", "deg", "--length-unit", "mm")
FLANGE_TO_BASE = ("--pose-direction", "flange-to-base")


@pytest.mark.parametrize("layout", ["folder", "visp"])
def test_an_exported_dataset_imports_back_to_the_same_calibration(exported, tmp_path, capsys, layout) -> None:
    options = (*FOLDER_OPTIONS, "--pose-direction", "flange-to-base") if layout == "folder" else ()
    assert main(_import(exported, tmp_path / "imported", layout, *options)) == 0
    out = capsys.readouterr().out
    assert "imported 17 images (0 with depth)" in out
    assert "convention check: the robot poses fit the stated convention" in out
    provenance = load_dataset(tmp_path / "imported").metadata["provenance"]
    assert provenance["layout"] == layout and len(provenance["pose_values"]) == 17
    for method in ("ekf", "opencv-park"):
        expected = _calibrate(exported["reference"], method)
        np.testing.assert_allclose(_calibrate(tmp_path / "imported", method), expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ((*FOLDER_OPTIONS, "--pose-direction", "base-to-flange"), "--pose-direction flange-to-base"),
        (
            (
                "--rotation",
                "rotvec",
                "--angle-unit",
                "deg",
                "--length-unit",
                "mm",
                "--pose-direction",
                "flange-to-base",
            ),
            "--rotation euler-xyz",
        ),
        (
            (
                "--rotation",
                "euler-xyz",
                "--angle-unit",
                "rad",
                "--length-unit",
                "mm",
                "--pose-direction",
                "flange-to-base",
            ),
            "--angle-unit deg",
        ),
        (
            (
                "--rotation",
                "euler-xyz",
                "--angle-unit",
                "deg",
                "--length-unit",
                "m",
                "--pose-direction",
                "flange-to-base",
            ),
            "--length-unit mm",
        ),
    ],
)
def test_each_convention_mistake_is_named_on_import(exported, tmp_path, capsys, options, named) -> None:
    assert main(_import(exported, tmp_path / "imported", "folder", *options)) == 0
    out = capsys.readouterr().out
    assert "convention check: the robot poses look like" in out and f"pass {named}" in out


@pytest.mark.parametrize("mirrored", [False, True])
def test_a_mirrored_board_file_is_named(exported, tmp_path, capsys, mirrored) -> None:
    """The 8-QR board file written with y down (its rows swapped, each code's own corners as printed)
    is named; the right file is not."""
    board = json.loads(Path("models/boards/hec_8qr.json").read_text())
    if mirrored:
        for marker in board["markers"]:
            marker["center_m"][1] *= -1.0
    (tmp_path / "board.json").write_text(json.dumps(board))
    options = (*FOLDER_OPTIONS, *FLANGE_TO_BASE)
    argv = _import(exported, tmp_path / "imported", "folder", *options)
    argv[argv.index("hec_8qr")] = str(tmp_path / "board.json")
    assert main(argv) == 0
    out = capsys.readouterr().out
    if mirrored:
        assert "board check: the board file's marker layout looks mirrored top to bottom (y)" in out
        # nor is the corner noise learned from a board that is not the one in the images
        noise = json.loads((tmp_path / "imported" / "detections.json").read_text())["corner_noise"]
        assert "is the board file the board in the images?" in noise["reason"]
    else:
        assert "board check: the board file's layout fits the images" in out


def test_calibrate_names_the_convention_of_poses_that_fit_no_mount(exported, tmp_path, capsys) -> None:
    """Inverted poses imported unchecked: Park finds no mount and the other closed forms a bad one,
    so calibrate refuses before any estimation, naming the reading that fits."""
    options = (*FOLDER_OPTIONS, "--pose-direction", "base-to-flange", "--no-check")
    assert main(_import(exported, tmp_path / "imported", "folder", *options)) == 0
    capsys.readouterr()
    code = main(["calibrate", str(tmp_path / "imported"), "--method", "opencv-park", "--no-loo"])
    err = capsys.readouterr().err
    assert code == 2 and "the robot poses do not fit the images at any mount" in err, err
    assert "the robot poses look like flange-to-base (inverted)" in err
    assert "pass --pose-direction flange-to-base" in err


@pytest.mark.parametrize(
    ("written", "options", "said"),
    [
        ("arm", (), "the joints fit the robot poses in the arm's order"),
        ("ros-driver", (), "the joints look like the ROS driver's order (elbow first)"),
        ("ros-driver", ("--joint-order", "ros-driver"), "the joints fit the robot poses in the ROS driver's"),
        ("arm", ("--joint-order", "ros-driver"), "the joints look like the arm's order (base joint first)"),
        ("arm", ("--joint-unit", "deg"), "the joints do not match the robot poses in either order"),
    ],
)
def test_joints_are_imported_in_the_arms_order_and_a_wrong_order_is_named(
    exported, tmp_path, capsys, written, options, said
) -> None:
    """The rendered set's joints written in the arm's or the ROS driver's order (elbow first, as
    /joint_states gives them), imported with or without --joint-order."""
    joints = exported["folder"] / "joints.csv"
    if written == "ros-driver":
        lines = joints.read_text().splitlines()
        swapped = [",".join(np.array(line.split(","))[[0, 3, 2, 1, 4, 5, 6]]) for line in lines]
        joints = tmp_path / "joint_states.csv"
        joints.write_text("\n".join(swapped) + "\n")
    options = (*options, "--joints", str(joints), "--robot-model", "ur5")
    argv = _import(exported, tmp_path / "imported", "folder", *FOLDER_OPTIONS, *FLANGE_TO_BASE, *options)
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "17 joints" not in out and "6 joints each" in out
    assert f"joint check: {said}" in out
    if not options:  # calibrating with joints in the wrong order warns instead of absorbing them
        assert main(["calibrate", str(tmp_path / "imported"), "--no-loo", "--quiet", "--verbose"]) == 0
        warned = "the arm's self-calibration would otherwise absorb the mistake" in capsys.readouterr().out
        assert warned == (written == "ros-driver")
    if "fit the robot poses" in said:  # read in the right order, the arm's joints are the rendered ones
        source = load_dataset(exported["reference"])
        imported = load_dataset(tmp_path / "imported")
        np.testing.assert_allclose(
            [row["joints"] for row in imported.rows], [row["joints"] for row in source.rows], atol=1e-12
        )


def test_poses_in_ros_base_link_are_named_by_the_frame_check(exported, tmp_path, capsys) -> None:
    """The rendered set's poses given from ROS's base_link (the controller's base turned 180 degrees
    about z) with their joints: the frame check says so; as the controller gives them it says nothing."""
    names, T_base_flange = read_pose_file(exported["folder"] / "poses.csv", CONVENTION)
    base_link = make_transform(Rotation.from_euler("z", 180, degrees=True).as_matrix(), np.zeros(3))
    values = values_from_poses(np.array([base_link @ T for T in T_base_flange]), CONVENTION)
    poses = tmp_path / "poses.csv"
    poses.write_text(
        "image,x,y,z,a,b,c\n"
        + "".join(
            f"{n}," + ",".join(repr(float(x)) for x in v) + "\n" for n, v in zip(names, values, strict=True)
        )
    )
    joints = ("--joints", str(exported["folder"] / "joints.csv"), "--robot-model", "ur5")
    for source, said in ((exported["folder"] / "poses.csv", False), (poses, True)):
        argv = _import(exported, tmp_path / "imported", "folder", *FOLDER_OPTIONS, *FLANGE_TO_BASE, *joints)
        argv[argv.index("--poses") + 1] = str(source)
        assert main([*argv, "--force"]) == 0
        out = capsys.readouterr().out
        assert "joint check: the joints fit the robot poses in the arm's order" in out
        frame = (
            "frame check: the robot poses are the joints' flange poses in another base frame (turned 180 deg"
        )
        assert (frame in out) == said, out


def test_pose_pairs_import_back_as_written(tmp_path, capsys) -> None:
    rng = np.random.default_rng(2)
    pairs = [
        PosePair(
            i,
            *(
                make_transform(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
                for _ in range(2)
            ),
        )
        for i in range(6)
    ]
    samples = write_easy_handeye_samples(tmp_path / "cell.samples", pairs)
    assert main(["import", "easy_handeye2", str(samples), "--out", str(tmp_path / "pairs")]) == 0
    assert "imported 6 pose pairs" in capsys.readouterr().out
    read, source = read_pose_pairs(tmp_path / "pairs" / "pose_pairs.json")
    assert source["layout"] == "easy_handeye2"
    for a, b in zip(pairs, read, strict=True):
        np.testing.assert_allclose(b.T_base_flange, a.T_base_flange, atol=1e-9)
        np.testing.assert_allclose(b.T_cam_board, a.T_cam_board, atol=1e-9)
    dataset = load_dataset(tmp_path / "pairs")
    assert dataset.intrinsics is None and dataset.board is None and len(dataset) == 6
    np.testing.assert_allclose(dataset.rows[3]["T_base_flange"], pairs[3].T_base_flange, atol=1e-9)


@pytest.fixture(scope="module")
def rendered_samples(default_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The rendered default set as easy_handeye2 samples: reported flange poses, PnP board poses."""
    from hec.bench.pose_pairs import rendered_pairs

    pairs = rendered_pairs(load_dataset(default_dataset))
    return write_easy_handeye_samples(tmp_path_factory.mktemp("samples") / "cell.samples", pairs)


@pytest.mark.parametrize(
    ("options", "said"),
    [
        ([], "the pose pairs fit the stated directions"),
        (["--pose-direction", "flange-to-base"], "robot poses base-to-flange (inverted)"),
        (["--tracking-direction", "target-to-camera"], "tracking poses camera-to-target (inverted)"),
        (["--pose-direction", "flange-to-base", "--tracking-direction", "target-to-camera"], "both inverted"),
    ],
)
def test_each_pose_pair_direction_mistake_is_named_on_rendered_pairs(
    rendered_samples, tmp_path, capsys, options, said
) -> None:
    """A mistake named is refused, nothing written; the stated reading that fits is imported."""
    argv = ["import", "easy_handeye2", str(rendered_samples), "--out", str(tmp_path / "pairs"), *options]
    code = main(argv)
    out, err = capsys.readouterr()
    if options:
        assert code == 2 and f"the pose pairs look like {said}" in err and "nothing written" in err, err
        assert not (tmp_path / "pairs").exists()
    else:
        assert code == 0 and f"convention check: {said}" in out


def test_bad_sources_name_the_file_and_the_field(exported, tmp_path) -> None:
    images = exported["folder"] / "images"
    poses = tmp_path / "poses.csv"
    lines = (exported["folder"] / "poses.csv").read_text().splitlines()
    poses.write_text("\n".join(lines[:-1]) + "\n")  # the last image has no pose
    with pytest.raises(PairingError, match=r"images without poses in .*poses.csv: 000016.png"):
        read_folder(images, poses, CONVENTION)
    poses.write_text("\n".join([lines[0], lines[1].replace("000000.png", "missing.png")]) + "\n")
    with pytest.raises(PairingError, match="line 2 names image 'missing.png', which is not in"):
        read_folder(images, poses, CONVENTION)
    unnamed = tmp_path / "unnamed.csv"
    unnamed.write_text("\n".join(line.split(",", 1)[1] for line in lines[:5]) + "\n")
    with pytest.raises(PairingError, match="has 17 images but .*unnamed.csv 4 poses"):
        read_folder(images, unnamed, CONVENTION)
    samples = tmp_path / "bad.samples"
    samples.write_text("samples:\n- robot: {translation: {x: 0, y: 0, z: 0}}\n")
    with pytest.raises(LayoutError, match=r"bad.samples: samples\[0\].robot: expected translation"):
        read_easy_handeye_samples(samples)
    (tmp_path / "visp").mkdir()
    (tmp_path / "visp" / "pose_fPe_1.yaml").write_text("rows: 6\ncols: 1\ndata:\n  - [0.1]\n")
    (tmp_path / "visp" / "image-1.png").write_bytes((exported["visp"] / "image-1.png").read_bytes())
    assert (
        main(
            [
                "import",
                "visp",
                str(tmp_path / "visp"),
                "--out",
                str(tmp_path / "x"),
                "--board",
                "hec_8qr",
                "--intrinsics",
                str(exported["camera"]),
            ]
        )
        == 2
    )
    assert not (tmp_path / "x").exists()


def test_bad_joint_files_name_the_file_and_the_field(exported, tmp_path) -> None:
    images, poses = exported["folder"] / "images", exported["folder"] / "poses.csv"
    lines = (exported["folder"] / "joints.csv").read_text().splitlines()
    joints = tmp_path / "joints.csv"
    joints.write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(LayoutError, match=r"joints.csv: no joints for image 000016.png"):
        read_folder(images, poses, CONVENTION, joint_file=JointFile(joints))
    joints.write_text("\n".join(line.split(",", 1)[1] for line in lines[:5]) + "\n")
    with pytest.raises(LayoutError, match="joints.csv has 4 rows of joints but the pose file 17"):
        read_folder(images, poses, CONVENTION, joint_file=JointFile(joints))
    joints.write_text(
        "\n".join([lines[0], lines[1].replace(lines[1].split(",")[3], "nan"), *lines[2:]]) + "\n"
    )
    with pytest.raises(PoseFileError, match="joints.csv: line 2: a NaN or infinite number"):
        read_folder(images, poses, CONVENTION, joint_file=JointFile(joints))
    joints.write_text("\n".join(",".join(line.split(",")[:4]) for line in lines) + "\n")
    with pytest.raises(
        LayoutError, match="joint order 'ros-driver' is a UR arm's, for six joints; the file has 3"
    ):
        read_folder(images, poses, CONVENTION, joint_file=JointFile(joints, order="ros-driver"))
    three = read_folder(images, poses, CONVENTION, joint_file=JointFile(joints, unit="deg"))
    assert three.joints.shape == (17, 3)  # any count of joints in the arm's order
    joints.write_text("image,q1\n000000.png,zero\n")
    with pytest.raises(PoseFileError, match=r"joints.csv: line 2, column 'q1': not a number: 'zero'"):
        read_folder(images, poses, CONVENTION, joint_file=JointFile(joints))


def test_import_without_camera_or_board_is_refused(exported, tmp_path, capsys) -> None:
    argv = _import(exported, tmp_path / "x", "visp")
    without_camera = argv[: argv.index("--intrinsics")] + ["--quiet"]
    assert main(without_camera) == 2
    assert "give --intrinsics FILE or --camera" in capsys.readouterr().err
    without_board = [a for a in argv if a not in ("--board", "hec_8qr")]
    assert main(without_board) == 2
    assert "--board is needed to import images" in capsys.readouterr().err
