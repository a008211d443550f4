"""Running a sweep: its output folder, trials on local processes or a Dask cluster, resume
and rerun.

Trial t of cell c draws everything (mount, random views, noise) from
``numpy.random.default_rng([seed, c, t])`` (``[seed, t]`` in a paired sweep), so the results do
not depend on where or in which order trials run, and one trial can be rerun alone (--rerun
c03-t0042). The estimators, the detector and MuJoCo are imported where a trial runs
(hec.sweep.trials). Each worker process uses one BLAS thread (OPENBLAS_NUM_THREADS=1,
also what Dask's nanny sets), which keeps the floating-point results identical wherever a trial runs.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

from tqdm import tqdm

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.io.lock import FolderLockedError, acquire_lock, release_lock
from hec.sweep.config import SweepConfig
from hec.sweep.parameters import PARAMETERS, RENDER, parameter_columns
from hec.sweep.rows import (
    DATASETS_DIR,
    EXAMPLE_DIR,
    FORMAT,
    META_FILE,
    ROWS_FILE,
    TRIAL_ID,
    VERSION,
    SweepError,
    compact_rows,
    format_rows,
    row_columns,
)
from hec.sweep.trials import TrialTask, one_line, remove_temporary_folders, run_trial, tasks_for

POOL_RESTARTS = 3
PARENT_POLL_S = 0.5  # how often a worker checks that the sweep that started it still runs
WORKER_EXIT_S = 10.0  # how long a stopped worker may take to remove its temporary folders
# Dask: trials submitted ahead per worker thread, and in all at least (see _run_dask).
DASK_TRIALS_IN_FLIGHT, DASK_MIN_IN_FLIGHT = 4, 8
BLAS_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


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
        "trial_seed": (
            "numpy.random.default_rng([seed, trial]); column seed = 'seed/trial'"
            if config.paired
            else "numpy.random.default_rng([seed, cell index, trial]); column seed = 'seed/cell/trial'"
        ),
        "trials_total": len(config.cells) * config.trials,
        "columns": row_columns(config.fidelity),
        "parameter_columns": parameter_columns(config.fidelity),
        "parameters": {p.name: p.doc for p in PARAMETERS.values() if config.fidelity in p.fidelities},
        "units": "errors, sigmas and CRB: root-sum-square over the 3 axes; mm and degrees; time_s seconds",
        "software": _software(),
    }


def check_same_config(stored: dict, config: SweepConfig, out_dir: Path) -> None:
    """Raise SweepError naming the first field where the folder's sweep differs from config."""
    new = json.loads(json.dumps(config.to_dict()))
    old = {"paired": False, **stored.get("config", {})}  # folders from before the key were unpaired
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
        check_same_config(stored, config, out_dir)
        before, now = stored.get("software", {}), _software()
        changed = [f"{k} {before.get(k)} -> {now.get(k)}" for k in now if before.get(k) != now.get(k)]
        if changed:
            print(
                f"note: software differs from {meta_path} ({'; '.join(changed)}): new trials may not match "
                "the earlier ones bit for bit",
                file=sys.stderr,
            )
        rows = compact_rows(out_dir, row_columns(config.fidelity), config.methods)
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


def available_cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _worker_exit(*_: object) -> None:
    """A worker's end when stopped (SIGTERM) or orphaned: remove its trial's temporary folders, exit."""
    remove_temporary_folders()
    os._exit(1)


def _watch_parent(parent_pid: int) -> None:
    """Exit the worker once its parent is gone (killed: nobody else would stop it)."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    _worker_exit()


def _start_worker(parent_pid: int) -> None:
    """Worker start: Ctrl-C is the parent's to handle (it stops the workers with SIGTERM, which
    removes the trial's temporary folders); a worker whose parent dies exits too; progress bars
    (the render trials' detection) lock with a thread lock."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_exit)
    # tqdm's default lock is a multiprocessing semaphore, which a stopped worker would leak.
    tqdm.set_lock(threading.RLock())
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()


def local_pool(workers: int) -> ProcessPoolExecutor:
    """Fresh (spawned) processes with one BLAS thread each: set before they import numpy."""
    os.environ.update(BLAS_ENV)
    return ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_start_worker,
        initargs=(os.getpid(),),
    )


