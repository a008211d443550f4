"""`hec verify CALIBRATION.json DATASET`: does a calibration still hold on a few new frames
(hec.estimator.solve.verify)? Exit code 0 consistent, 1 moved, 2 bad input or nothing to test against."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hec.commands.verbs import HELP
from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.io.calibration_file import CalibrationFile

if TYPE_CHECKING:
    from hec.estimator.solve.verify import Verification

EXIT_MOVED = 1
EXIT_UNTESTED = 2


def add_parser(sub: argparse._SubParsersAction) -> None:
    from hec.estimator.solve.method_names import METHOD_NAMES

    p = sub.add_parser("verify", help=HELP["verify"])
    p.add_argument("calibration", type=Path, help="a hec calibrate --json output")
    p.add_argument("dataset", type=Path, help="dataset folder with the new frames (3 or more)")
    p.add_argument("--method", choices=list(METHOD_NAMES), help="the result to test in a --method all file")
    p.add_argument("--json", type=Path, metavar="OUT", help="also write the verification to this JSON file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _noise_line(cal: CalibrationFile) -> str:
    n = cal.noise
    if n is None:
        return "noise: as the verification dataset declares it (the calibration did not learn it)"
    extra = f"; its self-calibrated {', '.join(n.self_calibration)}" if n.self_calibration else ""
    return (
        f"noise: the calibration's learned levels (corners {n.pixel_scale:.2f}x the detector's sigma, "
        f"depth {n.depth_scale:.2f}x, arm {1e3 * n.robot_translation_sigma_m:.3f} mm / "
        f"{np.degrees(n.robot_rotation_sigma_rad):.4f} deg){extra}"
    )


def format_verification(v: Verification, setup: str = EYE_IN_HAND) -> list[str]:
    """The report's lines after the header: the shift with its sigma, the test, the verdict. setup:
    the calibration's (eye-to-hand: the fixed camera's shift along the base axes)."""
    from hec.calibration.report import format_vector
    from hec.estimator.solve.verify import format_verdict

    sigma = np.sqrt(np.diag(v.covariance_verify))
    mm, deg = v.test_sigma
    lines = [
        f"{'camera' if setup == EYE_TO_HAND else 'mount'} from these frames alone (board pose free): shift "
        f"[mm] along {'base' if setup == EYE_TO_HAND else 'flange'} x y z "
        f"{format_vector(1e3 * v.delta[:3], '+.3f')} (+- {format_vector(1e3 * sigma[:3], '.3f')}); "
        f"rotation [deg] about camera x y z {format_vector(np.degrees(v.delta[3:]), '+.4f')} "
        f"(+- {format_vector(np.degrees(sigma[3:]), '.4f')})",
        f"fit of the verification frames: chi-square per degree of freedom {v.fit_chi2_dof:.2f} (about 1 "
        "when the calibration's noise model fits them; well above: a model error, the test is then not "
        "to be trusted)",
    ]
    if v.chi2 is not None:
        lines.append(
            f"test: chi-square {v.chi2:.2f} on 6 degrees of freedom with the calibration's and these frames' "
            f"covariance (1 sigma together: {mm:.3f} mm, {deg:.4f} deg)"
        )
    return [*lines, f"verdict: {format_verdict(v)}"]


def run(args: argparse.Namespace) -> int:
    """`hec verify`: hec.verify (hec.calibration.verification) and its report; 0 consistent,
    1 moved, 2 when the calibration has no covariance."""
    from hec.calibration.report import check_json_path, write_json
    from hec.calibration.verification import untested_message, verify_calibration
    from hec.estimator.common.files import refuse_writing_over_inputs
    from hec.estimator.io.dataset import dataset_inputs

    if args.json is not None:
        check_json_path(args.json)
        inputs = {"calibration file": args.calibration} | dataset_inputs(args.dataset)
        refuse_writing_over_inputs(args.json, inputs, "--json")
    result = verify_calibration(args.calibration, args.dataset, args.method, args.quiet)
    cal, v = result.calibration, result.verification
    covariance = "given" if cal.covariance is not None else "none"
    print(f"calibration: {cal.path} ({cal.method}, covariance {covariance})")
    print(
        f"verification: {result.dataset} ({result.frames} frames, {result.observation_count} marker "
        f"observations; observations {result.observations_source})"
    )
    for line in result.rejected:
        print(f"  left out: {line}")
    print(_noise_line(cal))
    print("\n".join(format_verification(v, cal.setup)))
    if result.error_vs_truth is not None:
        dt, dr = result.error_vs_truth
        print(
            f"vs ground truth: the verification cell's true {cal.hand_eye_name} is {1e3 * dt:.3f} mm and "
            f"{np.degrees(dr):.4f} deg from the calibration"
        )
    if args.json is not None:
        print(f"wrote {write_json(args.json, result.to_dict())}")
    if v.moved is None:
        print(f"hec: error: {untested_message(cal)}", file=sys.stderr)
        return EXIT_UNTESTED
    return EXIT_MOVED if v.moved else 0
