"""`hec sweep`: a reproducible grid of calibration trials, run on local processes or a Dask cluster.

A sweep file (experiments.sweep_config) names the parameters to vary, the fidelity and the
methods. Trial t of cell c draws everything (mount, random views, noise) from
``numpy.random.default_rng([seed, c, t])``, so the results do not depend on where or in
which order trials run, and one trial can be rerun alone (--rerun c03-t0042).

Fidelities: ``measurements`` synthesises the observations from the cell's geometry and
noise models (estimator.synthetic: no images); ``render`` renders each trial with MuJoCo
into a temporary dataset (sim.simulate), detects the board and estimates, as `hec demo` does.

Output folder:

    sweep.json   written first: the resolved configuration, its cells, the columns, software versions
    rows.csv     one row per trial and method, appended and flushed as each trial finishes; on
                 completion (and on --resume) rewritten sorted, through a rename. load_rows reads it.

Row columns (row_columns): trial_id ('c03-t0042'), cell ('c03'), fidelity, seed ('seed/cell/trial'),
the fidelity's parameters (experiments.sweep_config.PARAMETERS, resolved values), method, status
('ok' | 'failed'), failure ('' when ok), error_translation_mm, error_rotation_deg (against the truth),
sigma_translation_mm, sigma_rotation_deg (root-sum-square of the method's three 1-sigmas; NaN without
a covariance), nees (NaN without a covariance), crb_translation_mm, crb_rotation_deg (root-sum-square
of the Cramer-Rao sigmas at the truth; NaN when not observable), time_s (the method's own time).

The estimators, the detector and MuJoCo are imported where a trial runs, not with this module
(the `hec` command line builds its parser from add_parser). Each worker process uses one BLAS
thread (OPENBLAS_NUM_THREADS=1, also what Dask's nanny sets), which keeps the floating-point
results identical wherever a trial runs.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import multiprocessing
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from estimator.camera import project_points
from estimator.dataset import load_dataset
from estimator.files import write_atomic
from estimator.geometry import invert, pose_error, rpy_from_transform, transform_points
from estimator.jsonfile import read_json_object
from estimator.lie import pose_minus
from estimator.observations import camera_points
from estimator.problem import CalibrationInputError, build_problem, dataset_robot_noise
from experiments.sweep_config import (
    MEASUREMENTS,
    PARAMETERS,
    RENDER,
    SweepConfig,
    SweepConfigError,
    cell_scenario,
    load_config,
    parameter_columns,
)
from sim.noise import depth_noise_model, robot_pose_noise_model
from sim.scenario import scenario_from_dict
from sim.trajectory import (
    Waypoint,
    WaypointFileError,
    look_at_board,
    paper_waypoints,
    rotation_rich_waypoints,
    write_waypoint_file,
)

ROWS_FILE, META_FILE, DATASETS_DIR, EXAMPLE_DIR = "rows.csv", "sweep.json", "datasets", "example"
FORMAT, VERSION = "hec-sweep", 1
ID_COLUMNS = ("trial_id", "cell", "fidelity", "seed")
RESULT_COLUMNS = (
    "method",
    "status",
    "failure",
    "error_translation_mm",
    "error_rotation_deg",
    "sigma_translation_mm",
    "sigma_rotation_deg",
    "nees",
    "crb_translation_mm",
    "crb_rotation_deg",
    "time_s",
)
FLOAT_COLUMNS = RESULT_COLUMNS[3:]
# Random trajectory: views of the board centre (sim.trajectory.look_at_board) with every marker in view.
RANDOM_TILT_DEG, RANDOM_ROLL_DEG, RANDOM_DISTANCE_FACTOR = (10.0, 35.0), 30.0, (0.9, 1.2)
RANDOM_VIEW_DRAWS = 200
POOL_RESTARTS = 3
TRIAL_ID = re.compile(r"^c(\d+)-t(\d+)$")
BLAS_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


class SweepError(RuntimeError):
    """An output folder or a trial id that cannot be used; the message says why."""


def row_columns(fidelity: str) -> list[str]:
    """Every column of a fidelity's rows, in file order."""
    return [*ID_COLUMNS, *parameter_columns(fidelity), *RESULT_COLUMNS]


