"""The calibration file (`hec calibrate --json`, hec.save_calibration): the context a result is
written with (the dataset, the frames used, the options, the robot pose noise and its source) and
the detection's notes on the frames it kept. hec verify, hec export and hec plan read it back
(hec.estimator.io.calibration_file)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hec.calibration.loo import BUDGET_S
from hec.estimator.io.calibration_file import CALIBRATION_FORMAT, CALIBRATION_VERSION
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.problem import CalibrationProblem


@dataclass(frozen=True)
class CalibrationContext:
    """How a calibration was run: where its robot pose noise came from (in words), whether depth
    was used, the map model, whether the depth scale was estimated, the prior file, whether it was
    cross-validated and within what budget (seconds; None: any)."""

    noise_source: str
    use_depth: bool = True
    map_model: str = "board"
    estimate_depth_scale: bool = False
    prior_file: Path | None = None
    loo: bool = True
    loo_budget_s: float | None = BUDGET_S


def robot_noise_source(dataset: Dataset) -> str:
    """Where the dataset's robot pose noise comes from, in words."""
    return "dataset.json" if "robot_pose_noise" in dataset.metadata else "default: dataset.json has none"


def calibration_context(dataset: Dataset, problem: CalibrationProblem, context: CalibrationContext) -> dict:
    """The calibration file's fields beside the result's own: its format, the dataset, the frames
    used and left out, the options and the robot pose noise (metres, radians)."""
    return {
        "format": CALIBRATION_FORMAT,
        "version": CALIBRATION_VERSION,
        "dataset": str(dataset.root),
        "pose_frame": dataset.metadata.get("pose_frame", "flange"),
        "frames_used": len(problem.frames),
        "frames_left_out": list(problem.rejected),
        "use_depth": context.use_depth,
        "map_model": context.map_model,
        "estimate_depth_scale": context.estimate_depth_scale,
        "prior_file": None if context.prior_file is None else str(context.prior_file),
        "leave_one_frame_out_settings": {"enabled": context.loo, "budget_s": context.loo_budget_s},
        "robot_pose_noise": problem.robot_noise.to_dict() | {"source": context.noise_source},
    }


def frame_notes(observations: list[FrameObservations]) -> list[str]:
    """What the detection said of frames it kept (a depth image not aligned to the colour image,
    without valid pixels), one line per note with the frames it was said of."""
    frames: dict[str, list[int]] = {}
    for o in observations:
        for note in o.notes:
            frames.setdefault(note, []).append(o.frame)
    return [
        f"frame {said[0]}: {note}" if len(said) == 1 else f"frames {', '.join(map(str, said))}: {note}"
        for note, said in frames.items()
    ]
