"""The calibration session, the same for the simulated and the real cell: for each planned
waypoint move, settle, capture, read the pose, write the frame, and (optionally) detect it
and re-run the EKF over every frame so far to show the running estimate and its sigma.

A cell (SessionCell) is hec.sim.session_cell.SimulatedCell or hec.hardware.cell.HardwareCell. The moves are
a fixed plan or a MoveSource that chooses each after the frames before it (the adaptive session,
hec.session.adaptive).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from hec.estimator.common.files import os_error_text
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.waypoints import PlannedMove, Waypoint, WaypointRejected
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.recorder import DatasetRecorder
from hec.estimator.observe.corner_noise import learn_corner_floor
from hec.estimator.observe.frames import Capture, Frame
from hec.estimator.observe.observations import (
    FrameObservations,
    dataset_depth_noise,
    observe_dataset,
    observe_frame,
    save_observations,
)
from hec.estimator.solve.calibration import Calibration, MethodOptions
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import run_method
from hec.estimator.solve.problem import (
    CalibrationInputError,
    build_problem,
    dataset_robot_noise,
    dataset_setup,
)
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.target import Target
from hec.hardware.camera_settings import CameraError
from hec.hardware.ur_robot import RobotError
from hec.session.plot import PLOT_FILE, plot_convergence

# Why the running estimate may not exist yet: too few usable frames, or the method failed.
_NOT_YET = (CalibrationInputError, ValueError, np.linalg.LinAlgError)
# What stops a session (the frames recorded before stay): the arm, the camera, a frame that cannot be
# written (a full disk; the error names the file), or Ctrl-C, SIGTERM and SIGHUP.
SESSION_STOPS = (RobotError, CameraError, OSError, KeyboardInterrupt)


class SessionCell(Protocol):
    """What a session needs of a cell: what its camera is, a plan of joint targets, moving
    (raises WaypointRejected to skip a waypoint, a SESSION_STOPS error to stop) and capturing."""

    source: str
    intrinsics: CameraIntrinsics
    board: Target
    depth_scale_m: float

    def plan(self, waypoints: list[Waypoint]) -> list[PlannedMove]: ...
    def move_to(self, move: PlannedMove) -> None: ...
    def capture(self) -> Capture: ...
    def close(self) -> None: ...


class MoveSource(Protocol):
    """Moves handed out one at a time, each once the frames before it are recorded and detected.
    max_moves: the most it hands out (the progress line's count); record(): what dataset.json's
    session block keeps of the choice."""

    max_moves: int

    def __iter__(self) -> Iterator[PlannedMove]: ...
    def record(self) -> dict: ...


def rss_sigmas(cal: Calibration) -> tuple[float, float] | None:
    """Root sum of squares of the per-axis 1-sigmas of T_flange_cam: (mm, deg); None without a
    covariance."""
    if cal.covariance is None:
        return None
    return float(np.linalg.norm(cal.sigma_translation_mm)), float(np.linalg.norm(cal.sigma_rotation_deg))


class LiveEstimate:
    """Detects each new frame of a recording and runs the EKF over every frame so far, with
    the dataset's depth and robot noise as declared (learning them from a few frames at every frame
    would cost seconds and say little; `hec calibrate` and `hec run`'s final calibration learn them
    from all frames), so the running estimate shows how the views add up as they come.
    latest: the estimate over every frame so far, None until one exists. target_sigma: (mm, deg)
    RSS 1-sigmas each line compares the estimate's with (None: no comparison)."""

    def __init__(
        self, root: Path, method: str = DEFAULT_METHOD, target_sigma: tuple[float, float] | None = None
    ) -> None:
        dataset = load_dataset(root)
        self.board, self.intrinsics = dataset.board, dataset.intrinsics
        self.depth_noise = dataset_depth_noise(dataset)
        self.robot_noise = dataset_robot_noise(dataset)
        self.setup = dataset_setup(dataset)
        self.settings = DetectorSettings()
        self.detector = detector_for(dataset.board, self.settings)
        self.method = method
        self.target_sigma = target_sigma
        self.latest: Calibration | None = None
        self.observations: list[FrameObservations] = observe_dataset(dataset, self.settings, self.depth_noise)

    def add(self, index: int, frame: Frame) -> str:
        """Detect frame number index; returns a line: markers found and the running estimate."""
        obs = observe_frame(index, frame, self.detector, self.depth_noise)
        self.observations.append(obs)
        found = f"{len(obs.markers)}/{len(self.board.marker_ids)} markers"
        if obs.problem:
            found += f" ({obs.problem})"
        return f"{found} | {self.method}: {self._estimate_line()}"

    def estimate(self, observations: list[FrameObservations] | None = None) -> Calibration:
        """The method's result over the given observations (default: every frame so far).
        Raises CalibrationInputError (too few usable frames) and the method's own errors."""
        observations = self.observations if observations is None else observations
        problem = build_problem(observations, self.board, self.intrinsics, self.robot_noise, setup=self.setup)
        return run_method(self.method, problem, MethodOptions(learn_noise=False), observations)

    def history(self) -> list[tuple[int, Calibration]]:
        """The estimate after each frame so far, as (frames used, result), from the first
        frame count that calibrates."""
        results = []
        for count in range(1, len(self.observations) + 1):
            try:
                results.append((count, self.estimate(self.observations[:count])))
            except _NOT_YET:
                continue
        return results

    def _estimate_line(self) -> str:
        try:
            cal = self.latest = self.estimate()
        except _NOT_YET as exc:
            self.latest = None
            return f"not yet ({exc})"
        t = 1e3 * cal.T_flange_cam[:3, 3]
        line = "t [" + " ".join(f"{v:+.2f}" for v in t) + "] mm"
        if cal.sigma_translation_mm is not None:
            line += " +- [" + " ".join(f"{v:.2f}" for v in cal.sigma_translation_mm) + "] mm"
            line += ", rotation +- [" + " ".join(f"{v:.3f}" for v in cal.sigma_rotation_deg) + "] deg"
        rss = rss_sigmas(cal)
        if self.target_sigma is not None and rss is not None:
            line += (
                f" | RSS {rss[0]:.3f} mm / {rss[1]:.4f} deg, target {self.target_sigma[0]:g} mm / "
                f"{self.target_sigma[1]:g} deg"
            )
        return line

    def save(self, root: Path) -> list[Path]:
        """Write the observations, on the corner noise floor they show, as the dataset's
        detections.json (after its last change) and, once the estimate has a sigma, the picture
        of how it settled. Frames recorded but not yet detected (Ctrl-C during a frame's
        detection) are detected first. Returns the files."""
        dataset = load_dataset(root)
        for index in range(len(self.observations), len(dataset)):
            self.observations.append(
                observe_frame(index, dataset.frame(index), self.detector, self.depth_noise)
            )
        learned, noise = learn_corner_floor(self.observations, self.board, self.intrinsics, self.settings)
        block = None if noise is None else noise.to_dict()
        written = [save_observations(root, learned, self.settings, self.depth_noise, block)]
        history = self.history()
        if any(c.covariance is not None for _, c in history):
            written.append(plot_convergence(history, root / PLOT_FILE))
        return written