def trial_id(cell_index: int, trial: int) -> str:
    return f"c{cell_index:02d}-t{trial:04d}"


# ------------------------------------------------------------------ one trial


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

    @property
    def seed_text(self) -> str:
        """The derived seed: default_rng([seed, cell_index, trial])."""
        return f"{self.seed}/{self.cell_index}/{self.trial}"


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


def _one_line(text: str) -> str:
    return " | ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _mount(scenario: Any, kind: str, rng: np.random.Generator) -> np.ndarray:
    """T_flange_cam of a trial: the scenario's, or one drawn around it as random_mount draws it."""
    T_fixed = scenario.mount.transform()
    if kind == "fixed":
        return T_fixed
    from experiments.synthetic_scenes import SCENARIO, random_mount

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


def _flange_poses(scenario: Any, board: Any, params: dict, X: np.ndarray, rng: np.random.Generator) -> list:
    """The trial's true T_base_flange (4, 4) targets: the first `waypoints` views of its trajectory."""
    T_base_board, distance = scenario.board.transform(), scenario.trajectory.distance_m
    n = params["waypoints"]
    if params["trajectory"] == "random":
        return [T_base_board @ T @ invert(X) for T in _random_views(scenario, board, n, rng)]
    make = paper_waypoints if params["trajectory"] == "paper" else rotation_rich_waypoints
    return [w.T_base_flange for w in make(T_base_board, X, distance)[:n]]


def _with_depth_bias(observations: list, flange_true: list, X: np.ndarray, scenario: Any, board: Any) -> list:
    """Add the scenario's depth bias as the simulator does: z = scale * z_true + offset + noise."""
    bias, intrinsics = scenario.noise.depth_bias, scenario.camera.intrinsics()
    T_base_board = scenario.board.transform()
    for obs in observations:
        T_cam_board = invert(flange_true[obs.frame] @ X) @ T_base_board
        for i, m in enumerate(obs.markers):
            p_board = np.vstack([board.marker_center(m.marker_id)[None], board.marker_corners(m.marker_id)])
            z_true = transform_points(T_cam_board, p_board)[:, 2]
            z = m.depth_m + (bias.scale - 1.0) * z_true + bias.offset_m
            points, points_cov = camera_points(m, z, m.depth_cov, np.zeros((5, 2)), intrinsics)
            obs.markers[i] = replace(m, depth_m=z, points_cam=points, points_cov=points_cov)
    return observations


def _measurement_inputs(task: TrialTask, scenario: Any, rng: np.random.Generator) -> tuple:
    from estimator.synthetic import SyntheticNoise, synthetic_observations

    board, intrinsics = scenario.board_definition(), scenario.camera.intrinsics()
    X = _mount(scenario, task.parameters["mount"], rng)
    flange_true = _flange_poses(scenario, board, task.parameters, X, rng)
    robot = robot_pose_noise_model(scenario.noise)
    noise = SyntheticNoise(task.parameters["pixel_sigma_px"], depth_noise_model(scenario.noise), robot)
    T_base_board = scenario.board.transform()
    observations = synthetic_observations(board, intrinsics, X, T_base_board, flange_true, noise, rng)
    if scenario.noise.depth_bias.enabled:
        observations = _with_depth_bias(observations, flange_true, X, scenario, board)
    return observations, board, intrinsics, robot, X, T_base_board


