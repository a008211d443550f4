"""hec's public API (hec.api, re-exported as hec.*): the example script runs on a rendered dataset, gives
the command line's calibration, and importing hec does not load it."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.hec_cli import run_hec

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "examples" / "calibrate_a_dataset.py"
IMPORT_EXAMPLE = ROOT / "docs" / "examples" / "import_verify_export.py"


def test_hec_offers_every_name_of_its_api() -> None:
    import hec
    from hec import api

    assert sorted(hec.API) == sorted(api.__all__)
    assert all(getattr(hec, name) is getattr(api, name) for name in hec.API)


def test_importing_hec_does_not_load_the_api() -> None:
    code = (
        "import sys, hec; assert 'hec.api' not in sys.modules; hec.calibrate; assert 'hec.api' in sys.modules"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_the_example_script_calibrates_as_the_command_line_does(
    default_dataset: Path, tmp_path: Path
) -> None:
    dataset = tmp_path / "dataset"
    shutil.copytree(default_dataset, dataset)
    ran = subprocess.run(
        [sys.executable, str(EXAMPLE), str(dataset), str(tmp_path / "report")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    assert "T_flange_cam translation [mm]:" in ran.stdout and "verdict: " in ran.stdout
    assert (tmp_path / "report" / "report.html").is_file()
    code, _, stderr = run_hec(["calibrate", str(dataset), "--json", str(tmp_path / "cli.json"), "--quiet"])
    assert code == 0, stderr
    cli = np.array(json.loads((tmp_path / "cli.json").read_text())["T_flange_cam"])

    import hec

    api = hec.calibrate(hec.load_dataset(dataset), cross_validate=False)
    np.testing.assert_allclose(api.T_flange_cam, cli, atol=1e-9)
    assert hec.verdict(api).grade in ("good", "usable", "redo")


def test_the_api_page_shows_the_examples_as_they_are() -> None:
    page = (ROOT / "docs" / "pages" / "api.md").read_text()
    shown = [block.split("```", 1)[0] for block in page.split("```python\n")[1:]]
    assert [
        example.read_text().split('"""\n', 2)[-1].lstrip() for example in (EXAMPLE, IMPORT_EXAMPLE)
    ] == shown


def test_the_import_example_gives_the_command_lines_dataset_transform_and_files(
    default_dataset: Path, tmp_path: Path
) -> None:
    """The example imports an image folder with poses, calibrates, verifies and exports through
    hec.*; the same steps through the command line give the same frames, transform, verification and
    launch file (up to the paths they name)."""
    from hec.estimator.io.dataset import load_dataset
    from hec.estimator.io.intrinsics_file import write_opencv_intrinsics
    from hec.estimator.io.layouts import write_folder
    from hec.estimator.io.pose_file import PoseConvention

    source = load_dataset(default_dataset)
    pngs = [(source.root / row["rgb"]).read_bytes() for row in source.rows]
    T_base_flange = np.array([row["T_base_flange"] for row in source.rows])
    folder = write_folder(tmp_path / "folder", pngs, T_base_flange, PoseConvention())
    camera = write_opencv_intrinsics(tmp_path / "camera.yaml", source.intrinsics)
    new_frames = tmp_path / "new_frames"
    shutil.copytree(default_dataset, new_frames)
    images, poses = folder / "images", folder / "poses.csv"

    api, cli = tmp_path / "api", tmp_path / "cli"
    arguments = [str(path) for path in (IMPORT_EXAMPLE, images, poses, camera, new_frames, api)]
    ran = subprocess.run([sys.executable, *arguments], capture_output=True, text=True, check=False)
    assert ran.returncode == 0, ran.stderr
    assert f"imported {len(pngs)} images" in ran.stdout and "verify: " in ran.stdout

    steps = [
        ["import", "folder", str(images), "--out", str(cli / "dataset"), "--board", "hec_8qr"]
        + ["--intrinsics", str(camera), "--poses", str(poses), "--quiet"],
        ["calibrate", str(cli / "dataset"), "--json", str(cli / "calibration.json"), "--no-loo", "--quiet"],
        ["verify", str(cli / "calibration.json"), str(new_frames), "--json", str(cli / "verify.json")],
        ["export", str(cli / "calibration.json"), "--to", "ros2-launch", "--assume-zero-offset"]
        + ["--out", str(cli / "handeye.launch.py")],
    ]
    for argv in steps:
        code, _, stderr = run_hec(argv)
        assert code in (0, 1), (argv, stderr)  # verify: 1 when it finds the camera moved

    assert (api / "dataset" / "frames.csv").read_bytes() == (cli / "dataset" / "frames.csv").read_bytes()
    detections = [json.loads((root / "dataset" / "detections.json").read_text()) for root in (api, cli)]
    for record in detections:  # a hash of dataset.json, which records when and from where it was imported
        del record["dataset_fingerprint"]
    assert detections[0] == detections[1]
    from_api = json.loads((api / "calibration.json").read_text())
    from_cli = json.loads((cli / "calibration.json").read_text())
    np.testing.assert_allclose(from_api["T_flange_cam"], from_cli["T_flange_cam"], atol=1e-9)
    np.testing.assert_allclose(from_api["covariance"], from_cli["covariance"], atol=1e-12)

    import hec

    verified = hec.verify(api / "calibration.json", new_frames)
    np.testing.assert_allclose(
        verified.verification.delta, json.loads((cli / "verify.json").read_text())["delta"], atol=1e-9
    )
    launch_api = (api / "handeye.launch.py").read_text().replace(str(api), "OUT")
    launch_cli = (cli / "handeye.launch.py").read_text().replace(str(cli), "OUT")
    assert launch_api == launch_cli


def test_the_apis_refusals_are_typed_and_say_what_the_command_line_says(tmp_path: Path) -> None:
    """An import without a board, an export whose camera_link -> optical transform is unknown and a
    plan of 2 views: each raises its typed error, and `hec` prints the same message after
    `hec: error:` with exit code 2."""
    import hec

    images = tmp_path / "images"
    images.mkdir()
    calibration = tmp_path / "cal.json"
    record = {"format": "hec-calibration", "version": 1, "method": "ekf", "T_flange_cam": np.eye(4).tolist()}
    calibration.write_text(json.dumps(record))
    out = tmp_path / "out"
    cases = [
        (
            lambda: hec.import_dataset("folder", images, out),
            hec.DatasetImportError,
            ["import", "folder", str(images), "--out", str(out)],
        ),
        (
            lambda: hec.export(calibration, "urdf"),
            hec.ExportError,
            ["export", str(calibration), "--to", "urdf"],
        ),
        (
            lambda: hec.plan(tmp_path / "w.csv", views=2),
            hec.PlanError,
            ["plan", "--out", str(tmp_path / "w.csv"), "--views", "2"],
        ),
    ]
    for call, error, argv in cases:
        with pytest.raises(error) as raised:
            call()
        code, stdout, stderr = run_hec(argv)
        assert (code, stdout, stderr) == (2, "", f"hec: error: {raised.value}\n"), argv
    assert not out.exists() and not (tmp_path / "w.csv").exists()
