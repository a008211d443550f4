"""A dataset held in memory: what DatasetWriter would write and load_dataset read back, without
the files. A sweep's render trials use it, so their frames go from the renderer to the detector
without PNGs; the estimators see the same numbers as through the disk (tests/test_sweep_memory.py).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from hec.estimator.common.depth_png import decode_depth, encode_depth
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.transforms import transform_from_xyz_quat, xyz_quat_from_transform
from hec.estimator.io.dataset import dataset_json
from hec.estimator.observe.frames import Dataset, Frame, GroundTruth
from hec.estimator.targets.target import Target


def stored_frame(frame: Frame, depth_scale_m: float) -> Frame:
    """The frame as a dataset stores it and reads it back: the reported pose through frames.csv's
    translation and quaternion, the depth through uint16 steps of depth_scale_m (metres). The
    colour image is stored losslessly and shared, not copied."""
    xyz, quaternion = xyz_quat_from_transform(frame.T_base_flange)
    return replace(
        frame,
        depth_m=None
        if frame.depth_m is None
        else decode_depth(encode_depth(frame.depth_m, depth_scale_m), depth_scale_m),
        T_base_flange=transform_from_xyz_quat(xyz, quaternion),
    )


def dataset_in_memory(
    frames: list[Frame],
    intrinsics: CameraIntrinsics,
    board: Target,
    depth_scale_m: float,
    source: str,
    ground_truth: GroundTruth | None = None,
    extra: dict | None = None,
    name: str = "in memory",
) -> Dataset:
    """The dataset DatasetWriter(...).finish(ground_truth, extra) would write from these frames, as
    load_dataset would read it, held in memory. name: what messages call it (its root)."""
    stored = [stored_frame(frame, depth_scale_m) for frame in frames]
    meta = dataset_json(intrinsics, depth_scale_m, source, len(stored), ground_truth) | (extra or {})
    rows = [
        {
            "frame": i,
            "time_s": float(frame.time_s),
            "rgb": f"rgb/{i:06d}.png",
            "depth": "" if frame.depth_m is None else f"depth/{i:06d}.png",
            "T_base_flange": frame.T_base_flange,
            "joints": frame.joints.astype(float),
            "waypoint": None,
        }
        for i, frame in enumerate(stored)
    ]
    metadata = json.loads(json.dumps(meta))  # as read back: lists for tuples, plain floats
    return Dataset(Path(f"({name})"), metadata, intrinsics, board, depth_scale_m, rows, ground_truth, stored)
