"""Benchmark: time to simulate one waypoint (IK + checks, RGB + depth render, sensor noise) at 640x480.

Run: .venv/bin/python -m experiments.bench.render [--rounds N]
Prints the median and 90th percentile per stage over the default trajectory.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import sim  # noqa: F401  (chooses the GL backend before mujoco is imported)
from sim.cell import SimCell
from sim.noise import apply_depth_models, apply_rgb_models, perturb_flange_pose
from sim.scenario import Scenario
from sim.simulate import scenario_waypoints


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="passes over the default trajectory")
    args = parser.parse_args(argv)
    scenario = Scenario()
    rng = np.random.default_rng(0)
    cell = SimCell(scenario, rng)
    waypoints = scenario_waypoints(scenario)
    cell.render_true()  # warm-up: GL context and texture upload
    stages: dict[str, list[float]] = {"ik+checks": [], "render": [], "noise": [], "total": []}
    for _ in range(args.rounds):
        for waypoint in waypoints:
            t0 = time.perf_counter()
            cell.move_to(waypoint)
            t1 = time.perf_counter()
            rgb, depth = cell.render_true()
            t2 = time.perf_counter()
            apply_rgb_models(rgb, scenario.noise.rgb, rng)
            apply_depth_models(depth, cell.intrinsics, scenario.noise, rng)
            perturb_flange_pose(cell.true_flange_pose(), scenario.noise.robot_pose, rng)
            t3 = time.perf_counter()
            for name, dt in zip(stages, (t1 - t0, t2 - t1, t3 - t2, t3 - t0), strict=True):
                stages[name].append(dt * 1000)
    cell.close()
    k = cell.intrinsics
    print(f"per waypoint at {k.width}x{k.height}, {len(stages['total'])} waypoints:")
    for name, times in stages.items():
        print(f"  {name:10s} median {np.median(times):6.1f} ms   p90 {np.percentile(times, 90):6.1f} ms")


if __name__ == "__main__":
    main()
