"""hec's public API: what the command line does, from Python; `hec import`, `hec calibrate`,
`hec verify`, `hec export` and `hec plan` call these same functions.

Example
-------
>>> import hec
>>> dataset = hec.load_dataset("runs/demo")
>>> calibration = hec.calibrate(dataset)                 # ekf, noise learned, cross-validated
>>> calibration.T_flange_cam                             # (4, 4), metres
>>> hec.write_report("runs/demo/report", dataset, calibration)
>>> hec.export("runs/demo/calibration.json", "ros2-launch", out="handeye.launch.py")

The results are hec.estimator.solve.calibration.Calibration objects: T_flange_cam, its covariance,
the residuals, the diagnostics (the learned noise, the observability, the leave-one-frame-out
figures) and the warnings in plain words; ``hec.verdict(calibration)`` grades it (good, usable or
redo, with why) and ``hec.findings(calibration)`` lists what to fix, each a cause and a remedy.
"""

from __future__ import annotations

from pathlib import Path

from hec.calibration.calibration_json import (
    CalibrationContext,
    calibration_context,
    frame_notes,
    robot_noise_source,
)
from hec.calibration.html_report import write_calibration_report
from hec.calibration.importing import DatasetImportError, ImportOptions, ImportResult
from hec.calibration.importing import import_dataset as _import_dataset
from hec.calibration.loo import LOO_KEY
from hec.calibration.report import calibration_to_dict, check_json_path, write_json
from hec.calibration.run import check_poses_fit, run_methods
from hec.calibration.summary import Verdict, findings, verdict
from hec.calibration.verification import VerifyResult, verify_calibration
from hec.estimator.common.files import refuse_writing_over_inputs
from hec.estimator.io.dataset import dataset_inputs
from hec.estimator.io.dataset import load_dataset as _load_dataset
from hec.estimator.io.export_calibration import DEFAULT_CHILD, ExportError, ExportResult, export_calibration
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.batch import one_blas_thread
from hec.estimator.solve.calibration import Calibration, MethodOptions
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.problem import (
    CalibrationProblem,
    dataset_problem,
)
from hec.estimator.solve.view_planning import CRITERIA
from hec.session.view_plan import DEFAULT_MAX_VIEWS, PlanError, ViewPlan, plan_views_for
from hec.support.detection import cached_or_detected

