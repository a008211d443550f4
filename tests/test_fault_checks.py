"""Faults of the checks of the newer commands: a board of absurd size, a plan that writes fewer views
than asked, depth images of zeros, files that are not what they say, and results that do not fit
their data, named as such by every method with the frames that disagree most."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from hec.estimator.io.dataset import load_dataset
from tests.hec_cli import run_hec, scenario_file
from tests.test_export import _calibration_file
from tests.test_fault_pass import REPO
from tests.test_fault_pass_2 import _folder_import
from tests.test_import import _import, exported, rendered_samples

__all__ = ["exported", "rendered_samples"]  # the fixtures of test_import, shared


# --- board, plan, depth and files that are not what they say --------------------------------------


@pytest.mark.parametrize(
    ("size", "said"), [([10, 10], "no printer takes a sheet over 2 m"), ([1e6, 1e6], "no printer takes")]
)
def test_a_board_of_absurd_size_is_refused_before_its_sheet_is_drawn(
    tmp_path: Path, size: list, said: str
) -> None:
    board = json.loads((REPO / "models" / "boards" / "hec_8qr.json").read_text()) | {"size_m": size}
    (tmp_path / "big.json").write_text(json.dumps(board))
    code, _, err = run_hec(["board", "--board", str(tmp_path / "big.json"), "--out", str(tmp_path / "s.png")])
    assert code == 2 and f"is {size[0]:g} x {size[1]:g} m (its size_m): {said}" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.json"]


def test_a_sheet_too_many_pixels_at_its_dpi_names_the_dpi_that_fits(tmp_path: Path) -> None:
    board = json.loads((REPO / "models" / "boards" / "hec_8qr.json").read_text()) | {"size_m": [1.9, 1.9]}
    (tmp_path / "a0.json").write_text(json.dumps(board))
    argv = ["board", "--board", str(tmp_path / "a0.json"), "--out", str(tmp_path / "s.png"), "--dpi", "2400"]
    code, _, err = run_hec(argv)
    assert code == 2 and "at 2400 dpi its sheet is 32.2 gigapixels; give --dpi 423 or less" in err, err


def test_plan_says_why_it_writes_fewer_views_than_asked(tmp_path: Path) -> None:
    code, out, err = run_hec(
        ["plan", "--views", "60", "--candidates", "60", "--out", str(tmp_path / "w.csv")]
    )
    assert code == 0, err
    written = int(out.rsplit("wrote ", 1)[1].split(": ")[1].split()[0])
    assert written < 60 and f"note: {written} views, not the 60 asked: only " in out
    assert "give more --candidates for more" in out


@pytest.mark.parametrize("option", ["--calibration", "--scenario"])
def test_plan_never_writes_over_its_inputs(tmp_path: Path, option: str) -> None:
    source = _calibration_file(tmp_path) if option == "--calibration" else scenario_file(tmp_path)
    before = source.read_bytes()
    code, _, err = run_hec(["plan", option, str(source), "--out", str(source), "--views", "4"])
    assert code == 2 and f"--out {source}: is the {option[2:]} file this command reads" in err, err
    assert source.read_bytes() == before


def test_depth_images_of_zeros_count_as_no_depth(default_dataset: Path, exported, tmp_path: Path) -> None:
    depth = shutil.copytree(default_dataset / "depth", tmp_path / "depth")
    for name in ("000003.png", "000007.png"):
        cv2.imwrite(str(depth / name), np.zeros((480, 640), np.uint16))
    code, out, err = run_hec(_folder_import(exported, tmp_path / "ds", "--depth", str(depth), "--no-check"))
    assert code == 0, err
    assert "note: 2 depth images hold no depth (every pixel 0)" in out and "(15 with depth)" in out
    assert [bool(r["depth"]) for r in load_dataset(tmp_path / "ds").rows].count(False) == 2


@pytest.mark.parametrize(("field", "axis"), [("translation", "x"), ("rotation", "w")])
def test_a_nan_in_an_easy_handeye2_sample_is_named_as_a_nan(
    rendered_samples: Path, tmp_path: Path, field: str, axis: str
) -> None:
    data = yaml.safe_load(rendered_samples.read_text())
    data["samples"][2]["tracking"][field][axis] = float("nan")
    (tmp_path / "nan.samples").write_text(yaml.safe_dump(data))
    code, _, err = run_hec(
        ["import", "easy_handeye2", str(tmp_path / "nan.samples"), "--out", str(tmp_path / "o")]
    )
    assert code == 2 and "samples[2].tracking: translation and rotation must be finite numbers" in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["pose_fPe_2.yaml", "image-4.png"])
def test_a_visp_file_of_random_bytes_is_named(exported, tmp_path: Path, name: str) -> None:
    visp = shutil.copytree(exported["visp"], tmp_path / "visp")
    (visp / name).write_bytes(np.random.default_rng(1).bytes(300))
    argv = _import(exported, tmp_path / "o", "visp", "--no-check")
    code, _, err = run_hec([*argv[:2], str(visp), *argv[3:]])
    assert code == 2 and f"{visp / name}: not a" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o").exists()


def test_a_visp_image_renamed_by_a_file_manager_keeps_its_number(exported, tmp_path: Path) -> None:
    visp = shutil.copytree(exported["visp"], tmp_path / "visp")
    (visp / "image-3.png").rename(visp / "image-3 (copy).png")
    argv = _import(exported, tmp_path / "o", "visp", "--no-check")
    code, out, err = run_hec([*argv[:2], str(visp), *argv[3:]])
    assert code == 0 and "imported 17 images" in out, err
    assert "image-3 (copy).png" in load_dataset(tmp_path / "o").metadata["provenance"]["images"][2]


# --- results that do not fit their data say so, for every method ----------------------------------


@pytest.mark.parametrize("method", ["ekf", "opencv-tsai", "opencv-daniilidis"])
def test_a_frame_paired_with_another_frames_image_is_named_by_every_method(
    default_dataset: Path, tmp_path: Path, method: str
) -> None:
    ds = shutil.copytree(default_dataset, tmp_path / "ds")
    (ds / "detections.json").unlink(missing_ok=True)
    lines = (ds / "frames.csv").read_text().splitlines()
    cells = lines[6].split(",")  # frame 5 shows frame 9's images
    cells[2], cells[3] = "rgb/000009.png", "depth/000009.png"
    lines[6] = ",".join(cells)
    (ds / "frames.csv").write_text("\n".join(lines) + "\n")
    code, out, err = run_hec(["calibrate", str(ds), "--method", method, "--quiet", "--no-loo", "--verbose"])
    assert code == 2 and "the robot poses do not fit the images at any mount" in err, err
    assert "the frames that disagree most, by how far from the others each puts the board: frame 5 (" in err


@pytest.fixture(scope="module")
def inverted_pairs(rendered_samples: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The rendered pose pairs imported with the robot poses read the wrong way (--no-check)."""
    out = tmp_path_factory.mktemp("inverted") / "pairs"
    argv = ["import", "easy_handeye2", str(rendered_samples), "--out", str(out)]
    code, _, err = run_hec([*argv, "--pose-direction", "flange-to-base", "--no-check"])
    assert code == 0, err
    return out


