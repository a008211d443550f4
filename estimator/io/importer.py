"""hec datasets from other tools' layouts (hec.estimator.io.layouts), written atomically, with where they
came from in dataset.json's ``provenance``: the layout, the source files, the pose convention, the
pose numbers as the source wrote them (so a later convention check can read them otherwise), the
hec version and the time of the import."""

from __future__ import annotations

import datetime
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import cv2
import numpy as np

from hec.estimator.common.depth_png import decode_depth
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.io.dataset import DatasetWriter
from hec.estimator.io.layouts import JointFile, LayoutError, LayoutFrames
from hec.estimator.observe.frames import Frame
from hec.estimator.observe.pose_pairs import POSE_PAIRS_FILE, PosePair, pose_pairs_json
from hec.estimator.targets.target import Target

NUMPY_DEPTH_STEP_M = 1e-4


def provenance(
    layout: str,
    sources: list[str | Path],
    frames: LayoutFrames | None = None,
    joint_file: JointFile | None = None,
) -> dict:
    """dataset.json's 'provenance' of an import: layout, absolute source paths, the pose convention
    and pose numbers (image layouts), the joints' unit and order as the source wrote them, the hec
    version and the time (UTC, ISO 8601)."""
    try:
        hec_version = version("hec")
    except PackageNotFoundError:
        hec_version = "unknown"
    record: dict = {
        "layout": layout,
        "sources": [str(Path(s).resolve()) for s in sources],
        "imported_by": f"hec {hec_version}",
        "imported_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    if frames is not None:
        record["pose_convention"] = frames.convention.to_dict()
        record["pose_values"] = np.asarray(frames.pose_values, dtype=float).tolist()
        record["images"] = [str(p.resolve()) for p in frames.images]
        record["pairing"] = frames.pairing.to_dict()
    if joint_file is not None:
        record["joints"] = {"unit": joint_file.unit, "order": joint_file.order}
    return record


def import_images(
    frames: LayoutFrames,
    out: str | Path,
    board: Target,
    intrinsics: CameraIntrinsics,
    depth_scale_m: float,
    record: dict,
    extra: dict | None = None,
    force: bool = False,
    check: Callable[[Path], None] | None = None,
) -> Path:
    """Write the layout's images, depths and poses as a hec dataset at out (nothing appears there
    unless it completes). record: the provenance; extra: more dataset.json fields (robot_model);
    check: run on the complete dataset before it is moved to out (its failure leaves nothing)."""
    T_base_flange = frames.T_base_flange
    # PNG depths are stored as they came; .npy depths (often float metres) in steps of 0.1 mm, which
    # hold 6.5 m (farther pixels are stored as no depth).
    numpy_depth = any(d is not None and d.suffix.lower() == ".npy" for d in frames.depths)
    stored_scale_m = min(depth_scale_m, NUMPY_DEPTH_STEP_M) if numpy_depth else depth_scale_m
    with DatasetWriter(out, intrinsics, board, stored_scale_m, "import", force=force) as writer:
        for i, (image, depth) in enumerate(zip(frames.images, frames.depths, strict=True)):
            writer.add_frame(
                Frame(
                    rgb=_rgb(image, intrinsics),
                    depth_m=None if depth is None else _depth(depth, intrinsics, depth_scale_m),
                    intrinsics=intrinsics,
                    T_base_flange=T_base_flange[i],
                    joints=np.zeros(0) if frames.joints is None else frames.joints[i],
                    time_s=float(i),
                )
            )
        return writer.finish(extra={"provenance": record, **(extra or {})}, check=check)


def _rgb(path: Path, intrinsics: CameraIntrinsics) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise LayoutError(f"{path}: not a readable image")
    _check_size(path, bgr, intrinsics)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _depth(path: Path, intrinsics: CameraIntrinsics, depth_scale_m: float) -> np.ndarray | None:
    """(H, W) float32 metres of a 16-bit depth PNG or a numpy .npy depth image (integers or floats,
    either times depth_scale_m), 0 where there is no depth; None when no pixel has depth (the frame
    is imported without depth, as it is)."""
    if path.suffix.lower() == ".npy":
        try:
            raw = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise LayoutError(f"{path}: not a numpy .npy file ({exc})") from None
        if raw.ndim != 2 or not np.issubdtype(raw.dtype, np.number):
            raise LayoutError(f"{path}: expected an (H, W) array of depths, got {raw.dtype} {raw.shape}")
        _check_size(path, raw, intrinsics)
        depth_m = np.where(np.isfinite(raw) & (raw > 0), raw, 0).astype(np.float32) * np.float32(
            depth_scale_m
        )
    else:
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
            raise LayoutError(f"{path}: expected a 16-bit single-channel depth PNG")
        _check_size(path, raw, intrinsics)
        depth_m = decode_depth(raw, depth_scale_m)
    _check_depth_range(path, depth_m, depth_scale_m)
    return depth_m if depth_m.any() else None


def _check_depth_range(path: Path, depth_m: np.ndarray, depth_scale_m: float) -> None:
    """Refuse depths whose typical value is no camera's range: the depth scale is then wrong."""
    valid = depth_m[depth_m > 0]
    if valid.size == 0:
        return
    median = float(np.median(valid))
    if not 0.03 <= median <= 30.0:
        raise LayoutError(
            f"{path}: with --depth-scale {depth_scale_m:g} m per unit the depths are {median:.4g} m "
            "typically, outside any depth camera's range; give the depth's unit in metres (0.001 for "
            "millimetres, 1 for metres)"
        )


def _check_size(path: Path, image: np.ndarray, intrinsics: CameraIntrinsics) -> None:
    if image.shape[:2] != (intrinsics.height, intrinsics.width):
        raise LayoutError(
            f"{path}: the image is {image.shape[1]}x{image.shape[0]} but the intrinsics say "
            f"{intrinsics.width}x{intrinsics.height}"
        )


def import_pose_pairs(
    pairs: list[PosePair],
    out: str | Path,
    record: dict,
    board: Target | None = None,
    intrinsics: CameraIntrinsics | None = None,
    force: bool = False,
) -> Path:
    """Write pose pairs as a hec dataset at out: frames.csv with the robot poses and no images,
    pose_pairs.json the observations (board and intrinsics as far as known)."""
    with DatasetWriter(out, intrinsics, board, 0.001, "import", force=force) as writer:
        for i, pair in enumerate(pairs):
            writer.add_pose(pair.T_base_flange, float(i))
        renumbered = [PosePair(i, p.T_base_flange, p.T_cam_board, p.covariance) for i, p in enumerate(pairs)]
        writer.add_file(POSE_PAIRS_FILE, pose_pairs_json(renumbered, record))
        return writer.finish(extra={"provenance": record, "pose_pairs_file": POSE_PAIRS_FILE})
