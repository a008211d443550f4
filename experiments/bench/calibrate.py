"""Benchmark: how long `hec calibrate` takes, side by side in one run, on the 17-frame datasets of the
ideal (default) and the realistic cell: the default method (noise learning, self-calibration and the
leave-one-frame-out folds included), --method all, and OpenCV Park's whole pipeline (PnP, the hand-eye
solve, its folds) on the same frames. Detection is done once beforehand and not counted.

Run: .venv/bin/python -m hec.bench.calibrate [--seed 0] [--rounds 1]
Prints per dataset and command the wall and CPU seconds (the median over the rounds) beside the goal.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import statistics
import tempfile
import time
from pathlib import Path

from hec.commands.calibrate import CalibrateSettings, calibrate_dataset
from hec.estimator.io.dataset import load_dataset
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.sim.scenario import load_scenario
from hec.sim.simulate import simulate
from hec.support.detection import cached_or_detected

SCENARIOS = (("ideal", None), ("realistic", "realistic"))
COMMANDS = ((DEFAULT_METHOD, "default"), ("all", "--method all"), ("opencv-park", "OpenCV Park"))
GOALS_S = {("realistic", DEFAULT_METHOD): 3.0, ("realistic", "all"): 20.0, ("ideal", "all"): 20.0}


def time_calibration(dataset: Path, method: str) -> tuple[float, float]:
    """(wall, CPU) seconds of `hec calibrate DATASET --method METHOD --quiet`, its printing silenced."""
    wall, cpu = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        calibrate_dataset(dataset, CalibrateSettings(method=method), quiet=True)
    return time.perf_counter() - wall, time.process_time() - cpu


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="the datasets' seed (default %(default)s)")
    parser.add_argument("--rounds", type=int, default=1, help="timings per command; the median is shown")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as root:
        print(f"{'dataset':10} {'command':14} {'wall s':>8} {'CPU s':>8}  goal")
        for name, scenario in SCENARIOS:
            dataset = simulate(load_scenario(scenario), Path(root) / name, args.seed, progress=False).out_dir
            cached_or_detected(load_dataset(dataset), quiet=True)  # detection is not timed
            for method, label in COMMANDS:
                times = [time_calibration(dataset, method) for _ in range(args.rounds)]
                wall, cpu = (statistics.median(t[i] for t in times) for i in (0, 1))
                goal = GOALS_S.get((name, method))
                verdict = "" if goal is None else f"<= {goal:g} s: {'met' if cpu <= goal else 'not met'}"
                print(f"{name:10} {label:14} {wall:8.2f} {cpu:8.2f}  {verdict}", flush=True)


if __name__ == "__main__":
    main()