@dataclass
class SessionOutcome:
    """recorded: frames written by this run; total: frames in the dataset; skipped: (waypoint
    index, reason); stopped: why the session ended early, None when every waypoint was visited."""

    root: Path
    recorded: int = 0
    total: int = 0
    skipped: list[tuple[int, str]] = field(default_factory=list)
    stopped: str | None = None


def run_session(
    cell: SessionCell,
    moves: list[PlannedMove] | MoveSource,
    recorder: DatasetRecorder,
    live: LiveEstimate | None = None,
    say: Callable[[str], None] = print,
) -> SessionOutcome:
    """Visit every planned move not yet recorded (a resumed session skips those), or each move a
    MoveSource hands out, writing each frame as it is captured. A stop of the arm or camera, a full
    disk, or Ctrl-C ends the session with the frames so far kept and dataset.json marked
    'interrupted'."""
    outcome = SessionOutcome(recorder.root)
    if isinstance(moves, list):
        done = recorder.recorded_waypoints
        todo: list[PlannedMove] | MoveSource = [m for m in moves if m.waypoint.index not in done]
        count = len(todo)
        if done:
            say(f"resuming: {len(recorder.rows)} frames recorded before, {count} waypoints to go")
    else:
        todo, count = moves, moves.max_moves
    try:
        for n, move in enumerate(todo, start=1):
            w = move.waypoint
            head = f"[{n}/{count}] waypoint {w.index} ({w.label})"
            try:
                if move.problem is not None:
                    raise WaypointRejected(move.problem)
                cell.move_to(move)
            except WaypointRejected as rejected:
                outcome.skipped.append((w.index, rejected.reason))
                say(f"{head}: skipped, {rejected.reason}")
                continue
            capture = cell.capture()
            index = recorder.add_frame(capture, w.index)
            outcome.recorded += 1
            say(f"{head}: frame {index}" + (f" | {live.add(index, capture.frame)}" if live else ""))
    except SESSION_STOPS as exc:
        outcome.stopped = os_error_text(exc) if isinstance(exc, OSError) else str(exc)
        if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, or SIGTERM/SIGHUP ("stopped by SIGTERM")
            outcome.stopped = str(exc) or "stopped by Ctrl-C"
    outcome.total = len(recorder.rows)
    session = {
        "waypoints": len(moves) if isinstance(moves, list) else None,
        "skipped_waypoints": [{"index": i, "reason": r} for i, r in outcome.skipped],
        "stopped": outcome.stopped,
    }
    if not isinstance(moves, list):
        session |= moves.record()
    recorder.finish("interrupted" if outcome.stopped else "complete", {"session": session})
    if live is not None:
        live.save(recorder.root)
    return outcome
