"""The ``hec`` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimator.board import BoardDefinitionError
from estimator.dataset import DatasetError
from estimator.geometry import rpy_from_transform, xyz_quat_from_transform
from estimator.observations import ObservationCacheError
from estimator.problem import CalibrationInputError
from experiments import record, regress, report, sweep, teach

USER_ERRORS = (
    BoardDefinitionError,
    DatasetError,
    ObservationCacheError,
    CalibrationInputError,
    FileExistsError,
    ValueError,
    FileNotFoundError,
    IsADirectoryError,
)


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="render a simulated calibration dataset")
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create")
    p.add_argument(
        "--scenario", type=Path, help="scenario TOML file (default: the built-in default scenario)"
    )
    p.add_argument("--seed", type=int, help="noise seed (default: the scenario's 'seed')")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    p.add_argument(
        "--preview", action="store_true", help="also write preview/overview.png and preview/contact_sheet.png"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_detect(sub: argparse._SubParsersAction) -> None:
    from estimator.detect import DEFAULT_PASSES

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


def _non_negative(text: str) -> float:
    value = float(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}")
    return value


def _add_calibrate(sub: argparse._SubParsersAction) -> None:
    from estimator.methods import DEFAULT_METHOD, METHODS

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
        choices=[*METHODS, "all"],
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
        "--prior",
        type=Path,
        metavar="FILE",
        help="JSON with 'T_flange_cam' (4x4, m) and optional 'covariance' (6x6), e.g. a --json output",
    )
    p.add_argument(
        "--robot-sigma-mm",
        type=_non_negative,
        metavar="X",
        help="1-sigma of the reported flange position per base axis, mm (default: the dataset's)",
    )
    p.add_argument(
        "--robot-sigma-deg",
        type=_non_negative,
        metavar="Y",
        help="1-sigma of the reported flange rotation per flange axis, degrees (default: the dataset's)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _run_calibrate(args: argparse.Namespace) -> int:
    from estimator.calibration import Calibration
    from experiments.calibration import CalibrateSettings, calibrate_dataset

    settings = CalibrateSettings(
        method=args.method,
        map_model=args.map,
        estimate_depth_scale=args.depth_scale,
        use_depth=not args.no_depth,
        prior_file=args.prior,
        robot_sigma_mm=args.robot_sigma_mm,
        robot_sigma_deg=args.robot_sigma_deg,
    )
    results = calibrate_dataset(args.dataset, settings, args.json, args.quiet)
    if not any(isinstance(r, Calibration) for r in results):
        print("hec: error: no method could calibrate from these observations", file=sys.stderr)
        return 2
    return 0


def _add_board(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("board", help="write a true-scale printable board (PNG or PDF)")
    p.add_argument("--out", required=True, type=Path, help="board.pdf or board.png")
    p.add_argument("--board", default="hec_8qr", help="board name in models/boards/ or a board JSON file")
    p.add_argument("--dpi", type=float, default=300.0)


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="the main job: simulate the default cell, detect, calibrate, report against ground truth"
    )
    p.add_argument(
        "--out", type=Path, default=Path("runs/demo"), help="dataset folder (replaced if it exists)"
    )
    p.add_argument("--seed", type=int, default=0)


def _format_matrix(T: np.ndarray) -> str:
    return "\n".join("  [" + "  ".join(f"{v:+.6f}" for v in row) + "]" for row in T)


def _print_simulation(result: object, T_flange_cam: np.ndarray) -> None:
    t, q = xyz_quat_from_transform(T_flange_cam)
    rpy = np.degrees(rpy_from_transform(T_flange_cam))
    print(f"dataset: {result.out_dir}  ({result.frames} frames, {len(result.skipped)} waypoints skipped)")
    for index, reason in result.skipped:
        print(f"  skipped waypoint {index}: {reason}")
    print("ground truth T_flange_cam (camera optical frame in the flange/tool0 frame; OpenCV: cam2gripper):")
    print(_format_matrix(T_flange_cam))
    print(f"  translation [mm]: {t[0] * 1000:+.3f} {t[1] * 1000:+.3f} {t[2] * 1000:+.3f}")
    print(f"  quaternion (w x y z): {q[0]:+.6f} {q[1]:+.6f} {q[2]:+.6f} {q[3]:+.6f}")
    print(f"  roll-pitch-yaw [deg]: {rpy[0]:+.4f} {rpy[1]:+.4f} {rpy[2]:+.4f}")
    for path in result.preview_files:
        print(f"preview: {path}")


def _demo_detect_and_calibrate(dataset: Path) -> None:
    """The demo after simulation: detect and grade, then calibrate with ekf."""
    from experiments.calibration import CalibrateSettings, calibrate_dataset
    from experiments.detection import run_detect

    print()
    observations = run_detect(dataset, overlay=True, quiet=True)
    print()
    calibrate_dataset(dataset, CalibrateSettings(method="ekf"), quiet=True, observations=observations)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hec", description="Eye-in-hand calibration testbench and tool.")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_demo(sub)
    _add_simulate(sub)
    _add_detect(sub)
    _add_calibrate(sub)
    _add_board(sub)
    sweep.add_parser(sub)
    report.add_parser(sub)
    regress.add_parser(sub)
    record.add_parsers(sub)
    teach.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "board":
            from experiments.printable import save_printable_board
            from sim.scene import find_board

            path = save_printable_board(find_board(args.board), args.out, args.dpi)
            print(f"wrote {path} at {args.dpi:g} dpi: print at 100% scale and check the 100 mm bar")
            return 0
        if args.command == "detect":
            from experiments.detection import run_detect

            passes = tuple(p.strip() for p in args.passes.split(",") if p.strip())
            run_detect(args.dataset, args.overlay, passes, args.quiet)
            return 0
        if args.command == "calibrate":
            return _run_calibrate(args)
        if args.command in ("record", "run"):
            return record.run(args)
        if args.command == "teach":
            return teach.run(args)
        if args.command in ("sweep", "report", "regress"):
            return {"sweep": sweep, "report": report, "regress": regress}[args.command].run(args)
        from sim.scenario import ScenarioError, load_scenario
        from sim.simulate import SimulationError, simulate
        from sim.trajectory import WaypointFileError

        try:
            if args.command == "demo":
                scenario = load_scenario(None)
                result = simulate(scenario, args.out, args.seed, force=True, preview=True)
            else:
                scenario = load_scenario(args.scenario)
                seed = scenario.seed if args.seed is None else args.seed
                result = simulate(scenario, args.out, seed, args.force, args.preview, progress=not args.quiet)
        except (ScenarioError, WaypointFileError, SimulationError) as exc:
            print(f"hec: error: {exc}", file=sys.stderr)
            return 2
        _print_simulation(result, scenario.mount.transform())
        if args.command == "demo":
            _demo_detect_and_calibrate(result.out_dir)
        return 0
    except USER_ERRORS as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
