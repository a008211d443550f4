"""Benchmark: the Monte-Carlo speed ratios, each measured side by side in one run (absolute times on
a shared 2-core machine vary from run to run; the ratios much less).

Run: .venv/bin/python -m hec.bench.speed [--rounds 3] [--dask-trials 10000] [--page PATH.md]
Prints, with its parts and its goal:
  waypoint      a whole simulated waypoint / MuJoCo's render of it, default and realistic scenario,
                in wall time and in CPU time (hec.bench.render)
  render trial  a render-fidelity sweep trial (17 views, ekf and Park) / simulating and detecting
                its views in memory (hec.sweep.trials.render_inputs)
  estimators    ekf / OpenCV's Park with its PnP poses; batch in ms (17 views x 8 markers,
                hec.bench.estimators.time_against_park)
  workers       sweep trials per second on 2 worker processes / on 1 at both fidelities, the two
                pools taking turns (see worker_speedup), beside the same ratio for a CPU-bound
                pure-Python loop on the same pools (the machine's own ceiling: its two cores are
                not one core twice), and the largest worker's peak memory
  dask          with --dask-trials N: a measurement sweep of N trials on a local Dask cluster of 2
                workers, the memory of this process and of the workers as it runs
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hec.support.results_page import markdown_table, write_results_page
from hec.sweep.config import SweepConfig, cell_scenario, load_config
from hec.sweep.parameters import MEASUREMENTS, RENDER
from hec.sweep.trials import render_inputs, run_trial, tasks_for

TRIAL_METHODS = '["ekf", "opencv-park"]'
BUSY_LOOP_ITERATIONS, BUSY_LOOPS_PER_TURN = 3_000_000, 6
WORKER_ROUNDS = 4
# The waypoint's goal is on CPU time (what a sweep with a worker per core pays; its wall time is
# printed beside it without a goal), and the workers' goal is relative to the machine's own
# two-process ratio for a CPU-bound loop measured on the same pools in the same run.
GOALS = {
    "waypoint": 2.0,
    "render trial": 2.0,
    "ekf / park": 3.0,
    "batch ms": 100.0,
    "workers/loop": 0.95,
}


def sweep_config(
    folder: Path, fidelity: str, trials: int, seed: int, methods: str = TRIAL_METHODS
) -> SweepConfig:
    """A sweep of `trials` trials of the default cell (17 views) at the fidelity, its file in folder."""
    path = folder / f"{fidelity}.toml"
    path.write_text(f'fidelity = "{fidelity}"\nseed = {seed}\ntrials = {trials}\nmethods = {methods}\n')
    return load_config(path)


def trial_times(folder: Path, rounds: int, seed: int) -> dict[str, float]:
    """Median seconds of a render trial and of simulating and detecting its views (the same trial's
    render_inputs), over `rounds` trials."""
    tasks = tasks_for(sweep_config(folder, RENDER, rounds + 1, seed))
    run_trial(tasks[-1])  # warm-up: imports, the GL context
    trial, views = [], []
    for task in tasks[:rounds]:
        start = time.perf_counter()
        run_trial(task)
        trial.append(time.perf_counter() - start)
        rng = np.random.default_rng(task.seed_list)
        scenario = cell_scenario(task.scenario, task.base_dir, task.parameters)
        start = time.perf_counter()
        render_inputs(task, scenario, rng)
        views.append(time.perf_counter() - start)
    return {"trial": float(np.median(trial)), "views": float(np.median(views))}


def busy_loop(iterations: int) -> int:
    """The machine's reference task: pure Python arithmetic in a few KiB (no memory traffic, no
    libraries), about 0.1 s per million iterations here."""
    total = 0
    for i in range(iterations):
        total += i * i % 7
    return total


def peak_rss_mib() -> float:
    """This process's peak resident memory, MiB: Linux's VmHWM, counted from the process's exec.
    (getrusage's ru_maxrss also counts the parent's memory at the fork of a spawned worker.)"""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise OSError("/proc/self/status has no VmHWM (not Linux)")


def timed_task(work: Callable, task: Any) -> tuple[int, float, float, float]:
    """work(task) in a pool worker: the worker's pid, the start and end time.time() of the task, and
    the worker's peak memory after it (MiB)."""
    start = time.time()
    work(task)
    return os.getpid(), start, time.time(), peak_rss_mib()


