"""One sweep trial: draw the mount, the views and the noise from the trial's seed, build the
observations (synthesised at measurement fidelity; rendered and detected at render fidelity, as
`hec demo` does) and run every method against the truth.

Fidelities: ``measurements`` synthesises the observations from the cell's geometry and
noise models (hec.estimator.observe.synthetic: no images); ``render`` renders each trial with MuJoCo
(hec.sim.simulate; in memory, or into a dataset folder when kept), detects the board and estimates.
"""

from __future__ import annotations

import contextlib
import io
import math
import shutil
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from hec.estimator.geometry.camera import project_points
from hec.estimator.geometry.lie import pose_nees
from hec.estimator.geometry.transforms import invert, pose_error, rpy_from_transform, transform_points
from hec.estimator.geometry.waypoints import (
    Waypoint,
    WaypointFileError,
    look_at_board,
    rotation_rich_views,
    translated_waypoints,
    write_waypoint_file,
)
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.observations import camera_points
from hec.estimator.solve.problem import CalibrationInputError, build_problem, dataset_arm, dataset_robot_noise
from hec.sim.noise import depth_noise_model, robot_pose_noise_model
from hec.sim.scenario import scenario_from_dict
from hec.sweep.config import SweepConfig, cell_scenario
from hec.sweep.parameters import MEASUREMENTS
from hec.sweep.rows import FLOAT_COLUMNS, SweepError, trial_id

# Random trajectory: views of the board centre (hec.estimator.geometry.waypoints.look_at_board)
# with every marker in view.
RANDOM_TILT_DEG, RANDOM_ROLL_DEG, RANDOM_DISTANCE_FACTOR = (10.0, 35.0), 30.0, (0.9, 1.2)
RANDOM_VIEW_DRAWS = 200
_TEMPORARY: set[Path] = set()  # render trials' scratch folders while they exist


def remove_temporary_folders() -> None:
    """Remove the scratch folders of the render trials running in this process (a worker stopped)."""
    for folder in list(_TEMPORARY):
        shutil.rmtree(folder, ignore_errors=True)
        _TEMPORARY.discard(folder)


@dataclass(frozen=True)
class TrialTask:
    """Everything a worker needs for one trial (picklable; no open files, no numpy state).
    scenario: the base Scenario.to_dict(), base_dir its folder. keep_dir: keep rendered datasets there.
    example_dir: render fidelity, first trial: keep its dataset there with previews and detection
    overlays, for the report."""

    trial_id: str
    cell: str
    cell_index: int
    trial: int
    seed: int
    fidelity: str
    parameters: dict
    methods: tuple[str, ...]
    scenario: dict
    base_dir: str
    keep_dir: str | None = None
    example_dir: str | None = None
    paired: bool = False

    @property
    def seed_list(self) -> list[int]:
        """The trial's seed for numpy.random.default_rng: [seed, trial] when paired (the same in
        every cell), else [seed, cell_index, trial]."""
        return [self.seed, self.trial] if self.paired else [self.seed, self.cell_index, self.trial]

    @property
    def seed_text(self) -> str:
        """The seed column: seed_list joined by '/'."""
        return "/".join(map(str, self.seed_list))


def tasks_for(
    config: SweepConfig, keep_dir: Path | None = None, example_dir: Path | None = None
) -> list[TrialTask]:
    """Every trial of a sweep, cell by cell; the first one keeps its dataset in example_dir if given."""
    base, base_dir = config.scenario.to_dict(), str(Path(config.scenario.base_dir).resolve())
    tasks = [
        TrialTask(
            trial_id(cell.index, t),
            cell.id,
            cell.index,
            t,
            config.seed,
            config.fidelity,
            dict(cell.parameters),
            tuple(config.methods),
            base,
            base_dir,
            None if keep_dir is None else str(keep_dir),
            paired=config.paired,
        )
        for cell in config.cells
        for t in range(config.trials)
    ]
    if example_dir is not None and tasks:
        tasks[0] = replace(tasks[0], example_dir=str(example_dir))
    return tasks


def _rss(values: np.ndarray | None) -> float:
    """Root-sum-square of (3,) sigmas; NaN when there are none or one is not finite."""
    if values is None:
        return math.nan
    total = float(np.sqrt(np.sum(np.square(values))))
    return total if math.isfinite(total) else math.nan


