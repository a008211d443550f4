"""The ``hec`` commands: the argument parser and the dispatch to each command (hec.cli runs
them, with the signals taken first)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hec.commands import arguments, importing, record, regress, sweep, teach
from hec.commands import export as export_command
from hec.commands import plan as plan_command
from hec.commands import verify as verify_command
from hec.estimator.io.calibration_file import CalibrationFileError
from hec.estimator.observe.frames import DatasetError
from hec.estimator.observe.observations import ObservationCacheError
from hec.estimator.solve.problem import CalibrationInputError
from hec.estimator.targets.target import BoardDefinitionError
from hec.support.version import VERSION
from hec.sweep import report

USER_ERRORS = (
    BoardDefinitionError,
    CalibrationFileError,
    DatasetError,
    ObservationCacheError,
    CalibrationInputError,
    FileExistsError,
    ValueError,
    OSError,  # a file that cannot be read or written (missing, read-only or full file system)
)


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="render a simulated calibration dataset")
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create")
    arguments.add_scenario(p)
    p.add_argument("--seed", type=arguments.seed, help="noise seed (default: the scenario's 'seed')")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    p.add_argument(
        "--preview", action="store_true", help="also write preview/overview.png and preview/contact_sheet.png"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_detect(sub: argparse._SubParsersAction) -> None:
    from hec.estimator.targets.qr import DEFAULT_PASSES

    p = sub.add_parser(
        "detect", help="detect the board in a dataset, cache the observations (DATASET/detections.json)"
    )
    p.add_argument("dataset", type=Path, help="dataset folder")
    p.add_argument("--overlay", action="store_true", help="also write DATASET/overlay/NNNNNN.png")
    p.add_argument(
        "--passes",
        default=",".join(DEFAULT_PASSES),
        help="decoding passes BACKEND@SCALE in order; back-ends zxing, pyzbar, opencv (default: %(default)s)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_calibrate(sub: argparse._SubParsersAction) -> None:
    from hec.estimator.solve.methods import DEFAULT_METHOD, METHODS

    p = sub.add_parser(
        "calibrate",
        help="estimate T_flange_cam (camera in the flange frame, OpenCV cam2gripper) from a dataset",
    )
    p.add_argument(
        "dataset", type=Path, help="dataset folder (observations from its detections.json if valid)"
    )
    p.add_argument(
        "--method",
        default=DEFAULT_METHOD,
        choices=[*METHODS, "all"],  # pose-pair datasets take ekf, iekf, batch and the OpenCV ones
        metavar="NAME|all",
        help=f"{', '.join(METHODS)}, or all to compare them (default: %(default)s)",
    )
    p.add_argument("--json", type=Path, metavar="OUT", help="also write the results to this JSON file")
    p.add_argument(
        "--map",
        default="board",
        choices=["board", "landmarks"],
        help="board: the board pose with its known geometry; landmarks: every corner a free point",
    )
    p.add_argument("--depth-scale", action="store_true", help="also estimate a depth scale factor")
    p.add_argument("--no-depth", action="store_true", help="use only the pixels, not the depth")
    p.add_argument(
        "--no-loo",
        action="store_true",
        help="skip the leave-one-frame-out prediction figures (they cost one calibration per frame)",
    )
    p.add_argument(
        "--loo-all",
        action="store_true",
        help="leave-one-frame-out also for methods whose folds would take over 30 s (batch on real data)",
    )
    p.add_argument(
        "--prior",
        type=Path,
        metavar="FILE",
        help="JSON with 'T_flange_cam' (4x4, m) and optional 'covariance' (6x6), e.g. a --json output",
    )
    p.add_argument(
        "--robot-sigma-mm",
        type=arguments.non_negative,
        metavar="X",
        help="1-sigma of the reported flange position per base axis, mm (default: the dataset's)",
    )
    p.add_argument(
        "--robot-sigma-deg",
        type=arguments.non_negative,
        metavar="Y",
        help="1-sigma of the reported flange rotation per flange axis, degrees (default: the dataset's)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_board(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("board", help="write a true-scale printable board (PNG or PDF)")
    p.add_argument("--out", required=True, type=Path, help="board.pdf or board.png")
    p.add_argument("--board", default="hec_8qr", help="board name in models/boards/ or a board JSON file")
    lo, hi = arguments.DPI_RANGE
    p.add_argument("--dpi", type=arguments.dpi, default=300.0, help=f"print resolution, {lo:g}-{hi:g}")
    p.add_argument(
        "--definition",
        type=Path,
        help="where to write the board definition with every marker's printed mask (default: OUT with .json)",
    )


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="the main job: simulate the default cell, detect, calibrate, report against ground truth"
    )
    p.add_argument(
        "--out", type=Path, default=Path("runs/demo"), help="dataset folder (replaced if it exists)"
    )
    p.add_argument("--seed", type=arguments.seed, default=0)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hec", description="Eye-in-hand calibration testbench and tool.")
    parser.add_argument("--version", action="version", version=f"hec {VERSION}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_demo(sub)
    _add_simulate(sub)
    _add_detect(sub)
    _add_calibrate(sub)
    _add_board(sub)
    importing.add_parser(sub)
    export_command.add_parser(sub)
    plan_command.add_parser(sub)
    verify_command.add_parser(sub)
    sweep.add_parser(sub)
    report.add_parser(sub)
    regress.add_parser(sub)
    record.add_parsers(sub)
    teach.add_parser(sub)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the command args name: its exit code (2 with a message on stderr for bad input)."""
    try:
        if args.command == "board":
            from hec.commands.printable import write_board

            for line in write_board(args.board, args.out, args.dpi, args.definition):
                print(line)
            return 0
        if args.command == "detect":
            from hec.support.detection import run_detect

            passes = tuple(p.strip() for p in args.passes.split(",") if p.strip())
            if not passes:
                raise ValueError(f"--passes {args.passes!r}: give at least one decoding pass, e.g. zxing@1")
            run_detect(args.dataset, args.overlay, passes, args.quiet)
            return 0
        if args.command == "calibrate":
            from hec.commands.calibrate import run as run_calibrate

            return run_calibrate(args)
        if args.command in ("export", "verify", "plan", "import"):
            return {
                "export": export_command,
                "verify": verify_command,
                "plan": plan_command,
                "import": importing,
            }[args.command].run(args)
        if args.command in ("record", "run"):
            return record.run(args)
        if args.command == "teach":
            return teach.run(args)
        if args.command in ("sweep", "report", "regress"):
            return {"sweep": sweep, "report": report, "regress": regress}[args.command].run(args)
        from hec.commands.demo import run_simulate

        return run_simulate(args)
    except USER_ERRORS as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