def _run_pool(tasks: list[TrialTask], workers: int, on_rows: Callable, on_error: Callable) -> list[TrialTask]:
    """Run tasks on a fresh pool. Returns the tasks left unfinished when a worker died (else [])."""
    pool = local_pool(workers)
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
        processes = list(getattr(pool, "_processes", {}).values())
        for process in processes:
            process.terminate()  # our own workers: a Ctrl-C must not wait for running trials
        for process in processes:
            process.join(WORKER_EXIT_S)  # each removes its temporary folders first
        pool.shutdown(wait=True, cancel_futures=True)
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
    """Run on the client's cluster (its workers retry a trial whose worker died; then it is lost).
    At most DASK_TRIALS_IN_FLIGHT trials per worker thread (at least DASK_MIN_IN_FLIGHT in all) are
    submitted at a time, so the scheduler and this process hold a bounded number of tasks and
    results however long the sweep: a finished trial's rows go to disk and its result is released."""
    from distributed import as_completed

    threads = sum(client.nthreads().values())
    window = max(DASK_MIN_IN_FLIGHT, DASK_TRIALS_IN_FLIGHT * threads)
    waiting = iter(tasks)
    task_of: dict[str, TrialTask] = {}

    def submit(task: TrialTask) -> Any:
        future = client.submit(run_trial, task, pure=False)
        task_of[future.key] = task
        return future

    running = as_completed([submit(t) for t in itertools.islice(waiting, window)])
    try:
        for future in running:
            task = task_of.pop(future.key)
            try:
                rows = future.result()
            except Exception as exc:  # noqa: BLE001  (a killed worker, an error in the trial)
                on_error(task, f"{type(exc).__name__}: {exc}")
            else:
                on_rows(rows)
            future.release()
            following = next(waiting, None)
            if following is not None:
                running.add(submit(following))
    finally:
        with contextlib.suppress(Exception):
            client.cancel(list(running.futures))


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (a batch system stopping the job) stops the sweep as Ctrl-C does, unless the caller
    handles SIGTERM already (`hec` does: hec.support.interrupts)."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = None
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        with contextlib.suppress(ValueError):  # not the main thread: leave signals alone
            previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        if previous is not None:
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
    """run_sweep once connected: lock the folder (a run and its --resume at once would lose rows),
    prepare it, run what is not done, compact the rows."""
    if out_dir.exists() and not out_dir.is_dir():
        raise SweepError(f"{out_dir}: exists and is not a folder")
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        try:
            note = acquire_lock(out_dir, "a sweep")
        except FolderLockedError as exc:
            raise SweepError(str(exc)) from None
        if note is not None:
            print(f"note: {note}", file=sys.stderr)
        return _run_locked(config, out_dir, client, workers, resume, keep_datasets, progress)
    finally:
        release_lock(out_dir)
        if created and not any(out_dir.iterdir()):
            out_dir.rmdir()


def _run_locked(
    config: SweepConfig,
    out_dir: Path,
    client: Any,
    workers: int | None,
    resume: bool,
    keep_datasets: bool,
    progress: bool,
) -> SweepOutcome:
    """_run_sweep with the folder locked."""
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
            outcome.lost.append((task.trial_id, one_line(message)))
            if say:
                tqdm.write(f"trial {task.trial_id} did not finish: {outcome.lost[-1][1]}", file=sys.stderr)

        with _terminate_as_interrupt():
            if tasks and client is not None:
                _run_dask(tasks, client, on_rows, on_error)
            elif tasks:
                _run_local(tasks, workers or available_cores(), on_rows, on_error)
    outcome.seconds = time.perf_counter() - start
    if not outcome.lost:
        compact_rows(out_dir, columns, config.methods)
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
    with local_pool(1) as pool:
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