def _render_inputs(task: TrialTask, scenario: Any, rng: np.random.Generator) -> tuple:
    """Render the trial into a dataset (temporary unless task.keep_dir), detect, and return the inputs."""
    from estimator.detect import DetectorSettings
    from experiments.detection import detect_and_cache, overlay_writer
    from sim.simulate import SimulationError, simulate

    board = scenario.board_definition()
    X = _mount(scenario, task.parameters["mount"], rng)
    flange = _flange_poses(scenario, board, task.parameters, X, rng)
    sim_seed = int(rng.integers(0, 2**63 - 1))
    tmp = Path(tempfile.mkdtemp(prefix=f"hec-sweep-{task.trial_id}-"))
    try:
        waypoint_file = tmp / "waypoints.csv"
        write_waypoint_file(
            waypoint_file, [Waypoint(i, f"view {i}", T_base_flange=T) for i, T in enumerate(flange)]
        )
        data = scenario.to_dict()
        data["mount"] = {
            "translation_m": [float(v) for v in X[:3, 3]],
            "rotation_rpy_deg": [float(v) for v in np.degrees(rpy_from_transform(X))],
        }
        data["trajectory"] = {**data["trajectory"], "kind": "file", "file": str(waypoint_file)}
        trial_scenario = scenario_from_dict(data, f"trial {task.trial_id}", Path(task.base_dir))
        out = Path(task.keep_dir) / task.trial_id if task.keep_dir else tmp / "dataset"
        out = Path(task.example_dir) if task.example_dir else out
        try:
            with contextlib.redirect_stderr(io.StringIO()):  # skipped waypoints: the dataset lists them
                result = simulate(
                    trial_scenario, out, sim_seed, force=True, preview=bool(task.example_dir), progress=False
                )
        except (SimulationError, WaypointFileError) as exc:
            raise SweepError(f"simulation: {exc}") from None
        dataset = load_dataset(result.out_dir)
        on_frame = overlay_writer(dataset) if task.example_dir else None
        observations, _ = detect_and_cache(dataset, DetectorSettings(), quiet=True, on_frame=on_frame)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    truth, robot = dataset.ground_truth, dataset_robot_noise(dataset)
    return observations, dataset.board, dataset.intrinsics, robot, truth.T_flange_cam, truth.T_base_board


def _failed(base: dict, method: str, failure: str, crb: tuple[float, float], time_s: float) -> dict:
    nan = math.nan
    return {
        **base,
        "method": method,
        "status": "failed",
        "failure": _one_line(failure) or "failed",
        **dict.fromkeys(FLOAT_COLUMNS, nan),
        "crb_translation_mm": crb[0],
        "crb_rotation_deg": crb[1],
        "time_s": time_s,
    }


def run_trial(task: TrialTask) -> list[dict]:
    """One trial: its rows, one per method in task.methods (a failure is a row, not an exception)."""
    from estimator.calibration import MethodOptions
    from estimator.measurement_model import HandEyeState
    from estimator.methods import METHODS
    from estimator.observability import observability

    base = {
        "trial_id": task.trial_id,
        "cell": task.cell,
        "fidelity": task.fidelity,
        "seed": task.seed_text,
        **task.parameters,
    }
    rng = np.random.default_rng([task.seed, task.cell_index, task.trial])
    scenario = cell_scenario(task.scenario, task.base_dir, task.parameters)
    no_crb = (math.nan, math.nan)
    start = time.perf_counter()
    try:
        make = _measurement_inputs if task.fidelity == MEASUREMENTS else _render_inputs
        observations, board, intrinsics, robot, X, T_base_board = make(task, scenario, rng)
        problem = build_problem(observations, board, intrinsics, robot)
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
    for method in task.methods:
        start = time.perf_counter()
        try:  # METHODS directly: run_method's observability at the estimate is not needed here
            result = METHODS[method](problem, MethodOptions(), observations)
        except Exception as exc:  # noqa: BLE001  (any failure of one method is that method's row)
            message = str(exc) if isinstance(exc, CalibrationInputError) else f"{type(exc).__name__}: {exc}"
            rows.append(_failed(base, method, message, crb, time.perf_counter() - start))
            continue
        error_m, error_rad = pose_error(result.T_flange_cam, X)
        nees = math.nan
        if result.covariance is not None:
            delta = pose_minus(result.T_flange_cam, X)
            with contextlib.suppress(np.linalg.LinAlgError):
                nees = float(delta @ np.linalg.solve(result.covariance, delta))
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
            }
        )
    return rows


# ------------------------------------------------------------------ rows on disk


