"""Images pair with poses by an explicit key, never silently by name order: on the rendered default
dataset written as other tools write it (numbered names, files without a header, spreadsheets'
CSV, numpy arrays, times), each pairing mistake is refused or named, and the right pairing is kept."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hec.cli import main
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.intrinsics_file import write_opencv_intrinsics
from hec.estimator.io.layouts import read_folder
from hec.estimator.io.pairing import PairingError, natural_key
from hec.estimator.io.pose_file import PoseConvention, PoseFileError, values_from_poses
from hec.estimator.io.pose_table import read_number_table
from hec.estimator.observe.frames import Dataset

CONVENTION = PoseConvention("quat-wxyz")


@pytest.fixture(scope="module")
def numbered(default_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The default rendered dataset's images as img_1.png .. img_17.png (no zero padding, so name
    order is not frame order), its camera as OpenCV YAML, and its poses in CONVENTION (17, 7)."""
    root = tmp_path_factory.mktemp("numbered")
    source = copy_images(default_dataset, root / "images", "img_{}.png", first=1)
    T_base_flange = np.array([row["T_base_flange"] for row in source.rows])
    return {
        "root": root,
        "images": root / "images",
        "camera": write_opencv_intrinsics(root / "camera.yaml", source.intrinsics),
        "values": values_from_poses(T_base_flange, CONVENTION),
    }


def copy_images(dataset: Path, folder: Path, name: str, first: int = 0) -> Dataset:
    """Copy a dataset's colour images into folder as name.format(first), name.format(first + 1), ...;
    returns the dataset."""
    source = load_dataset(dataset)
    folder.mkdir()
    for i, row in enumerate(source.rows):
        (folder / name.format(first + i)).write_bytes((source.root / row["rgb"]).read_bytes())
    return source


def _csv(values: np.ndarray, header: str | None = "x,y,z,qw,qx,qy,qz", sep: str = ",") -> str:
    lines = [header.replace(",", sep)] if header is not None else []
    lines += [sep.join(repr(float(v)) for v in row) for row in values]
    return "\n".join(lines) + "\n"


def _expected_order(frames_images: list[Path]) -> list[int]:
    """The frame index of each paired image, from its name img_K.png (frame K - 1)."""
    return [int(p.stem.split("_")[1]) - 1 for p in frames_images]


def test_numbered_images_pair_in_natural_order_not_name_order(numbered: dict, tmp_path: Path) -> None:
    poses = tmp_path / "poses.csv"
    poses.write_text(_csv(numbered["values"]))
    frames = read_folder(numbered["images"], poses, CONVENTION)
    assert frames.pairing.key == "number"
    assert [p.name for p in frames.images[8:11]] == ["img_9.png", "img_10.png", "img_11.png"]
    np.testing.assert_array_equal(frames.pose_values, numbered["values"])
    # Name order would have paired img_10.png with the second pose.
    assert sorted(p.name for p in frames.images)[1] == "img_10.png"
    lexicographic = read_folder(numbered["images"], poses, CONVENTION, pair_by="order")
    assert lexicographic.images[1].name == "img_10.png"
    assert "in name order with the rows in order (--pair-by order)" in lexicographic.pairing.describe()


def test_a_pose_file_without_a_header_keeps_its_first_pose(numbered: dict, tmp_path: Path) -> None:
    poses = tmp_path / "poses.csv"
    poses.write_text(_csv(numbered["values"], header=None))
    table = read_number_table(poses)
    assert "no header row" in table.layout and len(table.values) == 17
    frames = read_folder(numbered["images"], poses, CONVENTION)
    np.testing.assert_array_equal(frames.pose_values, numbered["values"])


def test_spreadsheet_and_numpy_files_read_the_same_numbers(numbered: dict, tmp_path: Path) -> None:
    values = numbered["values"]
    excel = tmp_path / "excel.csv"  # a BOM, CRLF, semicolons and decimal commas
    text = _csv(values, sep=";").replace(".", ",")
    excel.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    tabs = tmp_path / "tabs.tsv"
    tabs.write_text(_csv(values, sep="\t"))
    spaces = tmp_path / "savetxt.txt"
    np.savetxt(spaces, values)
    stack = tmp_path / "poses.npy"
    np.save(stack, values)
    for path in (excel, tabs, spaces, stack):
        frames = read_folder(numbered["images"], path, CONVENTION)
        np.testing.assert_allclose(frames.pose_values, values, rtol=0, atol=1e-12, err_msg=str(path))


