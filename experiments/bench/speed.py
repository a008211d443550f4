"""Benchmark: the Monte-Carlo speed ratios, each measured side by side in one run (absolute times on
a shared 2-core machine vary from run to run; the ratios much less).

Run: .venv/bin/python -m experiments.bench.speed [--rounds 3] [--dask-trials 10000]
Prints, with its parts and its goal:
  waypoint      a whole simulated waypoint / MuJoCo's render of it, default and realistic scenario
                (experiments.bench.render)
  render trial  a render-fidelity sweep trial (17 views, ekf and Park) / simulating and detecting
                its views in memory (experiments.sweep.trials.render_inputs)
  estimators    ekf / OpenCV's Park with its PnP poses; batch in ms (17 views x 8 markers,
                experiments.bench.estimators.time_against_park)
  workers       sweep trials per second on 2 worker processes / on 1 at both fidelities, after each
                worker's start-up (imports, GL context), and the peak memory of a worker
  dask          with --dask-trials N: a measurement sweep of N trials on a local Dask cluster of 2
                workers, the memory of this process and of the workers as it runs
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from experiments.sweep.config import SweepConfig, cell_scenario, load_config
from experiments.sweep.parameters import MEASUREMENTS, RENDER
from experiments.sweep.trials import TrialTask, render_inputs, run_trial, tasks_for

TRIAL_METHODS = '["ekf", "opencv-park"]'
GOALS = {"waypoint": 2.0, "render trial": 2.0, "ekf / park": 3.0, "batch ms": 100.0, "workers": 1.85}


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
        rng = np.random.default_rng([task.seed, task.cell_index, task.trial])
        scenario = cell_scenario(task.scenario, task.base_dir, task.parameters)
        start = time.perf_counter()
        render_inputs(task, scenario, rng)
        views.append(time.perf_counter() - start)
    return {"trial": float(np.median(trial)), "views": float(np.median(views))}


def _trials_per_second(pool: ProcessPoolExecutor, tasks: list[TrialTask], workers: int) -> float:
    """Throughput of the pool on tasks, after a first trial on each worker (its start-up), while
    every worker is busy: up to the completion that leaves a worker without a trial to start (the
    last workers - 1 trials run beside idle workers, which a long sweep does not see)."""
    list(pool.map(run_trial, tasks[:workers]))
    start = time.perf_counter()
    measured = tasks[workers:]
    busy = len(measured) - workers + 1
    for done, _ in enumerate(as_completed([pool.submit(run_trial, task) for task in measured]), 1):
        if done == busy:
            return busy / (time.perf_counter() - start)
    raise ValueError(f"{len(measured)} trials are too few to measure {workers} workers")


def worker_speedup(folder: Path, fidelity: str, trials: int, seed: int) -> dict[str, float]:
    """Trials per second on 1 and on 2 local worker processes (as `hec sweep` starts them) and the
    peak resident memory of the largest worker so far, MiB."""
    from experiments.sweep.runner import local_pool

    tasks = tasks_for(sweep_config(folder, fidelity, trials + 2, seed))
    rates = {}
    for workers in (1, 2):
        with local_pool(workers) as pool:
            rates[workers] = _trials_per_second(pool, tasks, workers)
    peak_mib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {"1 worker": rates[1], "2 workers": rates[2], "ratio": rates[2] / rates[1], "peak_mib": peak_mib}


def dask_memory(folder: Path, trials: int, seed: int, every_s: float = 5.0) -> list[dict[str, float]]:
    """Run a measurement sweep of `trials` trials (Park only: the runner is what is measured) on a
    local Dask cluster of 2 single-threaded worker processes; every every_s seconds the trials done
    and the resident memory (MiB) of this process and of each worker."""
    import threading

    import psutil
    from distributed import Client, LocalCluster

    from experiments.sweep.rows import ROWS_FILE
    from experiments.sweep.runner import run_sweep

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


def _line(name: str, ratio: float, parts: str) -> None:
    goal = GOALS[name]
    ok = ratio <= goal if name != "workers" else ratio >= goal
    sign = ">=" if name == "workers" else "<="
    print(f"  {name:14s}{ratio:8.2f}   goal {sign} {goal:g}  {'met' if ok else 'NOT met'}   {parts}")


def main(argv: list[str] | None = None) -> None:
    from experiments.bench.render import waypoint_times

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="repetitions of each timing (median)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--worker-trials", type=int, default=24, help="render trials per worker count")
    parser.add_argument(
        "--dask-trials", type=int, default=0, help="also run a Dask sweep of this many trials"
    )
    args = parser.parse_args(argv)
    print("ratio          value    goal           parts")
    for scenario, parts in waypoint_times(args.rounds).items():
        text = ", ".join(f"{k} {v:.1f}" for k, v in parts.items())
        _line("waypoint", parts["total"] / parts["render"], f"{scenario} (ms): {text}")
    with tempfile.TemporaryDirectory(prefix="hec-bench-speed-") as folder:
        _print_trials_and_workers(Path(folder), args)
        if args.dask_trials:
            print(f"\nDask sweep of {args.dask_trials} measurement trials, resident memory (MiB):")
            readings = dask_memory(Path(folder), args.dask_trials, args.seed)
            for reading in readings[:: max(1, len(readings) // 10)] + readings[-1:]:
                print("  " + ", ".join(f"{k} {v:.0f}" for k, v in reading.items()))


def _print_trials_and_workers(folder: Path, args: argparse.Namespace) -> None:
    from experiments.bench.estimators import time_against_park

    trial = trial_times(folder, args.rounds, args.seed)
    _line(
        "render trial",
        trial["trial"] / trial["views"],
        f"trial {trial['trial']:.2f} s, views {trial['views']:.2f} s",
    )
    methods = time_against_park(max(args.rounds, 5), args.seed)
    _line(
        "ekf / park",
        methods["ekf"] / methods["park"],
        f"ekf {1e3 * methods['ekf']:.1f} ms, park {1e3 * methods['park']:.1f} ms",
    )
    learned = f"{1e3 * methods['batch_learned']:.0f} ms with its noise learned (run_method)"
    _line("batch ms", 1e3 * methods["batch"], f"17 views x 8 markers; {learned}")
    for fidelity, trials in ((MEASUREMENTS, 5 * args.worker_trials), (RENDER, args.worker_trials)):
        w = worker_speedup(folder, fidelity, trials, args.seed)
        rates = f"{w['1 worker']:.2f} and {w['2 workers']:.2f} trials/s"
        text = f"{fidelity}: {rates}; worker peak {w['peak_mib']:.0f} MiB"
        _line("workers", w["ratio"], text)


if __name__ == "__main__":
    main()
