"""The ``hec`` commands: the argument parser and the dispatch to each command (hec.cli runs
them, with the signals taken first)."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable
from pathlib import Path

from hec.commands import arguments
from hec.commands.verbs import HELP
from hec.support.version import VERSION


def _user_errors() -> tuple[type[Exception], ...]:
    """What a command reports as one line and exit code 2: bad input, named by the error."""
    from hec.estimator.io.calibration_file import CalibrationFileError
    from hec.estimator.observe.frames import DatasetError
    from hec.estimator.observe.observations import ObservationCacheError
    from hec.estimator.solve.problem import CalibrationInputError
    from hec.estimator.targets.target import BoardDefinitionError

    return (
        BoardDefinitionError,
        CalibrationFileError,
        DatasetError,
        ObservationCacheError,
        CalibrationInputError,
        ValueError,
    )


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help=HELP["simulate"])
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

    p = sub.add_parser("detect", help=HELP["detect"])
    p.add_argument("dataset", type=Path, help="dataset folder")
    p.add_argument("--overlay", action="store_true", help="also write DATASET/overlay/NNNNNN.png")
    p.add_argument(
        "--passes",
        default=",".join(DEFAULT_PASSES),
        help="decoding passes BACKEND@SCALE in order; back-ends zxing, pyzbar, opencv (default: %(default)s)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_calibrate(sub: argparse._SubParsersAction) -> None:
    from hec.estimator.solve.method_names import DEFAULT_METHOD, METHOD_NAMES

    p = sub.add_parser("calibrate", help=HELP["calibrate"])
    p.add_argument(
        "dataset", type=Path, help="dataset folder (observations from its detections.json if valid)"
    )
    p.add_argument(
        "--method",
        default=DEFAULT_METHOD,
        choices=[*METHOD_NAMES, "all"],  # pose-pair datasets take ekf, iekf, batch and the OpenCV ones
        metavar="NAME|all",
        help=f"{', '.join(METHOD_NAMES)}, or all to compare them (default: %(default)s)",
    )
    p.add_argument("--json", type=Path, metavar="OUT", help="also write the results to this JSON file")
    p.add_argument(
        "--report",
        type=Path,
        metavar="DIR",
        help="also write DIR/report.html: the verdict, residuals, poses and every frame to look at",
    )
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
        "--verbose",
        action="store_true",
        help="the full report (residuals, noise, fit, folds) instead of the verdict and its findings",
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
    p = sub.add_parser("board", help=HELP["board"])
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
    p = sub.add_parser("demo", help=HELP["demo"])
    p.add_argument(
        "--out", type=Path, default=Path("runs/demo"), help="dataset folder (replaced if it exists)"
    )
    p.add_argument("--seed", type=arguments.seed, default=0)


def _module_parser(module: str, function: str = "add_parser") -> Callable[[argparse._SubParsersAction], None]:
    """Adds a verb's parser from its module, loaded only when that verb is the one run."""

    def add(sub: argparse._SubParsersAction) -> None:
        getattr(importlib.import_module(module), function)(sub)

    return add


# Each verb: what adds its parser (a module's add_parser, loaded only for the verb being run) and what
# runs it. Their help is hec.commands.verbs.HELP, which `hec --help` lists without loading any.
PARSERS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "demo": _add_demo,
    "simulate": _add_simulate,
    "detect": _add_detect,
    "calibrate": _add_calibrate,
    "board": _add_board,
    "import": _module_parser("hec.commands.importing"),
    "export": _module_parser("hec.commands.export"),
    "plan": _module_parser("hec.commands.plan"),
    "verify": _module_parser("hec.commands.verify"),
    "sweep": _module_parser("hec.commands.sweep"),
    "report": _module_parser("hec.commands.report"),
    "regress": _module_parser("hec.commands.regress"),
    "record": _module_parser("hec.commands.record", "add_parsers"),
    "run": _module_parser("hec.commands.record", "add_parsers"),
    "teach": _module_parser("hec.commands.teach"),
    "rehearse": _module_parser("hec.commands.rehearse"),
}
RUNNERS = {
    "import": "hec.commands.importing",
    "export": "hec.commands.export",
    "plan": "hec.commands.plan",
    "verify": "hec.commands.verify",
    "sweep": "hec.commands.sweep",
    "report": "hec.commands.report",
    "regress": "hec.commands.regress",
    "record": "hec.commands.record",
    "run": "hec.commands.record",
    "teach": "hec.commands.teach",
    "rehearse": "hec.commands.rehearse",
    "calibrate": "hec.commands.calibrate",
}


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The hec parser. Only the verb argv names (its first word that is a verb) gets its options;
    the others are listed with their help, so `hec --help` and `hec VERB --help` load one command
    at most. argv None: every verb gets its options (the whole command line, for documentation)."""
    parser = argparse.ArgumentParser(prog="hec", description="Eye-in-hand calibration testbench and tool.")
    parser.add_argument("--version", action="version", version=f"hec {VERSION}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for verb in HELP:
        if (argv is None or verb in argv[:1]) and verb not in sub.choices:
            PARSERS[verb](sub)
    for verb in HELP:
        if verb not in sub.choices:
            sub.add_parser(verb, help=HELP[verb])
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the command args name: its exit code (2 with a message on stderr for bad input)."""
    user_errors = _user_errors()
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
        if args.command in RUNNERS:
            return importlib.import_module(RUNNERS[args.command]).run(args)
        from hec.commands.demo import run_simulate

        return run_simulate(args)
    except user_errors as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file that cannot be read or written (missing, read-only or full file system)
        from hec.estimator.common.files import os_error_text

        print(f"hec: error: {os_error_text(exc)}", file=sys.stderr)
        return 2