def format_rows(rows: Iterable[dict], columns: list[str]) -> str:
    """CSV text of rows (floats as repr: they read back bit for bit)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    for row in rows:
        writer.writerow([repr(v) if isinstance(v, float) else v for v in (row[c] for c in columns)])
    return out.getvalue()


def _typed(name: str, text: str) -> Any:
    if name in FLOAT_COLUMNS:
        return float(text)
    if name in PARAMETERS:
        return PARAMETERS[name].kind(text)
    return text


def _sort_key(row: dict, methods: list[str]) -> tuple:
    match = TRIAL_ID.match(row["trial_id"])
    ids = (int(match[1]), int(match[2])) if match else (math.inf, row["trial_id"])
    return (*ids, methods.index(row["method"]) if row["method"] in methods else len(methods))


def _read_rows(path: Path, methods: list[str] | None) -> list[dict]:
    """Complete trials from a rows file: a half-written last line, lines that do not parse and
    trials missing a method's row are left out; a trial stored twice keeps its first rows."""
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.split("\n")
    lines = lines[:-1]  # the last piece has no newline: empty, or a half-written line
    if not lines:
        return []
    header = next(csv.reader([lines[0]]))
    trials: dict[str, dict[str, dict]] = {}
    for line in lines[1:]:
        try:
            fields = next(csv.reader([line]))
            if len(fields) != len(header):
                continue
            row = {name: _typed(name, value) for name, value in zip(header, fields, strict=True)}
        except (ValueError, StopIteration, csv.Error):
            continue
        group = trials.setdefault(row["trial_id"], {})
        group.setdefault(row["method"], row)
    rows = [
        row
        for group in trials.values()
        if methods is None or set(methods) <= set(group)
        for method, row in group.items()
        if methods is None or method in methods
    ]
    return sorted(rows, key=lambda r: _sort_key(r, methods or []))


def load_rows(out_dir: Path) -> list[dict]:
    """The rows of a sweep folder, typed (str, float, int as the columns are), sorted by cell, trial and
    method; only trials with every method's row (an interrupted run's partial trial is left out)."""
    out_dir = Path(out_dir)
    meta = read_json_object(out_dir / META_FILE, SweepError, "missing: not a sweep output folder")
    try:
        methods = list(meta["config"]["methods"])
    except (KeyError, TypeError):
        raise SweepError(f"{out_dir / META_FILE}: field 'config.methods' is missing") from None
    return _read_rows(out_dir / ROWS_FILE, methods)


def _compact(out_dir: Path, columns: list[str], methods: list[str]) -> list[dict]:
    """Rewrite rows.csv with its complete trials only, sorted (through a rename). Returns the rows."""
    rows = _read_rows(out_dir / ROWS_FILE, methods)
    write_atomic(out_dir / ROWS_FILE, ",".join(columns) + "\n" + format_rows(rows, columns))
    return rows


# ------------------------------------------------------------------ the sweep folder


def _software() -> dict:
    versions = {"python": sys.version.split()[0]}
    for name in ("hec", "numpy", "scipy", "opencv-python-headless", "mujoco", "dask", "distributed"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            versions[name] = metadata.version(name)
    repo = Path(__file__).resolve().parent.parent
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True)
        dirty = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain"], capture_output=True, text=True
        )
        if head.returncode == 0:
            versions["git_commit"] = head.stdout.strip() + (" (modified)" if dirty.stdout.strip() else "")
    return versions


def _metadata(config: SweepConfig) -> dict:
    return {
        "format": FORMAT,
        "version": VERSION,
        "config_file": str(config.path.resolve()),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "config": config.to_dict(),
        "trial_seed": "numpy.random.default_rng([seed, cell index, trial]); column seed = 'seed/cell/trial'",
        "trials_total": len(config.cells) * config.trials,
        "columns": row_columns(config.fidelity),
        "parameter_columns": parameter_columns(config.fidelity),
        "parameters": {p.name: p.doc for p in PARAMETERS.values() if config.fidelity in p.fidelities},
        "units": "errors, sigmas and CRB: root-sum-square over the 3 axes; mm and degrees; time_s seconds",
        "software": _software(),
    }


