"""Does a calibration still hold on a few new frames? What `hec verify` and hec.verify compute:
the calibration file and the dataset checked against each other, the frames detected (or their
cache read), and the mount test of hec.estimator.solve.verify with the calibration's learned noise."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hec.calibration.run import without_depth
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.io.calibration_file import CalibrationFile, CalibrationFileError, read_calibration
from hec.estimator.io.dataset import load_dataset
from hec.estimator.solve.problem import dataset_problem, dataset_setup
from hec.estimator.solve.verify import Verification, format_verdict, verification_problem, verify_mount
from hec.support.detection import cached_or_detected


@dataclass(frozen=True)
class VerifyResult:
    """A calibration tested on new frames.

    calibration: the calibration file's result tested; dataset: the verification dataset's folder;
    frames and observation_count: what the test used (observations_source: cached or detected),
    rejected: what it left out and why; verification: the shift of the mount with its covariance,
    the chi-square test and moved (True, False, or None when the calibration has no covariance);
    error_vs_truth: in simulation, (metres, radians) between the calibration and the true mount.
    """

    calibration: CalibrationFile
    dataset: Path
    frames: int
    observation_count: int
    observations_source: str
    rejected: tuple[str, ...]
    verification: Verification
    error_vs_truth: tuple[float, float] | None

    @property
    def verdict(self) -> str:
        """The verdict in one line (consistent, moved, or why it cannot tell)."""
        return format_verdict(self.verification)

    def to_dict(self) -> dict:
        """The JSON record `hec verify --json` writes."""
        cal = self.calibration
        data = {"calibration": str(cal.path), "method": cal.method, "dataset": str(self.dataset)}
        return data | self.verification.to_dict() | {"verdict": self.verdict}


def verify_calibration(
    calibration: Path, dataset: Path, method: str | None = None, quiet: bool = True
) -> VerifyResult:
    """Test the calibration file's mount (its method's result; method names one in a --method all
    file) on the dataset's frames (3 or more). Raises CalibrationFileError when the two do not
    belong together (robot pose frames, set-ups) or a file is bad."""
    cal = read_calibration(calibration, method)
    data = load_dataset(dataset)
    pose_frame = data.metadata.get("pose_frame", "flange")
    if pose_frame != cal.pose_frame:
        raise CalibrationFileError(
            f"{calibration}: calibrated with the robot's {cal.pose_frame} poses, but {dataset} "
            f"records {pose_frame} poses"
        )
    setup = dataset_setup(data)
    if setup != cal.setup:
        raise CalibrationFileError(
            f"{calibration}: an {cal.setup} calibration, but {dataset} records an {setup} cell"
        )
    observations, source = cached_or_detected(data, quiet)
    if not cal.use_depth:
        observations = without_depth(observations)
    problem = dataset_problem(data, observations, use_depth=cal.use_depth)
    v = verify_mount(
        verification_problem(problem, cal.noise), cal.T_flange_cam, cal.covariance, cal.depth_scale
    )
    truth = None
    if data.ground_truth is not None:
        dt, dr = pose_error(cal.T_flange_cam, data.ground_truth.hand_eye)
        truth = (float(dt), float(dr))
    return VerifyResult(
        cal,
        data.root,
        len(problem.frames),
        problem.observation_count,
        source,
        tuple(problem.rejected),
        v,
        truth,
    )


def untested_message(cal: CalibrationFile) -> str:
    """Why a calibration without a covariance cannot be tested (one line)."""
    return (
        f"{cal.path}: field 'covariance' is null ({cal.method} gives no uncertainty): "
        "cannot tell a moved camera from the calibration's own error; calibrate with a method that "
        "reports a covariance (ekf, iekf, ukf, batch, seed-ekf)"
    )
