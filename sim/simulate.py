"""Render a scenario into a dataset: move, check, capture and write each waypoint."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import (
    Waypoint,
    WaypointRejected,
    eye_to_hand_waypoints,
    look_at_board,
    paper_waypoints,
    read_waypoint_file,
    rotation_rich_waypoints,
    translated_waypoints,
)
from hec.estimator.io.dataset import DatasetWriter
from hec.estimator.io.memory import dataset_in_memory
from hec.estimator.observe.frames import Dataset, Frame, GroundTruth
from hec.sim.cell import MIN_MODULE_PX, SimCell
from hec.sim.compiled import first_compile_note
from hec.sim.noise import depth_noise_model, robot_pose_noise_model, waypoint_rng
from hec.sim.preview import write_preview
from hec.sim.scenario import Scenario


class SimulationError(RuntimeError):
    """A simulation produced nothing usable."""


@dataclass
class SimulationResult:
    out_dir: Path
    frames: int
    skipped: list[tuple[int, str]] = field(default_factory=list)
    preview_files: list[Path] = field(default_factory=list)


def scenario_waypoints(scenario: Scenario) -> list[Waypoint]:
    """The scenario's trajectory as waypoints."""
    kind = scenario.trajectory.kind
    if kind == "file":
        return read_waypoint_file(scenario.waypoint_file())
    distance_m = scenario.trajectory.distance_m
    if not scenario.eye_to_hand:
        make = paper_waypoints if kind == "paper" else rotation_rich_waypoints
        return make(scenario.board.transform(), scenario.mount.transform(), distance_m)
    T_base_cam, T_flange_board = scenario.stand.transform(), scenario.board_mount.transform()
    if kind == "paper":
        head_on = T_base_cam @ invert(look_at_board(0, 0, 0, distance_m)) @ invert(T_flange_board)
        return translated_waypoints(head_on)
    return eye_to_hand_waypoints(T_base_cam, T_flange_board, distance_m)


def simulation_metadata(scenario: Scenario, seed: int, noise_seed: int) -> dict:
    """dataset.json fields of a simulated dataset: the noise the estimators should assume
    and what produced it (seed: the true cell's; noise_seed: each frame's noise); an eye-to-hand
    cell's 'setup'."""
    setup = {"setup": scenario.setup} if scenario.eye_to_hand else {}
    return {
        **setup,
        "depth_noise": depth_noise_model(scenario.noise).to_dict(),
        "robot_pose_noise": robot_pose_noise_model(scenario.noise).to_dict(),
        "simulation": {"seed": seed, "scenario": scenario.to_dict(), "noise_seed": noise_seed},
    }


def _warn_small_markers(module_px: list[float]) -> None:
    """Say so on stderr when frames show the markers too small to decode (hec.sim.cell.MIN_MODULE_PX)."""
    small = [px for px in module_px if px < MIN_MODULE_PX]
    if small:
        tqdm.write(
            f"warning: in {len(small)} of {len(module_px)} frames the markers are too small to decode: a QR "
            f"module (or tag bit) is {min(small):.2g} px wide (at least {MIN_MODULE_PX:g} px needed); move "
            "the views "
            "closer to the board or narrow the camera's field of view (camera.fovy_deg)",
            file=sys.stderr,
        )


def _captures(
    cell: SimCell,
    waypoints: list[Waypoint],
    noise_seed: int,
    truth: GroundTruth,
    skipped: list[tuple[int, str]],
    progress: bool,
) -> Iterator[Frame]:
    """Move to each waypoint and capture it with waypoint_rng(noise_seed, index): its frame, its
    truth appended to truth. A waypoint the cell rejects is said on stderr and appended to skipped
    (index, reason). Warns at the end when the markers were too small to decode."""
    module_px: list[float] = []
    for waypoint in tqdm(waypoints, desc="rendering", unit="view", disable=not progress, file=sys.stderr):
        try:
            cell.move_to(waypoint)
        except WaypointRejected as rejected:
            skipped.append((waypoint.index, rejected.reason))
            tqdm.write(
                f"waypoint {waypoint.index} ({waypoint.label}) skipped: {rejected.reason}", file=sys.stderr
            )
            continue
        module_px.append(cell.smallest_module_px())
        frame, frame_truth = cell.capture(waypoint_rng(noise_seed, waypoint.index))
        truth.T_base_flange.append(frame_truth.T_base_flange)
        truth.joints.append(frame_truth.joints)
        yield frame
    _warn_small_markers(module_px)


