"""DatasetRecorder: frames written in place one by one, and a session resumed after a crash."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.io.board_file import find_board
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.recorder import DatasetRecorder
from hec.estimator.observe.frames import Capture, DatasetError, Frame

INTRINSICS = CameraIntrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)


def _capture(i: int) -> Capture:
    rgb = np.full((48, 64, 3), 10 * i, dtype=np.uint8)
    depth = np.full((48, 64), 0.5 + 0.01 * i, dtype=np.float32)
    T = np.eye(4)
    T[:3, 3] = [0.1 * i, 0.0, 0.3]
    frame = Frame(rgb, depth, INTRINSICS, T, np.full(6, 0.1 * i), float(i))
    return Capture(frame, depth_samples=np.full((48, 64), 4, dtype=np.uint8))


def _recorder(root: Path, resume: bool = False, intrinsics: CameraIntrinsics = INTRINSICS) -> DatasetRecorder:
    return DatasetRecorder(root, intrinsics, find_board("hec_8qr"), 1e-4, "test", {"note": 1}, resume=resume)


def test_every_frame_is_on_disk_as_soon_as_it_is_added(tmp_path: Path) -> None:
    root = tmp_path / "session"
    recorder = _recorder(root)
    assert len(load_dataset(root)) == 0  # a valid, empty dataset from the start
    recorder.add_frame(_capture(0), waypoint=3)
    recorder.add_frame(_capture(1), waypoint=5)
    dataset = load_dataset(root)  # without finish(): what a crash would leave
    assert len(dataset) == 2 and dataset.metadata["recording"] == "in progress"
    assert [row["waypoint"] for row in dataset.rows] == [3, 5] and dataset.metadata["note"] == 1
    np.testing.assert_allclose(dataset.frame(1).depth_m, 0.51, atol=1e-4)
    assert (root / "depth_samples" / "000001.png").is_file()
    with pytest.raises(FileExistsError, match="add --resume"):
        _recorder(root)


def test_resume_drops_a_row_cut_short_and_appends(tmp_path: Path) -> None:
    root = tmp_path / "session"
    recorder = _recorder(root)
    recorder.add_frame(_capture(0), waypoint=0)
    with open(root / "frames.csv", "a") as f:
        f.write("1,1.0,rgb/000001.png,dep")  # the power went out here
    resumed = _recorder(root, resume=True)
    assert resumed.recorded_waypoints == {0}
    assert resumed.add_frame(_capture(1), waypoint=1) == 1
    resumed.finish("complete")
    dataset = load_dataset(root)
    assert len(dataset) == 2 and dataset.metadata["recording"] == "complete"
    assert dataset.rows[1]["T_base_flange"][0, 3] == pytest.approx(0.1)


def test_resume_refuses_another_camera(tmp_path: Path) -> None:
    root = tmp_path / "session"
    _recorder(root).add_frame(_capture(0), waypoint=0)
    other = CameraIntrinsics(64, 48, 61.0, 60.0, 31.5, 23.5)
    with pytest.raises(DatasetError, match="cannot resume, 'camera.fx' was 60.0 and is now 61.0"):
        _recorder(root, resume=True, intrinsics=other)
