"""Render trials in memory: a dataset held in memory reads back what DatasetWriter writes and
load_dataset reads, and a sweep's render trial gives the same rows in memory as through the disk."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.transforms import transform_from_xyz_quat
from hec.estimator.io.board_file import find_board
from hec.estimator.io.dataset import DatasetWriter, load_dataset
from hec.estimator.io.memory import dataset_in_memory
from hec.estimator.observe.frames import Frame, GroundTruth
from hec.sweep.config import load_config
from hec.sweep.runner import same_rows
from hec.sweep.trials import run_trial, tasks_for

DEPTH_SCALE_M = 0.0001


def _frames(rng: np.random.Generator, k: CameraIntrinsics, count: int) -> list[Frame]:
    """Frames with random images, depths off the depth steps and poses with full-precision rotations."""
    frames = []
    for i in range(count):
        T = transform_from_xyz_quat(rng.normal(size=3), rng.normal(size=4))
        T[:3, :3] += 1e-13 * rng.normal(size=(3, 3))  # not exactly what its quaternion gives back
        depth = rng.uniform(0.2, 2.0, (k.height, k.width)).astype(np.float32)
        depth[rng.random(depth.shape) < 0.1] = 0.0
        rgb = rng.integers(0, 256, (k.height, k.width, 3), dtype=np.uint8)
        frames.append(Frame(rgb, depth, k, T, rng.normal(size=6), 1.5 * i + 0.1))
    return frames


def test_a_dataset_in_memory_is_what_the_files_read_back(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    k = CameraIntrinsics(32, 24, 40.0, 41.0, 15.5, 11.5)
    frames, board = _frames(rng, k, 3), find_board("hec_8qr")
    truth = GroundTruth(np.eye(4), np.eye(4), np.eye(4), None, [np.eye(4)] * 3, [np.zeros(6)] * 3)
    extra = {"robot_pose_noise": {"translation_sigma_m": 1e-4, "rotation_sigma_rad": 2e-4}, "note": (1, 2)}
    with DatasetWriter(tmp_path / "d", k, board, DEPTH_SCALE_M, source="sim") as writer:
        for frame in frames:
            writer.add_frame(frame)
        on_disk = load_dataset(writer.finish(truth, extra))
    in_memory = dataset_in_memory(frames, k, board, DEPTH_SCALE_M, "sim", truth, extra)
    assert in_memory.metadata == on_disk.metadata
    assert in_memory.board == on_disk.board and in_memory.intrinsics == on_disk.intrinsics
    for i, row in enumerate(on_disk.rows):
        for key, value in row.items():
            assert np.array_equal(in_memory.rows[i][key], value), key
        a, b = in_memory.frame(i), on_disk.frame(i)
        for field in ("rgb", "depth_m", "T_base_flange", "joints"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field
            assert getattr(a, field).dtype == getattr(b, field).dtype, field
        assert a.time_s == b.time_s
    assert not np.array_equal(in_memory.frame(0).T_base_flange, frames[0].T_base_flange)  # as stored


def test_a_render_trial_in_memory_gives_the_rows_of_one_through_the_disk(tmp_path: Path) -> None:
    path = tmp_path / "render.toml"
    path.write_text(
        'fidelity = "render"\nseed = 5\ntrials = 1\nmethods = ["ekf", "batch", "opencv-park"]\n'
        '[fixed]\nwaypoints = 5\nmount = "random"\n'
    )
    (task,) = tasks_for(load_config(path))
    in_memory = run_trial(task)
    through_disk = run_trial(replace(task, keep_dir=str(tmp_path)))
    assert (tmp_path / task.trial_id / "rgb" / "000004.png").is_file()  # it did go through the disk
    assert all(row["status"] == "ok" for row in in_memory), in_memory
    assert same_rows(in_memory, through_disk) == []