def one_line(text: str) -> str:
    return " | ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _mount(scenario: Any, kind: str, rng: np.random.Generator) -> np.ndarray:
    """The trial's camera: T_flange_cam (eye-to-hand T_base_cam) of the scenario, or one drawn around
    it as random_mount draws it."""
    T_fixed = scenario.stand.transform() if scenario.eye_to_hand else scenario.mount.transform()
    if kind == "fixed":
        return T_fixed
    from hec.support.synthetic_scenes import SCENARIO, random_mount

    return T_fixed @ invert(SCENARIO.mount.transform()) @ random_mount(rng)


def _random_views(scenario: Any, board: Any, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """n T_board_cam (4, 4) aimed at the board centre, each showing every marker corner inside the
    image with the scenario's margin_px and within max_view_angle_deg (redrawn until it does)."""
    settings, k = scenario.trajectory, scenario.camera.intrinsics()
    corners = board.all_corners().reshape(-1, 3)
    views = []
    for _ in range(n):
        for _ in range(RANDOM_VIEW_DRAWS):
            T_board_cam = look_at_board(
                rng.uniform(*RANDOM_TILT_DEG),
                rng.uniform(0.0, 360.0),
                rng.uniform(-RANDOM_ROLL_DEG, RANDOM_ROLL_DEG),
                settings.distance_m * rng.uniform(*RANDOM_DISTANCE_FACTOR),
            )
            T_cam_board = invert(T_board_cam)
            p_cam = corners @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            cos_view = -(p_cam @ T_cam_board[:3, 2]) / np.linalg.norm(p_cam, axis=1)
            if np.any(p_cam[:, 2] <= 0.05) or cos_view.min() < np.cos(
                np.radians(settings.max_view_angle_deg)
            ):
                continue
            uv, m = project_points(T_cam_board, corners, k.K), settings.margin_px
            if np.all((uv >= m - 0.5) & (uv <= [k.width - 0.5 - m, k.height - 0.5 - m])):
                views.append(T_board_cam)
                break
        else:
            raise SweepError(f"no random view shows the whole board in {RANDOM_VIEW_DRAWS} draws")
    return views


def _board_pose(scenario: Any) -> np.ndarray:
    """(4, 4) the board's fixed pose: T_base_board, eye-to-hand T_flange_board."""
    return scenario.board_mount.transform() if scenario.eye_to_hand else scenario.board.transform()


def _flange_for_view(scenario: Any, X: np.ndarray, T_board_cam: np.ndarray) -> np.ndarray:
    """(4, 4) T_base_flange that shows the camera X (T_flange_cam; eye-to-hand T_base_cam) the board
    from T_board_cam (4, 4)."""
    if scenario.eye_to_hand:
        return X @ invert(T_board_cam) @ invert(scenario.board_mount.transform())
    return scenario.board.transform() @ T_board_cam @ invert(X)


def _flange_poses(scenario: Any, board: Any, params: dict, X: np.ndarray, rng: np.random.Generator) -> list:
    """The trial's true T_base_flange (4, 4) targets: the first `waypoints` views of its trajectory."""
    distance, n = scenario.trajectory.distance_m, params["waypoints"]
    if params["trajectory"] == "random":
        return [_flange_for_view(scenario, X, T) for T in _random_views(scenario, board, n, rng)]
    if params["trajectory"] == "paper":
        return [
            w.T_base_flange
            for w in translated_waypoints(_flange_for_view(scenario, X, look_at_board(0, 0, 0, distance)))[:n]
        ]
    return [_flange_for_view(scenario, X, T) for _, T in rotation_rich_views(distance)[:n]]


def _with_depth_bias(observations: list, flange_true: list, X: np.ndarray, scenario: Any, board: Any) -> list:
    """Add the scenario's depth bias as the simulator does: z = scale * z_true + offset + noise."""
    bias, intrinsics = scenario.noise.depth_bias, scenario.camera.intrinsics()
    for obs in observations:
        F = flange_true[obs.frame]
        if scenario.eye_to_hand:
            T_cam_board = invert(X) @ F @ _board_pose(scenario)
        else:
            T_cam_board = invert(F @ X) @ _board_pose(scenario)
        for i, m in enumerate(obs.markers):
            p_board = np.vstack([board.marker_center(m.marker_id)[None], board.marker_corners(m.marker_id)])
            z_true = transform_points(T_cam_board, p_board)[:, 2]
            z = m.depth_m + (bias.scale - 1.0) * z_true + bias.offset_m
            points, points_cov = camera_points(m, z, m.depth_cov, np.zeros((5, 2)), intrinsics)
            obs.markers[i] = replace(m, depth_m=z, points_cam=points, points_cov=points_cov)
    return observations


def measurement_inputs(task: TrialTask, scenario: Any, rng: np.random.Generator) -> tuple:
    """Synthesise the trial's observations and return the inputs (as render_inputs; no arm)."""
    from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations

    board, intrinsics = scenario.board_definition(), scenario.camera.intrinsics()
    X = _mount(scenario, task.parameters["mount"], rng)
    flange_true = _flange_poses(scenario, board, task.parameters, X, rng)
    robot = robot_pose_noise_model(scenario.noise)
    noise = SyntheticNoise(task.parameters["pixel_sigma_px"], depth_noise_model(scenario.noise), robot)
    B = _board_pose(scenario)
    observations = synthetic_observations(
        board, intrinsics, X, B, flange_true, noise, rng, setup=scenario.setup
    )
    if scenario.noise.depth_bias.enabled:
        observations = _with_depth_bias(observations, flange_true, X, scenario, board)
    return observations, board, intrinsics, robot, None, X, B


def _trial_scenario(scenario: Any, T_flange_cam: np.ndarray, waypoint_file: Path, name: str) -> Any:
    """The scenario with the mount T_flange_cam (4, 4) (eye-to-hand: the stand T_base_cam) and the
    trajectory of waypoint_file."""
    data = scenario.to_dict()
    data["stand" if scenario.eye_to_hand else "mount"] = {
        "translation_m": [float(v) for v in T_flange_cam[:3, 3]],
        "rotation_rpy_deg": [float(v) for v in np.degrees(rpy_from_transform(T_flange_cam))],
    }
    data["trajectory"] = {**data["trajectory"], "kind": "file", "file": str(waypoint_file)}
    return scenario_from_dict(data, f"trial {name}", Path(scenario.base_dir))


def render_views(
    scenario: Any,
    T_flange_cam: np.ndarray,
    flange: list[np.ndarray],
    sim_seed: int,
    name: str,
    out: Path | None = None,
    example: bool = False,
    noise_seed: int | None = None,
) -> tuple[Dataset, list]:
    """Render the scenario's cell with the mount T_flange_cam (4, 4) at the T_base_flange (4, 4)
    targets flange and detect it: (the dataset, its observations). The frames stay in memory
    (hec.estimator.io.memory) unless out names a folder to write the dataset into. sim_seed draws the
    true cell, noise_seed (default sim_seed) each frame's noise (hec.sim.simulate.simulate); name: the
    trial, for messages and the scratch folder's name; example: with previews and detection
    overlays (needs out)."""
    from hec.estimator.targets.qr import DetectorSettings
    from hec.sim.simulate import SimulationError, simulate, simulate_in_memory
    from hec.support.detection import detect_and_cache, detect_dataset, overlay_writer

    tmp = Path(tempfile.mkdtemp(prefix=f"hec-sweep-{name}-"))
    _TEMPORARY.add(tmp)
    try:
        waypoint_file = tmp / "waypoints.csv"
        write_waypoint_file(
            waypoint_file, [Waypoint(i, f"view {i}", T_base_flange=T) for i, T in enumerate(flange)]
        )
        trial_scenario = _trial_scenario(scenario, T_flange_cam, waypoint_file, name)
        try:
            with contextlib.redirect_stderr(io.StringIO()):  # skipped waypoints: the dataset lists them
                if out is None:
                    dataset = simulate_in_memory(trial_scenario, sim_seed, noise_seed, f"trial {name}")
                else:
                    result = simulate(
                        trial_scenario,
                        out,
                        sim_seed,
                        force=True,
                        preview=example,
                        progress=False,
                        noise_seed=noise_seed,
                    )
                    dataset = load_dataset(result.out_dir)
        except (SimulationError, WaypointFileError) as exc:
            raise SweepError(f"simulation: {exc}") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        _TEMPORARY.discard(tmp)
    if out is None:
        observations, _ = detect_dataset(dataset, DetectorSettings(), quiet=True)
    else:
        on_frame = overlay_writer(dataset) if example else None
        observations, _, _ = detect_and_cache(dataset, DetectorSettings(), quiet=True, on_frame=on_frame)
    return dataset, observations


def render_inputs(task: TrialTask, scenario: Any, rng: np.random.Generator) -> tuple:
    """Render the trial (in memory unless task.keep_dir or task.example_dir), detect, and return the
    inputs: observations, board, intrinsics, robot noise, the arm behind the poses (a measurement
    trial has none), the true T_flange_cam and T_base_board."""
    board = scenario.board_definition()
    X = _mount(scenario, task.parameters["mount"], rng)
    flange = _flange_poses(scenario, board, task.parameters, X, rng)
    sim_seed = int(rng.integers(0, 2**63 - 1))
    out = Path(task.keep_dir) / task.trial_id if task.keep_dir else None
    out = Path(task.example_dir) if task.example_dir else out
    dataset, observations = render_views(
        scenario, X, flange, sim_seed, task.trial_id, out, example=bool(task.example_dir)
    )
    truth, robot = dataset.ground_truth, dataset_robot_noise(dataset)
    arm = dataset_arm(dataset)
    return observations, dataset.board, dataset.intrinsics, robot, arm, truth.hand_eye, truth.board_pose


def _failed(base: dict, method: str, failure: str, crb: tuple[float, float], time_s: float) -> dict:
    nan = math.nan
    return {
        **base,
        "method": method,
        "status": "failed",
        "failure": one_line(failure) or "failed",
        **dict.fromkeys(FLOAT_COLUMNS, nan),
        "crb_translation_mm": crb[0],
        "crb_rotation_deg": crb[1],
        "time_s": time_s,
    }


def run_trial(task: TrialTask) -> list[dict]:
    """One trial: its rows, one per method in task.methods (a failure is a row, not an exception)."""
    from hec.estimator.solve.calibration import MethodOptions
    from hec.estimator.solve.measurement_model import HandEyeState
    from hec.estimator.solve.methods import needs_learned_noise, solve
    from hec.estimator.solve.noise_learning import learn_noise
    from hec.estimator.solve.observability import observability

    base = {
        "trial_id": task.trial_id,
        "cell": task.cell,
        "fidelity": task.fidelity,
        "seed": task.seed_text,
        **task.parameters,
    }
    rng = np.random.default_rng(task.seed_list)
    scenario = cell_scenario(task.scenario, task.base_dir, task.parameters)
    no_crb = (math.nan, math.nan)
    start = time.perf_counter()
    try:
        make = measurement_inputs if task.fidelity == MEASUREMENTS else render_inputs
        observations, board, intrinsics, robot, arm, X, T_base_board = make(task, scenario, rng)
        problem = build_problem(observations, board, intrinsics, robot, arm=arm, setup=scenario.setup)
    except (CalibrationInputError, SweepError) as exc:
        elapsed = time.perf_counter() - start
        return [_failed(base, m, str(exc), no_crb, elapsed) for m in task.methods]
    bound = observability(problem, HandEyeState(X, T_base_board=T_base_board))
    crb = (
        (_rss(bound.crb_sigma_translation_mm), _rss(bound.crb_sigma_rotation_deg))
        if bound.observable
        else no_crb
    )
    rows = []
    options, learned = MethodOptions(), None
    for method in task.methods:
        start = time.perf_counter()
        try:  # solve, not run_method: the observability at the estimate is not needed here
            if learned is None and needs_learned_noise(method, options):
                learned = learn_noise(problem, options)  # once, shared by the noise-modelling methods
            result = solve(method, problem, options, observations, learned)
        except Exception as exc:  # noqa: BLE001  (any failure of one method is that method's row)
            message = str(exc) if isinstance(exc, CalibrationInputError) else f"{type(exc).__name__}: {exc}"
            rows.append(_failed(base, method, message, crb, time.perf_counter() - start))
            continue
        error_m, error_rad = pose_error(result.T_flange_cam, X)
        nees = math.nan
        if result.covariance is not None:
            with contextlib.suppress(np.linalg.LinAlgError):
                nees = pose_nees(result.T_flange_cam, X, result.covariance)
        rows.append(
            {
                **base,
                "method": method,
                "status": "ok",
                "failure": "",
                "error_translation_mm": 1e3 * error_m,
                "error_rotation_deg": math.degrees(error_rad),
                "sigma_translation_mm": _rss(result.sigma_translation_mm),
                "sigma_rotation_deg": _rss(result.sigma_rotation_deg),
                "nees": nees if math.isfinite(nees) else math.nan,
                "crb_translation_mm": crb[0],
                "crb_rotation_deg": crb[1],
                "time_s": float(result.diagnostics.get("time_s", time.perf_counter() - start)),
                "warnings": float(len(result.warnings)),
            }
        )
    return rows
