"""Benchmark: time to simulate one waypoint at 640x480, the default (ideal) scenario beside the realistic
one (models/scenarios/realistic.toml, every model error on).

Run: .venv/bin/python -m experiments.bench.render [--rounds N]
Prints the median and 90th percentile per part over the default trajectory for each scenario: IK +
checks, the RGB + depth render, the real camera (lens, depth misregistration, flying pixels, holes,
image effects; nothing for the ideal cell) and the sensor noise; then realistic / default per part
and total / render per scenario. waypoint_times gives the medians to other benchmarks.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import sim  # noqa: F401  (chooses the GL backend before mujoco is imported)
from estimator.geometry.transforms import invert
from estimator.geometry.waypoints import WaypointRejected
from estimator.io.models import models_dir
from sim.cell import SimCell
from sim.noise import apply_depth_models, apply_rgb_models
from sim.scenario import Scenario, load_scenario
from sim.simulate import scenario_waypoints

PARTS = ("ik+checks", "render", "real camera", "noise", "total")


def time_pass(cell: SimCell, times: dict[str, list[float]]) -> None:
    """One pass over the cell's trajectory: milliseconds per part of every captured waypoint appended to
    times, the steps of SimCell.capture timed apart."""
    camera, noise, rng = cell.camera, cell.scenario.noise, cell.rng
    for waypoint in scenario_waypoints(cell.scenario):
        t0 = time.perf_counter()
        try:
            cell.move_to(waypoint)
        except WaypointRejected:
            continue
        t1 = time.perf_counter()
        rgb, depth = cell.render_true()
        t2 = time.perf_counter()
        T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
        rgb, depth = camera.view(rgb, depth, rng)
        rgb = camera.light(rgb, T_cam_board, rng)
        t3 = time.perf_counter()
        apply_rgb_models(rgb, noise.rgb, rng)
        depth = apply_depth_models(depth, camera.intrinsics, noise, rng, camera.depth_correlation_px())
        cell.flange_pose()
        t4 = time.perf_counter()
        camera.holes(depth, rng)  # a real-camera effect, applied after the noise
        t5 = time.perf_counter()
        parts = (t1 - t0, t2 - t1, t3 - t2 + t5 - t4, t4 - t3, t5 - t0)
        for name, dt in zip(PARTS, parts, strict=True):
            times[name].append(dt * 1000)


def scenarios() -> dict[str, Scenario]:
    """The benchmarked scenarios: the default (ideal) cell and the realistic one."""
    return {
        "default": Scenario(),
        "realistic": load_scenario(models_dir() / "scenarios" / "realistic.toml"),
    }


def time_waypoints(rounds: int) -> dict[str, dict[str, list[float]]]:
    """Milliseconds per part (PARTS) of every captured waypoint, per scenario (see scenarios),
    over rounds passes of the trajectory that alternate between the scenarios."""
    cells = {name: SimCell(s, np.random.default_rng(0)) for name, s in scenarios().items()}
    results: dict[str, dict[str, list[float]]] = {name: {part: [] for part in PARTS} for name in cells}
    for cell in cells.values():
        cell.render_true()  # warm-up: GL context and texture upload
    for _ in range(rounds):  # alternating, so that a change in the machine's load hits both alike
        for name, cell in cells.items():
            time_pass(cell, results[name])
    for cell in cells.values():
        cell.close()
    return results


def waypoint_times(rounds: int) -> dict[str, dict[str, float]]:
    """Median milliseconds per waypoint, per scenario ("default", "realistic") and part (PARTS),
    over rounds passes of the trajectory; e.g. ["default"]["total"] / ["default"]["render"]."""
    return {
        name: {part: float(np.median(t)) for part, t in parts.items()}
        for name, parts in time_waypoints(rounds).items()
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="passes over the default trajectory")
    args = parser.parse_args(argv)
    results = time_waypoints(args.rounds)
    k = Scenario().camera
    views = ", ".join(f"{name} {len(r['total'])}" for name, r in results.items())
    print(f"ms per waypoint at {k.width}x{k.height} ({views} waypoints), median (p90):")
    print(f"  {'part':12s}{'default':>16s}{'realistic':>16s}   realistic / default")
    for part in PARTS:
        d, r = results["default"][part], results["realistic"][part]
        ratio = f"{np.median(r) / np.median(d):5.2f}x" if np.median(d) >= 1.0 else "    -"
        print(f"  {part:12s}{_cell(d)}{_cell(r)}   {ratio}")
    ratios = ", ".join(
        f"{name} {np.median(r['total']) / np.median(r['render']):.2f}x" for name, r in results.items()
    )
    print(f"  total / render: {ratios}")


def _cell(times_ms: list[float]) -> str:
    return f"{np.median(times_ms):8.1f} ({np.percentile(times_ms, 90):5.1f})"


if __name__ == "__main__":
    main()
