"""`hec export CALIBRATION.json --to FORMAT`: the calibration for the user's stack. The work is
hec.export (hec.estimator.io.export_calibration, whose doc says where the camera_link -> optical
transform comes from); this parses the options and prints its notes and the export."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hec.commands.verbs import HELP
from hec.estimator.io.export import FORMATS
from hec.estimator.io.export_calibration import DEFAULT_CHILD, export_calibration


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


def run(args: argparse.Namespace) -> int:
    """`hec export`: hec.export (hec.estimator.io.export_calibration), its notes on stderr and the
    export printed or written to --out."""
    result = export_calibration(
        args.calibration,
        args.to,
        args.parent,
        args.child,
        args.link_optical,
        args.link_optical_values,
        args.assume_zero_offset,
        args.method,
        args.out,
    )
    for note in result.notes:
        print(note, file=sys.stderr)
    if result.path is None:
        sys.stdout.write(result.text)
    else:
        print(f"wrote {result.path} ({result.fmt}: T_{result.parent}_{result.child})")
    return 0
