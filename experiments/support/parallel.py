"""Running a benchmark's jobs here or in worker processes."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any


def results_as_done(fn: Callable[..., Any], jobs: Iterable[tuple], workers: int) -> Iterator[Any]:
    """fn(*job) for every job: in this process, in order, when workers <= 1; else in `workers`
    processes, each result as soon as it is done (callers sort them if order matters)."""
    if workers <= 1:
        yield from (fn(*job) for job in jobs)
        return
    with ProcessPoolExecutor(workers) as pool:
        yield from (f.result() for f in as_completed([pool.submit(fn, *job) for job in jobs]))
