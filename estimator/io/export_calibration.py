"""Export a calibration file for the user's stack: what `hec export` and hec.export compute
(the formats are hec.estimator.io.export's).

The default child frame is camera_link, the root of the frames realsense-ros publishes, so the export
gives no frame a second parent. With a child frame that is the camera's root link the camera driver's
camera_link -> optical frame transform is composed out; it comes from link_optical_values,
link_optical (a file or a dataset folder), or the calibration's own dataset when it recorded the
camera's extrinsics (a RealSense session's cell.camera.T_colour_depth). Without any of them the export
is refused, unless assume_zero_offset takes RealSense's optical rotation with zero offset (about 15 mm
off on a D435), which a note then says. A child frame realsense-ros already publishes a parent for
(the optical frames) gets a note saying when that is safe."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hec.estimator.common.files import check_output_file, refuse_writing_over_inputs, write_atomic
from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.geometry.transforms import transform_from_xyz_quat
from hec.estimator.io.calibration_file import (
    CalibrationFile,
    CalibrationFileError,
    pose_field,
    read_calibration,
)
from hec.estimator.io.export import (
    PARENT_FRAMES,
    Export,
    export_text,
    realsense_link_optical,
    realsense_ros_parent,
)

DEFAULT_CHILD = "camera_link"
OPTICAL_FRAME = "camera_color_optical_frame"
DEFAULT_LINK = "RealSense's standard optical rotation with ZERO offset (assumed: --assume-zero-offset)"


class ExportError(ValueError):
    """An export refused: the one-line message `hec export` prints (nothing is written)."""


@dataclass(frozen=True)
class ExportResult:
    """An export: text (the file's content), fmt (its format), the transform T_parent_child it
    holds (frame names), notes to read before using it (one line each) and path, the file written
    (None when nothing was written)."""

    text: str
    fmt: str
    parent: str
    child: str
    notes: tuple[str, ...]
    path: Path | None = None


def _dataset_extrinsics(folder: Path) -> np.ndarray | None:
    """A dataset's recorded T_colour_depth (dataset.json cell.camera), (4, 4) metres, or None."""
    meta = read_json_object(folder / "dataset.json", CalibrationFileError)
    camera = (meta.get("cell") or {}).get("camera") or {}
    if "T_colour_depth" not in camera:
        return None
    return pose_field(camera, "T_colour_depth", folder / "dataset.json", CalibrationFileError)


def _link_optical(
    cal: CalibrationFile,
    child: str,
    link_optical: Path | None,
    link_optical_values: Sequence[float] | None,
    assume_zero_offset: bool,
) -> tuple[np.ndarray, str]:
    """T_link_optical (4, 4) and where it came from, in words (module doc); ExportError when it is
    not known and zero is not asked for."""
    if link_optical_values is not None:
        if not np.all(np.isfinite(link_optical_values)):
            raise ExportError(
                "--link-optical-values: every value must be a finite number, got "
                + " ".join(f"{v:g}" for v in link_optical_values)
            )
        x, y, z, qx, qy, qz, qw = link_optical_values
        q = np.array([qw, qx, qy, qz])
        if not np.isclose(np.linalg.norm(q), 1.0, atol=1e-6):
            raise ExportError(
                f"--link-optical-values: the quaternion must have length 1, got {np.linalg.norm(q):.6g}"
            )
        return transform_from_xyz_quat(np.array([x, y, z]), q), "--link-optical-values"
    if link_optical is not None:
        if link_optical.is_dir():
            T_colour_depth = _dataset_extrinsics(link_optical)
            if T_colour_depth is None:
                raise CalibrationFileError(
                    f"{link_optical / 'dataset.json'}: records no camera extrinsics "
                    "(cell.camera.T_colour_depth)"
                )
            return realsense_link_optical(T_colour_depth), f"RealSense extrinsics recorded in {link_optical}"
        data = read_json_object(link_optical, CalibrationFileError)
        return pose_field(data, "T_link_optical", link_optical, CalibrationFileError), str(link_optical)
    if cal.dataset is not None and (Path(cal.dataset) / "dataset.json").is_file():
        T_colour_depth = _dataset_extrinsics(Path(cal.dataset))
        if T_colour_depth is not None:
            return realsense_link_optical(T_colour_depth), f"RealSense extrinsics recorded in {cal.dataset}"
    if assume_zero_offset:
        return realsense_link_optical(), DEFAULT_LINK
    raise ExportError(
        f"'{child}' is the camera's root link and its transform to the optical frame is not known (the "
        "calibration's dataset recorded no camera extrinsics); give it with --link-optical-values "
        f"(what `ros2 run tf2_ros tf2_echo {child} {OPTICAL_FRAME}` prints) or --link-optical, or pass "
        "--assume-zero-offset to take it as zero (about 15 mm off on a D435); nothing written"
    )


def export_calibration(
    calibration: Path,
    fmt: str,
    parent: str | None = None,
    child: str = DEFAULT_CHILD,
    link_optical: Path | None = None,
    link_optical_values: Sequence[float] | None = None,
    assume_zero_offset: bool = False,
    method: str | None = None,
    out: Path | None = None,
) -> ExportResult:
    """The calibration file's transform in fmt (hec.estimator.io.export.FORMATS), written to out
    (temporary file, then rename; never over one of its inputs) when given.

    parent: the parent frame (default tool0, eye-to-hand base_link); child: the child frame (default
    camera_link: the link -> optical transform composed out, from link_optical (a dataset folder or a
    JSON with T_link_optical, (4, 4) metres), link_optical_values (x y z metres, qx qy qz qw) or the
    calibration's dataset; assume_zero_offset takes RealSense's rotation with zero offset).
    Raises ExportError (or CalibrationFileError for a bad file) with the command's message.
    """
    if out is not None:
        check_output_file(out)
        refuse_writing_over_inputs(
            out, {"calibration file": calibration, "--link-optical file": link_optical}
        )
    cal = read_calibration(calibration, method)
    parent = parent if parent is not None else PARENT_FRAMES[cal.setup]
    try:
        export = Export(cal, parent, child)
    except ValueError as exc:  # a frame name that is no frame name
        raise ExportError(str(exc)) from None
    notes = []
    driver_parent = realsense_ros_parent(child)
    if driver_parent is not None:
        notes.append(
            f"note: realsense-ros publishes {driver_parent} -> {child}: this export gives '{child}' a second "
            "parent unless the camera driver runs with publish_tf:=false (or is not running); "
            f"--child {DEFAULT_CHILD} never clashes"
        )
    if export.composes_link:
        T, source = _link_optical(cal, child, link_optical, link_optical_values, assume_zero_offset)
        export = Export(cal, parent, child, T, source)
        if source == DEFAULT_LINK:
            notes.append(
                f"note: '{child}' -> optical frame taken as {DEFAULT_LINK}; give --link-optical-values "
                "(tf2_echo CHILD OPTICAL_FRAME) or --link-optical for your camera's"
            )
    elif link_optical is not None or link_optical_values is not None or assume_zero_offset:
        notes.append(f"note: '{child}' is an optical frame; the link -> optical transform is not used")
    try:
        text = export_text(export, fmt)
    except ValueError as exc:  # an unknown format, a transform that is not finite
        raise ExportError(str(exc)) from None
    path = None if out is None else write_atomic(out, text)
    return ExportResult(text, fmt, parent, child, tuple(notes), path)
