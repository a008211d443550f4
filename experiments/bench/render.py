"""Benchmark: time to simulate one waypoint at 640x480, the default (ideal) scenario beside the realistic
one (models/scenarios/realistic.toml, every model error on).

Run: .venv/bin/python -m hec.bench.render [--rounds N]
Prints the median and 90th percentile per part over the default trajectory for each scenario: IK +
checks, the RGB + depth render, the real camera (lens, depth misregistration, flying pixels, holes,
image effects; nothing for the ideal cell) and the sensor noise; then realistic / default per part
and total / render per scenario, in wall time and in CPU time (the process's, all its threads: Mesa's
llvmpipe renders on several, OpenCV runs some passes on several; what a sweep with a worker per core
pays). waypoint_times gives the medians to other benchmarks.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import hec.sim as sim  # noqa: F401  (chooses the GL backend before mujoco is imported)
from hec.estimator.common.models import models_dir
from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import WaypointRejected
from hec.sim.cell import SimCell
from hec.sim.noise import apply_depth_models, apply_rgb_models
from hec.sim.scenario import Scenario, load_scenario
from hec.sim.simulate import scenario_waypoints

PARTS = ("ik+checks", "render", "real camera", "noise", "total")
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def _now() -> np.ndarray:
    """(2,) seconds on the wall and the process's CPU clock (CLOCKS' order)."""
    return np.array([clock() for clock in CLOCKS.values()])


def time_pass(cell: SimCell, times: dict[str, dict[str, list[float]]]) -> None:
    """One pass over the cell's trajectory: milliseconds per clock (CLOCKS) and part (PARTS) of every
    captured waypoint appended to times[clock][part], the steps of SimCell.capture timed apart."""
    camera, noise, rng = cell.camera, cell.scenario.noise, cell.rng
    for waypoint in scenario_waypoints(cell.scenario):
        t0 = _now()
        try:
            cell.move_to(waypoint)
        except WaypointRejected:
            continue
        t1 = _now()
        rgb, depth = cell.render_true()
        t2 = _now()
        T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
        rgb, depth = camera.view(rgb, depth, rng)
        rgb = camera.light(rgb, T_cam_board, rng)
        t3 = _now()
        apply_rgb_models(rgb, noise.rgb, rng)
        depth = apply_depth_models(depth, camera.intrinsics, noise, rng, camera.depth_correlation_px())
        cell.flange_pose()
        t4 = _now()
        camera.holes(depth, rng)  # a real-camera effect, applied after the noise
        t5 = _now()
        parts = (t1 - t0, t2 - t1, t3 - t2 + t5 - t4, t4 - t3, t5 - t0)
        for name, seconds in zip(PARTS, parts, strict=True):
            for clock, dt in zip(CLOCKS, seconds, strict=True):
                times[clock][name].append(dt * 1000)


def scenarios() -> dict[str, Scenario]:
    """The benchmarked scenarios: the default (ideal) cell and the realistic one."""
    return {
        "default": Scenario(),
        "realistic": load_scenario(models_dir() / "scenarios" / "realistic.toml"),
    }


def time_waypoints(rounds: int) -> dict[str, dict[str, dict[str, list[float]]]]:
    """Milliseconds of every captured waypoint per scenario (see scenarios), clock (CLOCKS) and part
    (PARTS), over rounds passes of the trajectory that alternate between the scenarios."""
    cells = {name: SimCell(s, np.random.default_rng(0)) for name, s in scenarios().items()}
    results = {name: {clock: {part: [] for part in PARTS} for clock in CLOCKS} for name in cells}
    for cell in cells.values():
        cell.render_true()  # warm-up: GL context and texture upload
    for _ in range(rounds):  # alternating, so that a change in the machine's load hits both alike
        for name, cell in cells.items():
            time_pass(cell, results[name])
    for cell in cells.values():
        cell.close()
    return results


def waypoint_times(rounds: int) -> dict[str, dict[str, dict[str, float]]]:
    """Median milliseconds per waypoint, per scenario ("default", "realistic"), clock (CLOCKS) and
    part (PARTS), over rounds passes of the trajectory; e.g. ["default"]["cpu"]["render"]."""
    return {
        name: {
            clock: {part: float(np.median(t)) for part, t in parts.items()} for clock, parts in clocks.items()
        }
        for name, clocks in time_waypoints(rounds).items()
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="passes over the default trajectory")
    args = parser.parse_args(argv)
    results = time_waypoints(args.rounds)
    k = Scenario().camera
    views = ", ".join(f"{name} {len(r['wall']['total'])}" for name, r in results.items())
    for clock in CLOCKS:
        print(f"{clock} ms per waypoint at {k.width}x{k.height} ({views} waypoints), median (p90):")
        print(f"  {'part':12s}{'default':>16s}{'realistic':>16s}   realistic / default")
        for part in PARTS:
            d, r = results["default"][clock][part], results["realistic"][clock][part]
            ratio = f"{np.median(r) / np.median(d):5.2f}x" if np.median(d) >= 1.0 else "    -"
            print(f"  {part:12s}{_cell(d)}{_cell(r)}   {ratio}")
        ratios = ", ".join(
            f"{name} {np.median(r[clock]['total']) / np.median(r[clock]['render']):.2f}x"
            for name, r in results.items()
        )
        print(f"  total / render: {ratios}")


def _cell(times_ms: list[float]) -> str:
    return f"{np.median(times_ms):8.1f} ({np.percentile(times_ms, 90):5.1f})"


if __name__ == "__main__":
    main()