@pytest.mark.parametrize(
    "method",
    ["opencv-tsai", "opencv-horaud", "opencv-andreff", "opencv-daniilidis", "opencv-shah", "opencv-li"],
)
def test_every_opencv_method_says_a_result_a_metre_off_does_not_fit(
    inverted_pairs: Path, method: str
) -> None:
    code, out, err = run_hec(["calibrate", str(inverted_pairs), "--method", method, "--quiet", "--no-loo"])
    if code == 0:
        assert f"{method}'s result does not fit its data: the board pose's spread over the pairs" in out, out
        assert "the pairs that disagree most: pair " in out
    else:  # no solution at all is a refusal, not a result
        assert code == 2 and "found no solution" in err, err


def test_pose_pairs_that_fit_raise_no_misfit(rendered_samples: Path, tmp_path: Path) -> None:
    code, _, err = run_hec(["import", "easy_handeye2", str(rendered_samples), "--out", str(tmp_path / "p")])
    assert code == 0, err
    code, out, err = run_hec(
        ["calibrate", str(tmp_path / "p"), "--method", "opencv-tsai", "--quiet", "--no-loo"]
    )
    assert code == 0 and "does not fit its data" not in out, out


def test_pose_pairs_with_one_robot_pose_throughout_cannot_be_checked(
    rendered_samples: Path, tmp_path: Path
) -> None:
    data = yaml.safe_load(rendered_samples.read_text())
    for sample in data["samples"]:
        sample["robot"] = data["samples"][0]["robot"]
    (tmp_path / "same.samples").write_text(yaml.safe_dump(data))
    code, out, err = run_hec(
        ["import", "easy_handeye2", str(tmp_path / "same.samples"), "--out", str(tmp_path / "o")]
    )
    assert code == 0, err
    assert "convention check: cannot check the pose pairs' directions: the flange barely rotates" in out
    assert "fit" not in out.split("convention check:")[1].split(":")[0]


def test_the_library_names_the_frame_that_disagrees_in_a_result_that_does_not_fit(
    default_dataset: Path,
) -> None:
    """Past the command's first check: run_method's own warning, OpenCV's methods included."""
    from hec.estimator.observe.observations import observe_dataset
    from hec.estimator.solve.calibration import MethodOptions
    from hec.estimator.solve.methods import run_method
    from hec.estimator.solve.problem import build_problem, dataset_robot_noise

    dataset = load_dataset(default_dataset)
    observations = observe_dataset(dataset)
    swapped = list(observations)  # frame 5's robot pose with frame 9's image
    swapped[5] = replace(observations[9], frame=5, T_base_flange=observations[5].T_base_flange)
    problem = build_problem(swapped, dataset.board, dataset.intrinsics, dataset_robot_noise(dataset))
    result = run_method("opencv-tsai", problem, MethodOptions(), swapped)
    misfit = result.diagnostics["misfit"]
    assert misfit in result.warnings and "opencv-tsai's result does not fit its data" in misfit
    assert "puts the board: frame 5 (" in misfit
    right = build_problem(observations, dataset.board, dataset.intrinsics, dataset_robot_noise(dataset))
    assert "misfit" not in run_method("opencv-tsai", right, MethodOptions(), observations).diagnostics


def test_the_board_check_never_says_fits_at_many_times_the_corners_noise(exported, tmp_path: Path) -> None:
    """A camera 13 % off (fx 700 for 617): the board poses leave 50 times the normal residual."""
    argv = _folder_import(exported, tmp_path / "ds", "--camera", "700", "700", "320", "240", "640", "480")
    code, out, err = run_hec([a for a in argv if a not in ("--intrinsics", str(exported["camera"]))])
    assert code == 0, err
    board = out.split("board check: ")[1]
    assert "fits" not in board.split(";")[0] and "times the corners' noise" in board, out
    assert "intrinsics or lens model" in board
