"""`hec demo` and `hec simulate`: render a scenario into a dataset and print its ground truth;
the demo then detects, grades and calibrates it with ekf."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from hec.estimator.common.files import os_error_text
from hec.estimator.geometry.transforms import rpy_from_transform, xyz_quat_from_transform
from hec.support import interrupts

IDEAL_CELL_NOTE = (
    "note: the default scenario is the ideal cell (exact kinematics, camera and board); "
    "models/scenarios/realistic.toml has a real cell's error sources and is the one to read real "
    "expectations from (hec simulate --scenario realistic --out DIR)"
)


def run_simulate(args: argparse.Namespace) -> int:
    """`hec demo` (args.command == "demo") or `hec simulate`; 0 done, 2 for a bad scenario."""
    from hec.estimator.geometry.waypoints import WaypointFileError
    from hec.sim.scenario import ScenarioError, load_scenario
    from hec.sim.simulate import SimulationError, simulate

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
    except OSError as exc:
        print(f"hec: error: cannot write {args.out}: {os_error_text(exc)}; nothing written", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"\ninterrupted: nothing written to {args.out}", file=sys.stderr)
        return interrupts.interrupted_exit_code(exc)
    if scenario.eye_to_hand:
        what = "T_base_cam (camera optical frame in the base frame; eye-to-hand)"
        _print_simulation(result, scenario.stand.transform(), what)
    else:
        _print_simulation(result, scenario.mount.transform())
    if args.command == "demo":
        _demo_detect_and_calibrate(result.out_dir)
        print(f"\n{IDEAL_CELL_NOTE}")
    return 0


def _format_matrix(T: np.ndarray) -> str:
    return "\n".join("  [" + "  ".join(f"{v:+.6f}" for v in row) + "]" for row in T)


def _print_simulation(
    result: object,
    T_hand_eye: np.ndarray,
    what: str = "T_flange_cam (camera optical frame in the flange/tool0 frame; OpenCV: cam2gripper)",
) -> None:
    """The dataset written, its skipped waypoints and the true transform to calibrate, T_hand_eye
    (4, 4), which is what says."""
    t, q = xyz_quat_from_transform(T_hand_eye)
    rpy = np.degrees(rpy_from_transform(T_hand_eye))
    print(f"dataset: {result.out_dir}  ({result.frames} frames, {len(result.skipped)} waypoints skipped)")
    for index, reason in result.skipped:
        print(f"  skipped waypoint {index}: {reason}")
    print(f"ground truth {what}:")
    print(_format_matrix(T_hand_eye))
    print(f"  translation [mm]: {t[0] * 1000:+.3f} {t[1] * 1000:+.3f} {t[2] * 1000:+.3f}")
    print(f"  quaternion (w x y z): {q[0]:+.6f} {q[1]:+.6f} {q[2]:+.6f} {q[3]:+.6f}")
    print(f"  roll-pitch-yaw [deg]: {rpy[0]:+.4f} {rpy[1]:+.4f} {rpy[2]:+.4f}")
    for path in result.preview_files:
        print(f"preview: {path}")


def _demo_detect_and_calibrate(dataset: Path) -> None:
    """The demo after simulation: detect and grade, then calibrate with ekf."""
    from hec.commands.calibrate import CalibrateSettings, calibrate_dataset
    from hec.support.detection import run_detect

    print()
    observations = run_detect(dataset, overlay=True, quiet=True)
    print()
    calibrate_dataset(dataset, CalibrateSettings(method="ekf"), quiet=True, observations=observations)
