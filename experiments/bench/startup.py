"""Benchmark: how long the command line takes to answer before it does any work.

Prints the median wall time of `python -c pass` (the interpreter alone) and of `hec --help`,
`hec --version`, `hec export --help` and `hec calibrate --help`, each run --runs times in turn in
one run of this benchmark (a busy machine slows them alike). The goal is 0.3 s for the first three.

    python -m hec.bench.startup [--runs 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "hec --help": [sys.executable, "-m", "hec", "--help"],
    "hec --version": [sys.executable, "-m", "hec", "--version"],
    "hec export --help": [sys.executable, "-m", "hec", "export", "--help"],
    "hec calibrate --help": [sys.executable, "-m", "hec", "calibrate", "--help"],
}
GOAL_S = 0.3


def startup_times(runs: int) -> dict[str, list[float]]:
    """Wall seconds of each command, runs times each, the commands taking turns."""
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    for _ in range(runs):
        for name, argv in COMMANDS.items():
            start = time.perf_counter()
            subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
            times[name].append(time.perf_counter() - start)
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="runs of each command (default %(default)s)")
    args = parser.parse_args(argv)
    print(f"{'command':24s} {'median s':>9s} {'min s':>7s} {'max s':>7s}")
    for name, seconds in startup_times(args.runs).items():
        median = statistics.median(seconds)
        mark = (
            "" if name.startswith(("python", "hec calibrate")) else (" ok" if median <= GOAL_S else " SLOW")
        )
        print(f"{name:24s} {median:9.3f} {min(seconds):7.3f} {max(seconds):7.3f}{mark}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