def test_a_4x4_stack_reads_as_matrices_and_says_so(numbered: dict, tmp_path: Path) -> None:
    matrices = np.tile(np.eye(4), (17, 1, 1))
    matrices[:, :3, 3] = numbered["values"][:, :3]
    path = tmp_path / "T_base_flange.npy"
    np.save(path, matrices)
    frames = read_folder(numbered["images"], path, PoseConvention("matrix"))
    np.testing.assert_array_equal(frames.T_base_flange, matrices)
    with pytest.raises(PoseFileError, match=r"4x4 matrices\? pass --rotation matrix"):
        read_folder(numbered["images"], path, CONVENTION)


@pytest.mark.parametrize("where", ["start", "end"])
def test_a_pose_off_by_one_or_a_waiting_pose_is_refused(numbered: dict, tmp_path: Path, where: str) -> None:
    values = numbered["values"]
    extra = values[:1] if where == "start" else values[-1:]  # the robot waited at the end
    poses = tmp_path / "poses.csv"
    poses.write_text(_csv(np.vstack([extra, values]) if where == "start" else np.vstack([values, extra])))
    with pytest.raises(PairingError, match="has 17 images but .*poses.csv 18 poses") as info:
        read_folder(numbered["images"], poses, CONVENTION)
    same = "line 2 and line 3" if where == "start" else "line 18 and line 19"
    assert f"{same} hold the same pose: a robot that waited, or a row written twice?" in str(info.value)


def test_names_without_numbers_are_refused_unless_name_order_is_asked(numbered: dict, tmp_path: Path) -> None:
    images = tmp_path / "images"
    images.mkdir()
    for k, path in enumerate(sorted(numbered["images"].iterdir(), key=lambda p: natural_key(p.name))):
        (images / f"view_{chr(ord('a') + k)}.png").write_bytes(path.read_bytes())
    poses = tmp_path / "poses.csv"
    poses.write_text(_csv(numbered["values"]))
    with pytest.raises(
        PairingError, match="carry no number to pair by: add an 'image' column .*--pair-by order"
    ):
        read_folder(images, poses, CONVENTION)
    frames = read_folder(images, poses, CONVENTION, pair_by="order")
    assert frames.images[0].name == "view_a.png"


def test_ambiguous_or_repeated_rows_are_refused(numbered: dict, tmp_path: Path) -> None:
    poses = tmp_path / "poses.csv"
    poses.write_text("image,1,2,3,4,5,6,7\n" + _csv(numbered["values"], header=None))
    with pytest.raises(PoseFileError, match="line 1 mixes names and numbers"):
        read_folder(numbered["images"], poses, CONVENTION)
    rows = [f"img_{i + 1}.png," + ",".join(map(repr, v.tolist())) for i, v in enumerate(numbered["values"])]
    poses.write_text("\n".join(["image,x,y,z,qw,qx,qy,qz", *rows, rows[4]]) + "\n")
    with pytest.raises(PoseFileError, match=r"image 'img_5.png' is listed twice \(line 6 and line 19\)"):
        read_folder(numbered["images"], poses, CONVENTION)


