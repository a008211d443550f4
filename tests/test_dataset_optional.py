"""Datasets from other cells: frames without depth, arms of any number of joints (or none), and
what still calibrates from them."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.transforms import pose_error
from hec.estimator.io.dataset import DatasetWriter, load_dataset
from hec.estimator.observe.frames import DatasetError
from hec.estimator.observe.observations import observe_dataset
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import solve
from hec.estimator.solve.problem import build_problem, dataset_arm, dataset_robot_noise


def _rewritten(source: Path, out: Path, joints: int | None, depth: bool) -> Path:
    """source's frames written again with joints (N,) zeros (None: the recorded six) and without
    depth unless depth."""
    dataset = load_dataset(source)
    with DatasetWriter(out, dataset.intrinsics, dataset.board, dataset.depth_scale_m, "import") as writer:
        for i in range(len(dataset)):
            frame = dataset.frame(i)
            writer.add_frame(
                replace(
                    frame,
                    depth_m=frame.depth_m if depth else None,
                    joints=frame.joints if joints is None else np.linspace(0.1, 0.7, joints),
                )
            )
        return writer.finish(dataset.ground_truth, {"robot_model": "ur5"})


@pytest.mark.parametrize(("joints", "depth"), [(7, False), (0, True), (None, False)])
def test_any_joint_count_and_no_depth_read_back_and_calibrate(
    default_dataset: Path, tmp_path: Path, joints: int | None, depth: bool
) -> None:
    out = _rewritten(default_dataset, tmp_path / "imported", joints, depth)
    header = (out / "frames.csv").read_text().splitlines()[0].split(",")
    assert header[11:] == [f"q{i}_rad" for i in range(1, (6 if joints is None else joints) + 1)]
    assert (out / "depth").is_dir() == depth
    dataset = load_dataset(out)
    frame = dataset.frame(0)
    assert frame.joints.shape == (6 if joints is None else joints,)
    assert (frame.depth_m is not None) == depth
    # The UR kinematics need the arm's six joints: other counts leave the arm unknown.
    assert (dataset_arm(dataset) is not None) == (joints is None)
    observations = observe_dataset(dataset)
    if not depth:
        assert all(m.points_cam is None for o in observations for m in o.markers)
        assert "no depth image; markers kept without depth" in observations[0].notes
    problem = build_problem(
        observations,
        dataset.board,
        dataset.intrinsics,
        dataset_robot_noise(dataset),
        arm=dataset_arm(dataset),
    )
    for method in ("ekf", "opencv-park"):
        calibration = solve(method, problem, MethodOptions(), observations)
        error_m, error_rad = pose_error(calibration.T_flange_cam, dataset.ground_truth.T_flange_cam)
        assert error_m < 1e-3 and np.degrees(error_rad) < 0.1, (method, error_m, error_rad)


def test_frames_of_different_joint_counts_are_refused(default_dataset: Path, tmp_path: Path) -> None:
    dataset = load_dataset(default_dataset)
    with DatasetWriter(
        tmp_path / "x", dataset.intrinsics, dataset.board, dataset.depth_scale_m, "import"
    ) as w:
        w.add_frame(replace(dataset.frame(0), joints=np.zeros(7)))
        with pytest.raises(DatasetError, match="frame 1 has 6 joints, the frames before it 7"):
            w.add_frame(dataset.frame(1))
    assert not (tmp_path / "x").exists()
