"""`hec export CALIBRATION.json --to FORMAT`: the calibration for the user's stack (hec.estimator.io.export).

The default child frame is camera_link, the root of the frames realsense-ros publishes, so the export
gives no frame a second parent. With a child frame that is the camera's root link the camera driver's
camera_link -> optical frame transform is composed out; it comes from --link-optical-values,
--link-optical FILE, or the calibration's own dataset when it recorded the camera's extrinsics (a
RealSense session's cell.camera.T_colour_depth). Without any of them the export is refused, unless
--assume-zero-offset takes RealSense's optical rotation with zero offset (about 15 mm off on a D435),
which the output then says. A child frame realsense-ros already publishes a parent for (the optical
frames) gets a note saying when that is safe."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from hec.commands.verbs import HELP
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
    FORMATS,
    PARENT_FRAMES,
    Export,
    export_text,
    realsense_link_optical,
    realsense_ros_parent,
)

DEFAULT_CHILD = "camera_link"
OPTICAL_FRAME = "camera_color_optical_frame"
DEFAULT_LINK = "RealSense's standard optical rotation with ZERO offset (assumed: --assume-zero-offset)"


def add_parser(sub: argparse._SubParsersAction) -> None:
    from hec.estimator.solve.method_names import METHOD_NAMES

    p = sub.add_parser("export", help=HELP["export"])
    p.add_argument("calibration", type=Path, help="a hec calibrate --json output")
    p.add_argument("--to", required=True, choices=FORMATS, metavar="FORMAT", help=", ".join(FORMATS))
    p.add_argument(
        "--parent",
        help="parent frame (default: tool0; base_link for an eye-to-hand calibration, the camera fixed in "
        "the cell)",
    )
    p.add_argument(
        "--child",
        default=DEFAULT_CHILD,
        help="child frame (default: %(default)s, which realsense-ros publishes no parent for); a name not "
        "ending in _optical_frame is the camera's root link: the link -> optical transform is composed out",
    )
    link = p.add_mutually_exclusive_group()
    link.add_argument(
        "--link-optical",
        type=Path,
        metavar="FILE",
        help="the camera's link -> optical frame transform: a dataset folder (its recorded extrinsics) or a "
        "JSON with 'T_link_optical' (4x4, metres)",
    )
    link.add_argument(
        "--link-optical-values",
        type=float,
        nargs=7,
        metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
        help="the same as numbers, metres and quaternion x y z w (as tf2_echo prints them)",
    )
    link.add_argument(
        "--assume-zero-offset",
        action="store_true",
        help="with no extrinsics known, take RealSense's optical rotation with zero offset (about 15 mm "
        "off on a D435)",
    )
    p.add_argument(
        "--method", choices=list(METHOD_NAMES), help="the result to export from a --method all file"
    )
    p.add_argument("--out", type=Path, metavar="FILE", help="write here (default: print)")


def _dataset_extrinsics(folder: Path) -> np.ndarray | None:
    """A dataset's recorded T_colour_depth (dataset.json cell.camera), or None."""
    meta = read_json_object(folder / "dataset.json", CalibrationFileError)
    camera = (meta.get("cell") or {}).get("camera") or {}
    if "T_colour_depth" not in camera:
        return None
    return pose_field(camera, "T_colour_depth", folder / "dataset.json", CalibrationFileError)


def link_optical(args: argparse.Namespace, cal: CalibrationFile, child: str) -> tuple[np.ndarray, str]:
    """T_link_optical (4, 4) and where it came from, in words (module doc); ValueError when it is
    not known and zero is not asked for."""
    if args.link_optical_values is not None:
        if not np.all(np.isfinite(args.link_optical_values)):
            raise ValueError(
                "--link-optical-values: every value must be a finite number, got "
                + " ".join(f"{v:g}" for v in args.link_optical_values)
            )
        x, y, z, qx, qy, qz, qw = args.link_optical_values
        q = np.array([qw, qx, qy, qz])
        if not np.isclose(np.linalg.norm(q), 1.0, atol=1e-6):
            raise ValueError(
                f"--link-optical-values: the quaternion must have length 1, got {np.linalg.norm(q):.6g}"
            )
        return transform_from_xyz_quat(np.array([x, y, z]), q), "--link-optical-values"
    path = args.link_optical
    if path is not None:
        if path.is_dir():
            T_colour_depth = _dataset_extrinsics(path)
            if T_colour_depth is None:
                raise CalibrationFileError(
                    f"{path / 'dataset.json'}: records no camera extrinsics (cell.camera.T_colour_depth)"
                )
            return realsense_link_optical(T_colour_depth), f"RealSense extrinsics recorded in {path}"
        data = read_json_object(path, CalibrationFileError)
        return pose_field(data, "T_link_optical", path, CalibrationFileError), str(path)
    if cal.dataset is not None and (Path(cal.dataset) / "dataset.json").is_file():
        T_colour_depth = _dataset_extrinsics(Path(cal.dataset))
        if T_colour_depth is not None:
            return realsense_link_optical(T_colour_depth), f"RealSense extrinsics recorded in {cal.dataset}"
    if args.assume_zero_offset:
        return realsense_link_optical(), DEFAULT_LINK
    raise ValueError(
        f"'{child}' is the camera's root link and its transform to the optical frame is not known (the "
        "calibration's dataset recorded no camera extrinsics); give it with --link-optical-values "
        f"(what `ros2 run tf2_ros tf2_echo {child} {OPTICAL_FRAME}` prints) or --link-optical, or pass "
        "--assume-zero-offset to take it as zero (about 15 mm off on a D435); nothing written"
    )


def run(args: argparse.Namespace) -> int:
    """`hec export`: print the export or write it to --out (temporary file, then rename; never over
    one of its inputs)."""
    if args.out is not None:
        check_output_file(args.out)
        inputs = {"calibration file": args.calibration, "--link-optical file": args.link_optical}
        refuse_writing_over_inputs(args.out, inputs)
    cal = read_calibration(args.calibration, args.method)
    child = args.child
    parent = args.parent if args.parent is not None else PARENT_FRAMES[cal.setup]
    export = Export(cal, parent, child)
    driver_parent = realsense_ros_parent(child)
    if driver_parent is not None:
        print(
            f"note: realsense-ros publishes {driver_parent} -> {child}: this export gives '{child}' a second "
            "parent unless the camera driver runs with publish_tf:=false (or is not running); "
            f"--child {DEFAULT_CHILD} never clashes",
            file=sys.stderr,
        )
    if export.composes_link:
        T, source = link_optical(args, cal, child)
        export = Export(cal, parent, child, T, source)
        if source == DEFAULT_LINK:
            print(
                f"note: '{child}' -> optical frame taken as {DEFAULT_LINK}; give --link-optical-values "
                "(tf2_echo CHILD OPTICAL_FRAME) or --link-optical for your camera's",
                file=sys.stderr,
            )
    elif args.link_optical is not None or args.link_optical_values is not None or args.assume_zero_offset:
        print(
            f"note: '{child}' is an optical frame; the link -> optical transform is not used", file=sys.stderr
        )
    text = export_text(export, args.to)
    if args.out is None:
        sys.stdout.write(text)
    else:
        print(f"wrote {write_atomic(args.out, text)} ({args.to}: T_{parent}_{child})")
    return 0