def busy_rate(spans: list[tuple[int, float, float, float]], workers: int) -> float:
    """Tasks per second of a pool of workers while every worker was busy, from the spans of
    timed_task: from the last worker's first start to the first worker's last end, each task
    counted by the fraction of its time inside that window. (Counting only the tasks completed up to
    the first idle worker leaves out the others' tasks in progress: 2 workers in step on 24 tasks
    come out 4 % slow.)"""
    by_worker: dict[int, list[tuple[float, float]]] = {}
    for pid, start, end, _ in spans:
        by_worker.setdefault(pid, []).append((start, end))
    if len(by_worker) != workers:
        raise ValueError(f"{len(spans)} tasks ran on {len(by_worker)} of {workers} workers: too few")
    t0 = max(min(start for start, _ in tasks) for tasks in by_worker.values())
    t1 = min(max(end for _, end in tasks) for tasks in by_worker.values())
    if t1 <= t0:
        raise ValueError(f"{len(spans)} tasks never kept all {workers} workers busy at once: too few")
    done = sum(max(0.0, min(end, t1) - max(start, t0)) / (end - start) for _, start, end, _ in spans)
    return done / (t1 - t0)


def worker_speedup(folder: Path, fidelity: str, trials: int, seed: int) -> dict[str, float]:
    """Trials per second on 1 and on 2 local worker processes (as `hec sweep` starts them) and their
    ratio; the same ratio for busy_loop (what this machine gives two processes that share nothing:
    its two cores are not one core twice); the largest worker's peak memory, MiB.

    Both pools stay up and take turns, WORKER_ROUNDS times (the machine's speed drifts over
    minutes), after each worker's first trial (imports, GL context): per turn the next
    trials / WORKER_ROUNDS trials on 1 worker and each of them twice on 2, then BUSY_LOOPS_PER_TURN
    busy loops per worker. Rates are busy_rate's; each ratio is the 2-worker pool's mean rate over the turns
    over the 1-worker pool's."""
    from hec.sweep.runner import local_pool

    tasks = tasks_for(sweep_config(folder, fidelity, trials, seed))
    per_turn = -(-trials // WORKER_ROUNDS)
    rates: dict[tuple[str, int], list[float]] = {}
    peaks = [0.0]
    with local_pool(1) as one, local_pool(2) as two:
        pools = {1: one, 2: two}
        for workers, pool in pools.items():
            list(pool.map(run_trial, tasks[:workers]))
        for turn in range(WORKER_ROUNDS):
            chunk = tasks[turn * per_turn : (turn + 1) * per_turn]
            loops = [BUSY_LOOP_ITERATIONS] * BUSY_LOOPS_PER_TURN
            for workers, pool in pools.items():
                for name, work, batch in (("trials", run_trial, chunk), ("loop", busy_loop, loops)):
                    futures = [pool.submit(timed_task, work, task) for task in batch * workers]
                    spans = [future.result() for future in futures]
                    rates.setdefault((name, workers), []).append(busy_rate(spans, workers))
                    peaks.extend(span[3] for span in spans)
    mean = {key: float(np.mean(r)) for key, r in rates.items()}
    return {
        "1 worker": mean["trials", 1],
        "2 workers": mean["trials", 2],
        "ratio": mean["trials", 2] / mean["trials", 1],
        "machine": mean["loop", 2] / mean["loop", 1],
        "peak_mib": max(peaks),
    }


def dask_memory(folder: Path, trials: int, seed: int, every_s: float = 5.0) -> list[dict[str, float]]:
    """Run a measurement sweep of `trials` trials (Park only: the runner is what is measured) on a
    local Dask cluster of 2 single-threaded worker processes; every every_s seconds the trials done
    and the resident memory (MiB) of this process and of each worker."""
    import threading

    import psutil
    from distributed import Client, LocalCluster

    from hec.sweep.rows import ROWS_FILE
    from hec.sweep.runner import run_sweep

    config = sweep_config(folder, MEASUREMENTS, trials, seed, methods='["opencv-park"]')
    rows_file, readings = folder / "dask" / ROWS_FILE, []
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        Client(cluster.scheduler_address) as client,
    ):
        done = threading.Event()

        def read() -> None:
            while not done.wait(every_s):
                rows = sum(1 for _ in open(rows_file)) - 1 if rows_file.exists() else 0
                workers = client.run(lambda: psutil.Process().memory_info().rss / 2**20)
                parent = psutil.Process().memory_info().rss / 2**20
                readings.append({"trials": rows, "this process": parent, **_named(workers)})

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            run_sweep(config, folder / "dask", scheduler=cluster.scheduler_address, progress=False)
        finally:
            done.set()
            reader.join()
    return readings


def _named(worker_mib: dict) -> dict[str, float]:
    return {f"worker {i + 1}": mib for i, (_, mib) in enumerate(sorted(worker_mib.items()))}