def _simulation_extra(scenario: Scenario, seed: int, noise_seed: int, waypoints: int, skipped: list) -> dict:
    """dataset.json fields of a simulation (simulation_metadata) with its waypoints and skips."""
    extra = simulation_metadata(scenario, seed, noise_seed)
    extra["simulation"] |= {
        "waypoints": waypoints,
        "skipped_waypoints": [{"index": i, "reason": r} for i, r in skipped],
    }
    return extra


def simulate(
    scenario: Scenario,
    out_dir: str | Path,
    seed: int,
    force: bool = False,
    preview: bool = False,
    progress: bool = True,
    noise_seed: int | None = None,
) -> SimulationResult:
    """Render every reachable waypoint of the scenario into a dataset at out_dir.

    Waypoints that cannot be used are skipped, reported on stderr and listed
    in dataset.json with their reason. ``seed`` drives every noise model: the true cell (its model
    errors: the arm's kinematics, the lens, the printed board) from default_rng(seed), each capture
    from hec.sim.noise.waypoint_rng(noise_seed, waypoint index), noise_seed default seed (another one: the
    same cell, new noise in every frame).
    """
    if Path(out_dir).exists() and not Path(out_dir).is_dir():  # --force replaces a dataset, not a file
        raise FileExistsError(f"{out_dir} is a file, not a dataset folder; it is not replaced")
    waypoints = scenario_waypoints(scenario)
    noise_seed = seed if noise_seed is None else noise_seed
    cell = SimCell(scenario, np.random.default_rng(seed))
    truth = cell.ground_truth()
    skipped: list[tuple[int, str]] = []
    frame_rgb: list[np.ndarray] = []
    if progress and (note := first_compile_note()) is not None:
        print(note, file=sys.stderr)
    try:
        with DatasetWriter(
            out_dir,
            cell.intrinsics,
            cell.board,
            scenario.noise.depth_quantisation.depth_scale_m,
            source="sim",
            force=force,
        ) as writer:
            for partial in writer.removed:
                print(f"note: removed {partial}, left behind by a run that was killed", file=sys.stderr)
            for frame in _captures(cell, waypoints, noise_seed, truth, skipped, progress):
                writer.add_frame(frame)
                frame_rgb.append(frame.rgb)
            if not frame_rgb:
                raise SimulationError("no waypoint could be used; see the reasons above")
            preview_files = write_preview(cell, frame_rgb, writer.tmp_dir / "preview") if preview else []
            extra = _simulation_extra(scenario, seed, noise_seed, len(waypoints), skipped)
            final = writer.finish(truth, extra)
    finally:
        cell.close()
    return SimulationResult(
        final, len(frame_rgb), skipped, [final / "preview" / p.name for p in preview_files]
    )


def simulate_in_memory(
    scenario: Scenario, seed: int, noise_seed: int | None = None, name: str = "simulation"
) -> Dataset:
    """What simulate(scenario, folder, seed, noise_seed=noise_seed) writes, as load_dataset would read
    it back, without writing anything (hec.estimator.io.memory); no progress bar or preview. Skipped
    waypoints are said on stderr and listed as in a written dataset. name: what messages call it."""
    waypoints = scenario_waypoints(scenario)
    noise_seed = seed if noise_seed is None else noise_seed
    cell = SimCell(scenario, np.random.default_rng(seed))
    truth = cell.ground_truth()
    skipped: list[tuple[int, str]] = []
    try:
        frames = list(_captures(cell, waypoints, noise_seed, truth, skipped, progress=False))
    finally:
        cell.close()
    if not frames:
        raise SimulationError("no waypoint could be used; see the reasons above")
    extra = _simulation_extra(scenario, seed, noise_seed, len(waypoints), skipped)
    depth_scale_m = scenario.noise.depth_quantisation.depth_scale_m
    return dataset_in_memory(frames, cell.intrinsics, cell.board, depth_scale_m, "sim", truth, extra, name)