# hec.API lists them too, for hec's lazy __getattr__ (tests/test_api.py checks the two agree)
__all__ = [
    "Calibration",
    "Dataset",
    "DatasetImportError",
    "ExportError",
    "ExportResult",
    "ImportOptions",
    "ImportResult",
    "PlanError",
    "Verdict",
    "VerifyResult",
    "ViewPlan",
    "calibrate",
    "detect",
    "export",
    "findings",
    "import_dataset",
    "load_dataset",
    "plan",
    "save_calibration",
    "verdict",
    "verify",
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


def save_calibration(
    path: str | Path,
    dataset: Dataset,
    calibration: Calibration,
    observations: list[FrameObservations] | None = None,
) -> Path:
    """Write the calibration file `hec calibrate --json` writes, which verify, export and plan read.

    Parameters
    ----------
    path : str or Path
        The JSON file to write (atomically; refused if it is one of the dataset's files).
    dataset, calibration
        The dataset and its calibration (from calibrate, with its default options).
    observations : list of FrameObservations, optional
        Those the calibration used; from the cache when not given.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    check_json_path(path)
    refuse_writing_over_inputs(path, dataset_inputs(dataset.root), "path")
    observations = detect(dataset) if observations is None else observations
    cross_validated = LOO_KEY in calibration.diagnostics
    context = CalibrationContext(robot_noise_source(dataset), loo=cross_validated)
    T_true = None if dataset.ground_truth is None else dataset.ground_truth.hand_eye
    data = calibration_context(dataset, _problem(dataset, observations), context)
    data |= {"frame_notes": frame_notes(observations)} | calibration_to_dict(calibration, T_true)
    return write_json(path, data)


def import_dataset(
    layout: str,
    source: str | Path,
    out: str | Path,
    options: ImportOptions | None = None,
    force: bool = False,
    quiet: bool = True,
) -> ImportResult:
    """Import another tool's recording as a hec dataset, as `hec import` does.

    Parameters
    ----------
    layout : str
        folder (images with a pose file or folder), visp (ViSP's hand-eye folder) or easy_handeye2
        (a .samples file of pose pairs).
    source : str or Path
        The image folder, or the .samples file.
    out : str or Path
        The dataset folder to create (nothing appears there unless the import completes).
    options : ImportOptions, optional
        The board, the camera, the pose file and its convention, depth, joints, the arm: the
        command's options as fields (``ImportOptions(board="qr8", poses=Path("poses.csv"),
        camera=(fx, fy, cx, cy, width, height))``).
    force : bool
        Replace a dataset already at out.
    quiet : bool
        No progress bar while the images are detected.

    Returns
    -------
    ImportResult
        ``path``, how many images (or pose pairs) and with depth, how the poses were read and paired,
        and the detection and convention checks' lines.

    Raises
    ------
    DatasetImportError
        When the import is refused (a missing option, an unreadable pose file, a convention the
        check finds wrong, ...).
    """
    options = ImportOptions() if options is None else options
    return _import_dataset(layout, Path(source), Path(out), options, force, quiet)


def verify(
    calibration: str | Path, dataset: str | Path, method: str | None = None, quiet: bool = True
) -> VerifyResult:
    """Test whether a calibration still holds on a few new frames, as `hec verify` does.

    Parameters
    ----------
    calibration : str or Path
        A calibration file (`hec calibrate --json`).
    dataset : str or Path
        A dataset folder with the new frames (3 or more), the camera in the same mount.
    method : str, optional
        The result to test in a `--method all` file.
    quiet : bool
        No progress bar.

    Returns
    -------
    VerifyResult
        ``verification.delta`` (6,): the mount's shift from these frames alone (metres along the
        flange axes, radians about the camera axes) with its covariance, the chi-square test and
        ``verification.moved`` (True, False, or None when the calibration has no covariance), what it
        used, and in simulation ``error_vs_truth`` (metres, radians).

    Raises
    ------
    CalibrationFileError
        When the file is bad or the calibration and the dataset do not belong together.
    """
    return verify_calibration(Path(calibration), Path(dataset), method, quiet)


def export(
    calibration: str | Path,
    to: str,
    out: str | Path | None = None,
    parent: str | None = None,
    child: str = DEFAULT_CHILD,
    link_optical: str | Path | None = None,
    link_optical_values: tuple[float, float, float, float, float, float, float] | None = None,
    assume_zero_offset: bool = False,
    method: str | None = None,
) -> ExportResult:
    """The calibration for the user's stack, as `hec export` writes it.

    Parameters
    ----------
    calibration : str or Path
        A calibration file (`hec calibrate --json`).
    to : str
        The format: ros2-launch, ros2-args, urdf, easy_handeye2, yaml or json (`hec export --help`).
    out : str or Path, optional
        Write the file here (atomically; never over an input); only returned when not given.
    parent : str, optional
        The parent frame; tool0 by default (base_link for an eye-to-hand calibration).
    child : str
        The child frame; camera_link by default, the camera's root link: the link -> optical frame
        transform is then composed out (a name ending in _optical_frame is the optical frame itself).
    link_optical : str or Path, optional
        That transform from a dataset folder (its recorded extrinsics) or a JSON with
        ``T_link_optical`` (4, 4), metres.
    link_optical_values : tuple of 7 floats, optional
        The same as x, y, z (metres), qx, qy, qz, qw, as ``tf2_echo`` prints it.
    assume_zero_offset : bool
        With no extrinsics known, take RealSense's optical rotation with zero offset (about 15 mm off
        on a D435).
    method : str, optional
        The result to export from a `--method all` file.

    Returns
    -------
    ExportResult
        ``text`` (the file's content), ``parent`` and ``child`` (it holds T_parent_child), ``notes``
        to read before using it and ``path`` (the file written, or None).

    Raises
    ------
    ExportError
        When the export is refused (the link -> optical transform unknown, a bad frame name, ...).
    """
    return export_calibration(
        Path(calibration),
        to,
        parent,
        child,
        None if link_optical is None else Path(link_optical),
        link_optical_values,
        assume_zero_offset,
        method,
        None if out is None else Path(out),
    )


def plan(
    out: str | Path | None = None,
    scenario: str | Path | None = None,
    calibration: str | Path | None = None,
    method: str | None = None,
    dataset: str | Path | None = None,
    cell: str | Path | None = None,
    views: int | None = None,
    target_sigma_mm: float | None = None,
    target_sigma_deg: float | None = None,
    max_views: int = DEFAULT_MAX_VIEWS,
    criterion: str = CRITERIA[0],
    candidates: int = 1000,
    corner_sigma_px: float = 0.1,
    seed: int = 0,
) -> ViewPlan:
    """Views chosen by the information about T_flange_cam they add, as `hec plan` chooses them.

    Parameters
    ----------
    out : str or Path, optional
        Write the waypoint CSV here (`hec record`, `hec run` and scenarios take it).
    scenario : str or Path, optional
        A simulated cell's scenario (default: the built-in one); views are checked in it.
    calibration : str or Path, optional
        Plan for the real cell of this calibration instead, with `cell` (a cell TOML) and `dataset`
        (default: the one it names); `method` picks the result in a `--method all` file.
    method, dataset, cell
        See `calibration`.
    views : int, optional
        How many views (12 without a target).
    target_sigma_mm, target_sigma_deg : float, optional
        Stop when the predicted RSS 1-sigma of the mount is this (both or neither; at most
        `max_views` views).
    max_views : int
        Most views with a target.
    criterion : str
        d-optimal or worst-direction.
    candidates : int
        Random candidate views to choose from.
    corner_sigma_px : float
        The corner noise the prediction assumes, pixels per coordinate.
    seed : int
        Seed of the candidates.

    Returns
    -------
    ViewPlan
        ``views`` (each a waypoint, T_base_flange in metres, and its predicted 1-sigma), ``steps``,
        the reference views' prediction, whether a target was reached and ``path``.

    Raises
    ------
    PlanError
        When the options clash or no candidate passes the cell's checks.
    """

    def optional(path: str | Path | None) -> Path | None:
        return None if path is None else Path(path)

    return plan_views_for(
        optional(out),
        scenario,
        optional(calibration),
        method,
        optional(dataset),
        optional(cell),
        views,
        target_sigma_mm,
        target_sigma_deg,
        max_views,
        criterion,
        candidates,
        corner_sigma_px,
        seed,
    )


def _problem(dataset: Dataset, observations: list[FrameObservations]) -> CalibrationProblem:
    return dataset_problem(dataset, observations)