def _line(rows: list[list[str]], name: str, ratio: float, parts: str) -> None:
    """Print one ratio with its goal (a name missing from GOALS has none) and keep it in rows."""
    goal, verdict = "(no goal)", "-"
    if name in GOALS:
        at_least = name == "workers/loop"
        ok = ratio >= GOALS[name] if at_least else ratio <= GOALS[name]
        goal, verdict = f"{'>=' if at_least else '<='} {GOALS[name]:g}", "met" if ok else "NOT met"
    print(f"  {name:14s}{ratio:8.2f}   {goal:9s} {verdict:8s}  {parts}", flush=True)
    rows.append([name, f"{ratio:.2f}", goal, verdict, parts])


def main(argv: list[str] | None = None) -> None:
    from hec.bench.render import waypoint_times

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="repetitions of each timing (median)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--worker-trials",
        type=int,
        default=24,
        help="render trials per worker count (5x as many measurement trials)",
    )
    parser.add_argument(
        "--dask-trials", type=int, default=0, help="also run a Dask sweep of this many trials"
    )
    parser.add_argument("--page", type=Path, help="also write the ratios as this Markdown page")
    args = parser.parse_args(argv)
    print("ratio          value    goal      verdict   parts")
    rows: list[list[str]] = []
    for scenario, clocks in waypoint_times(args.rounds).items():
        for clock, parts in clocks.items():
            text = ", ".join(f"{k} {v:.1f}" for k, v in parts.items())
            name = "waypoint" if clock == "cpu" else f"waypoint {clock}"
            _line(rows, name, parts["total"] / parts["render"], f"{scenario}, {clock} ms: {text}")
    with tempfile.TemporaryDirectory(prefix="hec-bench-speed-") as folder:
        _print_trials_and_workers(Path(folder), args, rows)
        if args.page:
            _write_page(args, rows)
        if args.dask_trials:
            print(f"\nDask sweep of {args.dask_trials} measurement trials, resident memory (MiB):")
            readings = dask_memory(Path(folder), args.dask_trials, args.seed)
            for reading in readings[:: max(1, len(readings) // 10)] + readings[-1:]:
                print("  " + ", ".join(f"{k} {v:.0f}" for k, v in reading.items()))


def _write_page(args: argparse.Namespace, rows: list[list[str]]) -> None:
    options = f"--rounds {args.rounds} --worker-trials {args.worker_trials}"
    command = f"python -m hec.bench.speed {options} --page {args.page}"
    intro = (
        "Each ratio is measured side by side in one run, so the machine's load cancels. The waypoint's"
        " goal is on CPU time, what a sweep with a worker per core pays (its wall time is shown"
        " without a goal: MuJoCo's software renderer uses both cores). The workers' goal is their"
        " ratio (2 worker processes against 1) divided by a CPU-bound loop's ratio on the same"
        " pools in the same run: the machine's own ceiling for two processes."
    )
    table = markdown_table(["ratio", "value", "goal", "verdict", "parts"], rows)
    write_results_page(args.page, "Speed of the Monte-Carlo sweeps", command, [intro, table])


def _print_trials_and_workers(folder: Path, args: argparse.Namespace, rows: list[list[str]]) -> None:
    from hec.bench.estimators import time_against_park

    trial = trial_times(folder, args.rounds, args.seed)
    _line(
        rows,
        "render trial",
        trial["trial"] / trial["views"],
        f"trial {trial['trial']:.2f} s, views {trial['views']:.2f} s",
    )
    methods = time_against_park(max(args.rounds, 5), args.seed)
    _line(
        rows,
        "ekf / park",
        methods["ekf"] / methods["park"],
        f"ekf {1e3 * methods['ekf']:.1f} ms, park {1e3 * methods['park']:.1f} ms",
    )
    learned = f"{1e3 * methods['batch_learned']:.0f} ms with its noise learned (run_method)"
    _line(rows, "batch ms", 1e3 * methods["batch"], f"17 views x 8 markers; {learned}")
    for fidelity, trials in ((MEASUREMENTS, 5 * args.worker_trials), (RENDER, args.worker_trials)):
        w = worker_speedup(folder, fidelity, trials, args.seed)
        rates = f"{w['1 worker']:.2f} and {w['2 workers']:.2f} trials/s"
        ratios = f"2 workers / 1 {w['ratio']:.2f}, a CPU-bound loop's {w['machine']:.2f}"
        text = f"{fidelity}: {rates}; {ratios} on the same pools; worker peak {w['peak_mib']:.0f} MiB"
        _line(rows, "workers/loop", w["ratio"] / w["machine"], text)


if __name__ == "__main__":
    main()
