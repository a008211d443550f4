"""Benchmark: how long `hec calibrate` takes, side by side in one run, on the 17-frame datasets of the
ideal (default) and the realistic cell: the default method (noise learning, self-calibration and the
leave-one-frame-out folds included), --method all, and OpenCV Park's whole pipeline (PnP, the hand-eye
solve, its folds) on the same frames. Detection is done once beforehand and not counted.

Run: .venv/bin/python -m hec.bench.calibrate [--seed 0] [--rounds 1] [--page PATH.md]
Prints per dataset and command the wall and CPU seconds (the median over the rounds) beside the goal;
--page also writes the table as a documentation page.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from hec.commands.calibrate import CalibrateSettings, calibrate_dataset
from hec.estimator.io.dataset import load_dataset
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.problem import CalibrationInputError
from hec.sim.scenario import load_scenario
from hec.sim.simulate import simulate
from hec.support.detection import cached_or_detected
from hec.support.results_page import markdown_table, write_results_page

# "unexplained": the realistic frames with each robot state shifted one frame on (no mount fits).
SCENARIOS = (("ideal", None), ("realistic", "realistic"), ("unexplained", "realistic"))
COMMANDS = ((DEFAULT_METHOD, "default"), ("all", "--method all"), ("opencv-park", "OpenCV Park"))
GOALS_S = {
    ("realistic", DEFAULT_METHOD): 3.0,
    ("realistic", "all"): 20.0,
    ("ideal", "all"): 20.0,
    ("unexplained", DEFAULT_METHOD): 10.0,
}


def time_calibration(dataset: Path, method: str) -> tuple[float, float]:
    """(wall, CPU) seconds of `hec calibrate DATASET --method METHOD --quiet`, its printing silenced.
    A calibration that refuses the data (CalibrationInputError) is timed to its refusal."""
    wall, cpu = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        with contextlib.suppress(CalibrationInputError):
            calibrate_dataset(dataset, CalibrateSettings(method=method), quiet=True)
    return time.perf_counter() - wall, time.process_time() - cpu


def unexplained_copy(dataset: Path, out: Path) -> Path:
    """A copy of dataset whose robot states (pose and joints) are shifted one frame on: no mount
    explains its images, and calibrate must say so quickly."""
    shutil.copytree(dataset, out)
    with open(out / "frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    robot = [k for k in rows[0] if k not in ("frame", "time_s", "rgb", "depth")]
    states = [{k: row[k] for k in robot} for row in rows]
    for row, state in zip(rows, states[1:] + states[:1], strict=True):
        row.update(state)
    with open(out / "frames.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="the datasets' seed (default %(default)s)")
    parser.add_argument("--rounds", type=int, default=1, help="timings per command; the median is shown")
    parser.add_argument("--page", type=Path, help="also write the table as this Markdown page")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as root:
        print(f"{'dataset':10} {'command':14} {'wall s':>8} {'CPU s':>8}  goal")
        for name, scenario in SCENARIOS:
            dataset = simulate(load_scenario(scenario), Path(root) / name, args.seed, progress=False).out_dir
            commands = COMMANDS
            if name == "unexplained":
                dataset, commands = unexplained_copy(dataset, Path(root) / "shifted"), COMMANDS[:1]
            cached_or_detected(load_dataset(dataset), quiet=True)  # detection is not timed
            for method, label in commands:
                times = [time_calibration(dataset, method) for _ in range(args.rounds)]
                wall, cpu = (statistics.median(t[i] for t in times) for i in (0, 1))
                goal = GOALS_S.get((name, method))
                verdict = "" if goal is None else f"<= {goal:g} s: {'met' if cpu <= goal else 'not met'}"
                print(f"{name:10} {label:14} {wall:8.2f} {cpu:8.2f}  {verdict}", flush=True)
                rows.append([name, label, f"{wall:.2f}", f"{cpu:.2f}", verdict or "-"])
    if args.page:
        _write_page(args, rows)


def _write_page(args: argparse.Namespace, rows: list[list[str]]) -> None:
    command = f"python -m hec.bench.calibrate --seed {args.seed} --rounds {args.rounds} --page {args.page}"
    intro = (
        f"`hec calibrate` on the 17-frame datasets of seed {args.seed}, detection done beforehand and"
        f" not counted; the median of {args.rounds} timing(s) per command. The goals are on CPU time"
        " (one core: what a user's machine or a sweep worker pays)."
    )
    table = markdown_table(["dataset", "command", "wall s", "CPU s", "goal"], rows)
    write_results_page(args.page, "Speed of one calibration", command, [intro, table])


if __name__ == "__main__":
    main()
