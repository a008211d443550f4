"""hec's public API: calibrate a recorded dataset from Python, as `hec calibrate` does.

Example
-------
>>> import hec
>>> dataset = hec.load_dataset("runs/demo")
>>> calibration = hec.calibrate(dataset)                 # ekf, noise learned, cross-validated
>>> calibration.T_flange_cam                             # (4, 4), metres
>>> hec.write_report("runs/demo/report", dataset, calibration)

The results are hec.estimator.solve.calibration.Calibration objects: T_flange_cam, its covariance,
the residuals, the diagnostics (the learned noise, the observability, the leave-one-frame-out
figures) and the warnings in plain words; ``hec.verdict(calibration)`` grades it (good, usable or
redo, with why) and ``hec.findings(calibration)`` lists what to fix, each a cause and a remedy.
"""

from __future__ import annotations

from pathlib import Path

from hec.calibration.html_report import write_calibration_report
from hec.calibration.run import check_poses_fit, run_methods
from hec.calibration.summary import Verdict, findings, verdict
from hec.estimator.io.dataset import load_dataset as _load_dataset
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.batch import one_blas_thread
from hec.estimator.solve.calibration import Calibration, MethodOptions
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.problem import (
    CalibrationProblem,
    dataset_problem,
)
from hec.support.detection import cached_or_detected

# hec.API lists them too, for hec's lazy __getattr__ (tests/test_api.py checks the two agree)
__all__ = [
    "Calibration",
    "Dataset",
    "Verdict",
    "calibrate",
    "detect",
    "findings",
    "load_dataset",
    "verdict",
    "write_report",
]


def load_dataset(path: str | Path) -> Dataset:
    """Open a hec dataset folder.

    Parameters
    ----------
    path : str or Path
        The folder `hec simulate`, `hec record` or `hec import` wrote.

    Returns
    -------
    Dataset
        Its frames (read on demand), intrinsics, board and, when simulated, the ground truth.
    """
    return _load_dataset(Path(path))


def detect(dataset: Dataset, quiet: bool = True) -> list[FrameObservations]:
    """The board's markers in every frame, from the dataset's detections cache when it is valid.

    Parameters
    ----------
    dataset : Dataset
        From load_dataset.
    quiet : bool
        No progress bar.

    Returns
    -------
    list of FrameObservations
        One per frame: the markers found (corners with covariances, depth) or why none.
    """
    return cached_or_detected(dataset, quiet)[0]


def calibrate(
    dataset: Dataset,
    method: str = DEFAULT_METHOD,
    observations: list[FrameObservations] | None = None,
    cross_validate: bool = True,
    quiet: bool = True,
) -> Calibration:
    """Estimate T_flange_cam, the camera's pose in the flange frame.

    Parameters
    ----------
    dataset : Dataset
        From load_dataset.
    method : str
        ekf (default), iekf, ukf, batch, seed-ekf or an opencv-* baseline.
    observations : list of FrameObservations, optional
        From detect; detected (or read from the cache) when not given.
    cross_validate : bool
        Add the leave-one-frame-out prediction figures (one calibration per frame).
    quiet : bool
        No progress output.

    Returns
    -------
    Calibration
        T_flange_cam (4, 4), covariance (6, 6) or None, residuals, diagnostics, warnings.

    Raises
    ------
    CalibrationInputError
        When the data cannot determine the mount (too few frames, poses that fit no mount, ...).
    """
    observations = detect(dataset, quiet) if observations is None else observations
    problem = _problem(dataset, observations)
    check_poses_fit(dataset, problem)
    with one_blas_thread():
        return run_methods([method], problem, MethodOptions(), observations, quiet, cross_validate)[0]


def write_report(
    directory: str | Path,
    dataset: Dataset,
    calibration: Calibration,
    observations: list[FrameObservations] | None = None,
) -> Path:
    """Write directory/report.html, the calibration as a page to look at (hec.calibration.html_report).

    Parameters
    ----------
    directory : str or Path
        Created if needed.
    dataset, calibration
        The dataset and its calibration (from calibrate).
    observations : list of FrameObservations, optional
        Those the calibration used; from the cache when not given.

    Returns
    -------
    Path
        The page written.
    """
    observations = detect(dataset) if observations is None else observations
    T_true = None if dataset.ground_truth is None else dataset.ground_truth.hand_eye
    return write_calibration_report(
        Path(directory), dataset, _problem(dataset, observations), calibration, T_true
    )


def _problem(dataset: Dataset, observations: list[FrameObservations]) -> CalibrationProblem:
    return dataset_problem(dataset, observations)