def test_images_pair_with_the_pose_nearest_in_time(numbered: dict, tmp_path: Path) -> None:
    images = tmp_path / "images"
    images.mkdir()
    image_times = 1700000000.0 + 2.0 * np.arange(17) + 0.004  # an image every 2 s, 4 ms after its pose
    for k, path in enumerate(sorted(numbered["images"].iterdir(), key=lambda p: natural_key(p.name))):
        (images / f"{image_times[k]:.6f}.png").write_bytes(path.read_bytes())
    # Poses at 10 Hz: the arm's poses between the views are other rows.
    pose_times = 1700000000.0 + 0.1 * np.arange(340)
    values = np.repeat(numbered["values"], 20, axis=0)
    lines = ["time,x,y,z,qw,qx,qy,qz"] + [
        f"{float(t)!r}," + ",".join(map(repr, v.tolist())) for t, v in zip(pose_times, values, strict=True)
    ]
    poses = tmp_path / "poses.csv"
    poses.write_text("\n".join(lines) + "\n")
    frames = read_folder(images, poses, CONVENTION, pair_by="time", time_tolerance_s=0.01)
    assert frames.pairing.rows == list(range(0, 340, 20))
    np.testing.assert_array_equal(frames.pose_values, numbered["values"])
    with pytest.raises(PairingError, match=r"no pose within 0.001 s .*nearest: line 2, 0.004 s away"):
        read_folder(images, poses, CONVENTION, pair_by="time", time_tolerance_s=0.001)


def test_import_prints_and_records_the_pairing(numbered: dict, tmp_path: Path, capsys) -> None:
    poses = tmp_path / "poses.csv"
    poses.write_text(_csv(numbered["values"], header=None))
    out = tmp_path / "dataset"
    argv = ["import", "folder", str(numbered["images"]), "--poses", str(poses), "--out", str(out)]
    argv += ["--board", "hec_8qr", "--intrinsics", str(numbered["camera"]), "--no-check"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert (
        "paired 17 images with poses by the number in each image's name (natural order) with the rows in "
        "order: img_1.png - line 1, img_2.png - line 2, ..., img_17.png - line 17"
    ) in printed
    pairing = json.loads((out / "dataset.json").read_text())["provenance"]["pairing"]
    assert pairing["key"] == "number"
    assert pairing["pairs"][9] == ["img_10.png", "line 10"]
    assert _expected_order([Path(name) for name, _ in pairing["pairs"]]) == list(range(17))


def test_an_image_column_one_row_off_is_named_by_the_import_check(
    numbered: dict, tmp_path: Path, capsys
) -> None:
    """The pose file names each image, but the poses were logged one row late: every image has the
    previous image's pose. The pairing is explicit, so only the images can tell: the import check
    names it (rendered images, real detector)."""
    poses = tmp_path / "poses.csv"
    values = np.vstack([numbered["values"][:1], numbered["values"][:-1]])
    rows = [f"img_{k + 1}.png," + ",".join(repr(float(v)) for v in row) for k, row in enumerate(values)]
    poses.write_text("image,x,y,z,qw,qx,qy,qz\n" + "\n".join(rows) + "\n")
    out = tmp_path / "dataset"
    argv = ["import", "folder", str(numbered["images"]), "--poses", str(poses), "--out", str(out)]
    argv += ["--board", "hec_8qr", "--intrinsics", str(numbered["camera"]), "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "the robot poses look like each image paired with the previous image's pose" in printed, printed
    assert "check the pairing of images and poses" in printed


def test_numpy_depth_in_metres_and_the_depth_camera_are_imported(
    numbered: dict, default_dataset: Path, tmp_path: Path
) -> None:
    source = load_dataset(default_dataset)
    depth_dir = tmp_path / "depth"
    depth_dir.mkdir()
    for i in range(len(source)):
        np.save(depth_dir / f"img_{i + 1}.npy", source.frame(i).depth_m)
    poses = tmp_path / "poses.csv"
    poses.write_text(_csv(numbered["values"]))
    out = tmp_path / "dataset"
    argv = ["import", "folder", str(numbered["images"]), "--poses", str(poses), "--out", str(out)]
    argv += ["--board", "hec_8qr", "--intrinsics", str(numbered["camera"]), "--no-check"]
    argv += ["--depth", str(depth_dir), "--depth-camera", "d405"]
    assert main(argv) == 2  # metres read as millimetres: the depths are refused, naming the scale
    assert not out.exists()
    assert main([*argv, "--depth-scale", "1"]) == 0
    imported = load_dataset(out)
    assert imported.metadata["depth_noise"]["baseline_m"] == 0.018
    np.testing.assert_allclose(imported.frame(3).depth_m, source.frame(3).depth_m, rtol=0, atol=1.01e-3)