def _same_config(stored: dict, config: SweepConfig, out_dir: Path) -> None:
    """Raise SweepError naming the first field where the folder's sweep differs from config."""
    new = json.loads(json.dumps(config.to_dict()))
    old = stored.get("config", {})
    for key in new.keys() - {"scenario_base_dir"}:  # the files may have moved; their content may not
        if old.get(key) != new[key]:
            raise SweepError(
                f"{out_dir / META_FILE}: field 'config.{key}' differs from {config.path}; this folder holds "
                "another sweep: choose another --out"
            )


def prepare_out_dir(config: SweepConfig, out_dir: Path, resume: bool) -> set[str]:
    """Create the folder and sweep.json, or check them on --resume. Returns the trial ids already done."""
    meta_path = out_dir / META_FILE
    if meta_path.exists():
        if not resume:
            raise SweepError(
                f"{out_dir} already holds a sweep ({META_FILE}); pass --resume to finish it, "
                "or choose another --out"
            )
        stored = read_json_object(meta_path, SweepError)
        _same_config(stored, config, out_dir)
        before, now = stored.get("software", {}), _software()
        changed = [f"{k} {before.get(k)} -> {now.get(k)}" for k in now if before.get(k) != now.get(k)]
        if changed:
            print(
                f"note: software differs from {meta_path} ({'; '.join(changed)}): new trials may not match "
                "the earlier ones bit for bit",
                file=sys.stderr,
            )
        rows = _compact(out_dir, row_columns(config.fidelity), config.methods)
        return {r["trial_id"] for r in rows}
    if out_dir.exists() and not out_dir.is_dir():
        raise SweepError(f"{out_dir}: exists and is not a folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    if (out_dir / ROWS_FILE).exists():
        raise SweepError(f"{out_dir / ROWS_FILE} exists without {META_FILE}; choose another --out")
    write_atomic(meta_path, json.dumps(_metadata(config), indent=1, allow_nan=False) + "\n")
    (out_dir / ROWS_FILE).write_text(",".join(row_columns(config.fidelity)) + "\n")
    return set()


# ------------------------------------------------------------------ execution


def _cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _ignore_sigint() -> None:
    """Worker start: Ctrl-C is the parent's to handle (it stops the workers)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _local_pool(workers: int) -> ProcessPoolExecutor:
    """Fresh (spawned) processes with one BLAS thread each: set before they import numpy."""
    os.environ.update(BLAS_ENV)
    return ProcessPoolExecutor(
        workers, mp_context=multiprocessing.get_context("spawn"), initializer=_ignore_sigint
    )


def _run_pool(tasks: list[TrialTask], workers: int, on_rows: Callable, on_error: Callable) -> list[TrialTask]:
    """Run tasks on a fresh pool. Returns the tasks left unfinished when a worker died (else [])."""
    pool = _local_pool(workers)
    try:
        pending = {pool.submit(run_trial, t): t for t in tasks}
        broken: list[TrialTask] = []
        while pending and not broken:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                task = pending.pop(future)
                try:
                    rows = future.result()
                except BrokenProcessPool:  # a worker died (killed, out of memory, a crash in native code)
                    broken.append(task)
                    continue
                except Exception as exc:  # noqa: BLE001  (a bug in the trial: report it, go on)
                    on_error(task, f"{type(exc).__name__}: {exc}")
                    continue
                on_rows(rows)
        broken.extend(pending.values())
    except BaseException:
        for process in list(getattr(pool, "_processes", {}).values()):
            process.terminate()  # our own workers: a Ctrl-C must not wait for running trials
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=not broken, cancel_futures=True)
    return sorted(broken, key=lambda t: (t.cell_index, t.trial))


def _run_local(tasks: list[TrialTask], workers: int, on_rows: Callable, on_error: Callable) -> None:
    """Run on local processes. When a worker dies, the unfinished trials go to a new pool, at most
    POOL_RESTARTS times; then they are reported lost (--resume runs them later)."""
    for restart in range(POOL_RESTARTS + 1):
        tasks = _run_pool(tasks, workers, on_rows, on_error)
        if not tasks:
            return
        again = (
            f"; restarting the workers ({restart + 1} of {POOL_RESTARTS})" if restart < POOL_RESTARTS else ""
        )
        tqdm.write(f"a worker process died with {len(tasks)} trials unfinished{again}", file=sys.stderr)
    for task in tasks:
        on_error(task, "worker processes kept dying", say=False)


def _dask_client(scheduler: str) -> Any:
    """A distributed.Client connected to the scheduler (before anything is written)."""
    try:
        from distributed import Client
    except ImportError:
        raise SweepError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
    try:
        return Client(scheduler, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise SweepError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None


def _run_dask(tasks: list[TrialTask], client: Any, on_rows: Callable, on_error: Callable) -> None:
    """Run on the client's cluster (its workers retry a trial whose worker died; then it is lost)."""
    from distributed import as_completed

    futures = client.map(run_trial, tasks, pure=False)
    task_of = {f.key: t for f, t in zip(futures, tasks, strict=True)}
    try:
        for future in as_completed(futures):
            try:
                rows = future.result()
            except Exception as exc:  # noqa: BLE001  (a killed worker, an error in the trial)
                on_error(task_of[future.key], f"{type(exc).__name__}: {exc}")
                continue
            on_rows(rows)
            future.release()
    finally:
        with contextlib.suppress(Exception):
            client.cancel(futures)


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (a batch system stopping the job) stops the sweep as Ctrl-C does."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@dataclass
class SweepOutcome:
    """What a run did: trials computed now, skipped as already done, lost (trial id, error)."""

    computed: int = 0
    skipped: int = 0
    lost: list[tuple[str, str]] = field(default_factory=list)
    failed_runs: int = 0
    seconds: float = 0.0


def run_sweep(
    config: SweepConfig,
    out_dir: Path,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    keep_datasets: bool = False,
    progress: bool = True,
) -> SweepOutcome:
    """Run every trial not yet in out_dir/rows.csv, appending each trial's rows as it arrives.
    KeyboardInterrupt propagates after the finished trials are on disk."""
    out_dir = Path(out_dir)
    client = _dask_client(scheduler) if scheduler else None
    try:
        return _run_sweep(config, out_dir, client, workers, resume, keep_datasets, progress)
    finally:
        if client is not None:
            client.close()


def _run_sweep(
    config: SweepConfig,
    out_dir: Path,
    client: Any,
    workers: int | None,
    resume: bool,
    keep_datasets: bool,
    progress: bool,
) -> SweepOutcome:
    """run_sweep once connected: prepare the folder, run what is not done, compact the rows."""
    done = prepare_out_dir(config, out_dir, resume)
    keep = out_dir / DATASETS_DIR if keep_datasets and config.fidelity == RENDER else None
    if keep is not None:
        keep.mkdir(exist_ok=True)
    example = out_dir / EXAMPLE_DIR if config.fidelity == RENDER else None
    tasks = [t for t in tasks_for(config, keep, example) if t.trial_id not in done]
    outcome = SweepOutcome(skipped=len(done))
    columns = row_columns(config.fidelity)
    start = time.perf_counter()
    bar = tqdm(
        total=len(done) + len(tasks),
        initial=len(done),
        desc="sweep",
        unit="trial",
        disable=not progress,
        file=sys.stderr,
        smoothing=0.05,
    )
    with open(out_dir / ROWS_FILE, "a", newline="") as rows_file, bar:

        def on_rows(rows: list[dict]) -> None:
            rows_file.write(format_rows(rows, columns))
            rows_file.flush()
            outcome.computed += 1
            outcome.failed_runs += sum(r["status"] != "ok" for r in rows)
            bar.update()
            if outcome.failed_runs:
                bar.set_postfix_str(f"{outcome.failed_runs} failed method runs", refresh=False)

        def on_error(task: TrialTask, message: str, say: bool = True) -> None:
            outcome.lost.append((task.trial_id, _one_line(message)))
            if say:
                tqdm.write(f"trial {task.trial_id} did not finish: {outcome.lost[-1][1]}", file=sys.stderr)

        with _terminate_as_interrupt():
            if tasks and client is not None:
                _run_dask(tasks, client, on_rows, on_error)
            elif tasks:
                _run_local(tasks, workers or _cores(), on_rows, on_error)
    outcome.seconds = time.perf_counter() - start
    if not outcome.lost:
        _compact(out_dir, columns, config.methods)
    return outcome


def parse_trial_id(config: SweepConfig, text: str) -> tuple[int, int]:
    """(cell index, trial) of a trial id such as 'c03-t0042'; SweepError if not in this sweep."""
    match = TRIAL_ID.match(text.strip())
    if not match:
        raise SweepError(f"trial id {text!r}: expected the form c03-t0042 (cell 3, trial 42)")
    cell, trial = int(match[1]), int(match[2])
    if cell >= len(config.cells) or trial >= config.trials:
        raise SweepError(
            f"trial id {text!r}: {config.path} has cells c00..c{len(config.cells) - 1:02d} and trials "
            f"t0000..t{config.trials - 1:04d}"
        )
    return cell, trial


def rerun_trial(config: SweepConfig, text: str, keep_dir: Path | None = None) -> list[dict]:
    """Run one trial again, alone, in a fresh worker process like the sweep's."""
    cell, trial = parse_trial_id(config, text)
    task = tasks_for(config, keep_dir)[cell * config.trials + trial]
    with _local_pool(1) as pool:
        return pool.submit(run_trial, task).result()


def same_rows(a: list[dict], b: list[dict], ignore: tuple[str, ...] = ("time_s",)) -> list[str]:
    """Differences between two row lists ('trial method: column a != b'), NaN equal to NaN."""
    if len(a) != len(b):
        return [f"{len(a)} rows != {len(b)} rows"]
    out = []
    for x, y in zip(a, b, strict=True):
        for key in x.keys() | y.keys():
            u, v = x.get(key), y.get(key)
            if (
                key in ignore
                or u == v
                or (isinstance(u, float) and isinstance(v, float) and u != u and v != v)
            ):
                continue
            out.append(f"{x.get('trial_id')} {x.get('method')}: {key} {u!r} != {v!r}")
    return out


# ------------------------------------------------------------------ command line


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add `hec sweep`."""
    p = sub.add_parser(
        "sweep",
        help="run a grid of calibration trials (Monte-Carlo) from a sweep TOML file",
        description="Run a reproducible grid of calibration trials: every cell of the sweep file's grid, "
        "`trials` times, every method. Rows go to DIR/rows.csv as trials finish (DIR/sweep.json first).",
    )
    p.add_argument(
        "config", type=Path, metavar="CONFIG", help="sweep TOML file (e.g. models/sweeps/noise.toml)"
    )
    p.add_argument(
        "--out", required=True, type=Path, metavar="DIR", help="output folder (sweep.json, rows.csv)"
    )
    p.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: every core)")
    p.add_argument(
        "--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask distributed scheduler instead"
    )
    p.add_argument("--resume", action="store_true", help="continue a sweep in --out: skip the trials done")
    p.add_argument(
        "--rerun",
        metavar="TRIAL_ID",
        help="run one trial (e.g. c03-t0042) again, print its rows and compare them with --out's",
    )
    p.add_argument(
        "--keep-datasets",
        action="store_true",
        help="render fidelity: keep each trial's dataset in DIR/datasets/TRIAL_ID (default: deleted)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _print_rows(rows: list[dict]) -> None:
    for r in rows:
        if r["status"] == "ok":
            print(
                f"  {r['method']:18s} {r['error_translation_mm']:9.4f} mm {r['error_rotation_deg']:9.5f} deg"
                f"  sigma {r['sigma_translation_mm']:8.4f} mm {r['sigma_rotation_deg']:8.5f} deg  "
                f"NEES {r['nees']:7.2f}"
            )
        else:
            print(f"  {r['method']:18s} failed: {r['failure']}")


def _summary(rows: list[dict], config: SweepConfig, most: int = 30) -> None:
    """Median translation error (mm) per cell and method, for the first `most` cells."""
    errors: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        if r["status"] == "ok":
            errors.setdefault((r["cell"], r["method"]), []).append(r["error_translation_mm"])
    swept, methods = config.swept, config.methods
    print("median translation error [mm] per cell (failed runs left out); `hec report` for the full report")
    print(
        f"{'cell':5s} {' '.join(f'{s[:14]:>14s}' for s in swept)} "
        + " ".join(f"{m.removeprefix('opencv-')[:9]:>9s}" for m in methods)
    )
    for cell in config.cells[:most]:
        values = [errors.get((cell.id, m)) for m in methods]
        params = " ".join(f"{str(cell.parameters[s])[:14]:>14s}" for s in swept)
        print(
            f"{cell.id:5s} {params} "
            + " ".join(f"{np.median(e):9.3f}" if e else f"{'-':>9s}" for e in values)
        )
    if len(config.cells) > most:
        print(f"... and {len(config.cells) - most} more cells")


def run(args: argparse.Namespace) -> int:
    """`hec sweep`. Returns 0 when every trial is done, 1 when some were lost, 2 on bad input, 130 on
    Ctrl-C."""
    config, out_dir = None, Path(args.out)
    try:
        config = load_config(args.config)
        if args.rerun:
            meta = out_dir / META_FILE
            if meta.exists():
                _same_config(read_json_object(meta, SweepError), config, out_dir)
            keep = out_dir / DATASETS_DIR if args.keep_datasets else None
            if keep is not None:
                keep.mkdir(parents=True, exist_ok=True)
            rows = rerun_trial(config, args.rerun, keep)
            print(f"trial {args.rerun} (seed {rows[0]['seed']}), {config.fidelity}:")
            _print_rows(rows)
            stored = (
                [r for r in load_rows(out_dir) if r["trial_id"] == rows[0]["trial_id"]]
                if meta.exists()
                else []
            )
            if not stored:
                print("no stored rows of this trial to compare with")
                return 0
            differences = same_rows(rows, stored)
            print(
                f"identical to {out_dir / ROWS_FILE} (time_s aside)"
                if not differences
                else "DIFFERS from the stored rows:\n  " + "\n  ".join(differences)
            )
            return 0 if not differences else 1
        if args.workers is not None and args.workers < 1:
            raise SweepError(f"--workers must be >= 1, got {args.workers}")
        total = len(config.cells) * config.trials
        where = (
            f"Dask scheduler {args.scheduler}" if args.scheduler else f"{args.workers or _cores()} processes"
        )
        print(
            f"sweep {config.path}: {len(config.cells)} cells x {config.trials} trials = {total} trials, "
            f"{len(config.methods)} methods, {config.fidelity} fidelity, on {where}",
            file=sys.stderr,
        )
        outcome = run_sweep(
            config, out_dir, args.workers, args.scheduler, args.resume, args.keep_datasets, not args.quiet
        )
    except (SweepConfigError, SweepError) as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        methods = config.methods if config is not None else None
        done = len({r["trial_id"] for r in _read_rows(out_dir / ROWS_FILE, methods)})
        print(
            f"\ninterrupted: {done} finished trials are in {out_dir / ROWS_FILE}; "
            "continue with the same command and --resume",
            file=sys.stderr,
        )
        return 130
    rows = load_rows(out_dir)
    print(
        f"{outcome.computed} trials run in {outcome.seconds:.1f} s ({outcome.skipped} already done), "
        f"{outcome.failed_runs} failed method runs; {len(rows)} rows in {out_dir / ROWS_FILE}"
    )
    _summary(rows, config)
    if not outcome.lost:
        from experiments.report import ReportError, build_report

        try:
            print(f"report: {build_report(out_dir, rows).html}")
        except ReportError as exc:
            print(f"hec: no report: {exc}", file=sys.stderr)
    if outcome.lost:
        print(
            f"{len(outcome.lost)} trials did not finish (first: {outcome.lost[0][0]}: {outcome.lost[0][1]}); "
            "run again with --resume",
            file=sys.stderr,
        )
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point (`python -m experiments.sweep CONFIG --out DIR`)."""
    parser = argparse.ArgumentParser(prog="hec")
    add_parser(parser.add_subparsers(dest="command", required=True))
    return run(parser.parse_args(["sweep", *(sys.argv[1:] if argv is None else argv)]))


if __name__ == "__main__":
    raise SystemExit(main())
