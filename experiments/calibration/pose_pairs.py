"""`hec calibrate` on a dataset of imported pose pairs (pose_pairs.json, no images): the OpenCV
methods on the pairs, hec's pose-pair model (hec.estimator.solve.pose_pair_methods) for ekf, iekf and
batch, the report and the JSON."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hec.calibration.report import (
    MethodFailure,
    Result,
    calibration_to_dict,
    format_calibration,
    result_to_dict,
    write_json,
)
from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.io.calibration_file import CALIBRATION_FORMAT, CALIBRATION_VERSION
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.pose_pairs import read_pose_pairs
from hec.estimator.solve.baselines import OPENCV_METHODS
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.pose_pair_methods import POSE_PAIR_MODEL_METHODS, solve_pose_pairs
from hec.estimator.solve.problem import CalibrationInputError

PAIR_METHODS = (*POSE_PAIR_MODEL_METHODS, *OPENCV_METHODS)


def calibrate_pose_pairs(
    dataset: Dataset,
    method: str,
    options: MethodOptions,
    noise: RobotPoseNoise,
    noise_source: str,
    json_out: Path | None = None,
) -> list[Result]:
    """Calibrate from the dataset's pose pairs with one method or 'all' (PAIR_METHODS), print the
    report and write the JSON."""
    pairs, source = read_pose_pairs(dataset.root / dataset.metadata["pose_pairs_file"])
    names = list(PAIR_METHODS) if method == "all" else [method]
    results: list[Result] = []
    for name in names:
        try:
            results.append(solve_pose_pairs(name, pairs, options, noise))
        except (CalibrationInputError, ValueError) as exc:
            if len(names) == 1:
                raise CalibrationInputError(str(exc)) from None
            results.append(MethodFailure(name, str(exc)))
    T_true = None if dataset.ground_truth is None else dataset.ground_truth.T_flange_cam
    origin = source.get("layout", "an import")
    print(
        f"dataset: {dataset.root} ({len(pairs)} pose pairs; observations: "
        f"{dataset.metadata['pose_pairs_file']}, imported from {origin}; no images)"
    )
    print(
        f"robot pose noise {1e3 * noise.translation_sigma_m:.3f} mm, "
        f"{np.degrees(noise.rotation_sigma_rad):.4f} deg ({noise_source})"
    )
    for result in results:
        if isinstance(result, MethodFailure):
            print(f"method: {result.method}: failed: {result.error}")
            continue
        print(format_calibration(result, T_true))
    if json_out is not None:
        data = {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "dataset": str(dataset.root),
            "observations": "pose pairs",
            "robot_pose_noise": noise.to_dict() | {"source": noise_source},
        }
        if method == "all":
            data["results"] = [result_to_dict(r, T_true) for r in results]
        else:
            data |= calibration_to_dict(results[0], T_true)
        print(f"wrote {write_json(json_out, data)}")
    return results
