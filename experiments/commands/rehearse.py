"""`hec rehearse --out DIR`: the real-cell session (`hec run --robot HOST --camera SERIAL`) from the
command line with no arm and no camera: the real ur_rtde clients against a loopback UR controller
and librealsense's own pipeline against a software D435 (hec.rehearsal), both over one simulated
cell. The output is a real session's (the plan, each frame, the calibration), then the result's
error against the simulated cell's true mount, which a real cell cannot give."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from hec.commands import arguments, record
from hec.commands.verbs import HELP
from hec.estimator.common.files import write_atomic
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.io.calibration_file import read_calibration
from hec.estimator.solve.method_names import DEFAULT_METHOD

DEFAULT_HOST = "127.0.0.2"


def add_parser(sub: argparse._SubParsersAction) -> None:
    from hec.estimator.solve.methods import METHODS

    p = sub.add_parser("rehearse", help=HELP["rehearse"])
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create (as hec run --out)")
    p.add_argument(
        "--scenario", type=Path, help="scenario TOML of the simulated cell (default: the built-in one)"
    )
    p.add_argument(
        "--seed",
        type=arguments.seed,
        help="the simulated cell's model errors (the camera's noise: seed + 1); default: the scenario's",
    )
    p.add_argument(
        "--waypoints",
        type=Path,
        metavar="FILE",
        help="waypoint CSV (default: the scenario's trajectory as flange poses)",
    )
    p.add_argument(
        "--views", type=int, metavar="N", help="only the first N waypoints of the default trajectory"
    )
    p.add_argument("--method", default=DEFAULT_METHOD, choices=list(METHODS))
    p.add_argument("--dry-run", action="store_true", help="print the plan and stop (as hec run --dry-run)")
    p.add_argument(
        "--preview",
        type=Path,
        metavar="FILE.png",
        help="draw the planned moves into this new PNG (as hec run)",
    )
    p.add_argument(
        "--host",
        default=DEFAULT_HOST,
        help="loopback address the stand-in controller serves ur_rtde's ports on (default: %(default)s)",
    )
    p.add_argument(
        "--speedup",
        type=float,
        default=4.0,
        help="the stand-in controller's clock runs this many times wall time (default: %(default)s)",
    )


def run(args: argparse.Namespace) -> int:
    """`hec rehearse`: start the stand-ins, run `hec run` against them, print the error against
    the true mount; returns hec run's exit code."""
    from hec.rehearsal.rig import (
        REHEARSAL_BURST,
        REHEARSAL_CELL_TOML,
        rehearsal_rig,
        rehearsal_scenario,
        write_pose_waypoints,
    )
    from hec.rehearsal.software_d435 import SERIAL

    if args.views is not None and args.views < 3:
        raise ValueError(f"--views {args.views}: give at least 3 (a calibration needs several views)")
    if args.views is not None and args.waypoints is not None:
        raise ValueError(
            "--views takes the first N of the default trajectory; with --waypoints, edit the file"
        )
    if args.out.exists():
        raise FileExistsError(f"{args.out} already exists; choose another --out")
    scenario = rehearsal_scenario(args.scenario)
    seed = scenario.seed if args.seed is None else args.seed
    print(
        f"rehearsal: hec run against a loopback UR controller on {args.host} (the real ur_rtde clients) and "
        f"a software D435 (librealsense's pipeline), over the simulated cell with seed {seed}"
    )
    with tempfile.TemporaryDirectory(prefix="hec-rehearse-") as folder:
        cell_file = Path(folder) / "cell.toml"
        write_atomic(cell_file, REHEARSAL_CELL_TOML.format(timeout_s=20.0, burst=REHEARSAL_BURST))
        waypoints = args.waypoints
        if waypoints is None:
            waypoints = write_pose_waypoints(Path(folder) / "waypoints.csv", scenario, args.views)
        argv = ["run", "--robot", args.host, "--camera", SERIAL, "--cell", str(cell_file)]
        argv += ["--waypoints", str(waypoints), "--out", str(args.out), "--yes", "--method", args.method]
        argv += ["--dry-run"] if args.dry_run else []
        argv += ["--preview", str(args.preview)] if args.preview is not None else []
        parser = argparse.ArgumentParser(prog="hec")
        record.add_parsers(parser.add_subparsers(dest="command", required=True))
        with rehearsal_rig(scenario, seed, args.host, args.speedup) as rig:
            T_flange_cam_true = rig.cell.ground_truth().T_flange_cam
            code = record.run(parser.parse_args(argv), rig.device.context)
    calibration_path = args.out / "calibration.json"
    if code == 0 and calibration_path.is_file():
        calibration = read_calibration(calibration_path)
        dt_m, dr_rad = pose_error(calibration.T_flange_cam, T_flange_cam_true)
        print(
            f"rehearsal: error against the simulated cell's true mount {1e3 * dt_m:.2f} mm, "
            f"{np.degrees(dr_rad):.3f} deg"
        )
    return code
