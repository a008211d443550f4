"""The speed benchmark's worker throughput: the all-busy window and a worker's own peak memory."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from hec.bench.speed import busy_rate, peak_rss_mib, timed_task


def _spans(pid: int, durations: list[float], start: float = 0.0) -> list[tuple[int, float, float, float]]:
    """Back-to-back tasks of one worker: (pid, start, end, peak MiB)."""
    ends = start + np.cumsum(durations)
    return [(pid, end - d, end, 100.0) for d, end in zip(durations, ends, strict=True)]


def test_two_workers_in_step_give_twice_one_worker() -> None:
    # 12 one-second tasks each: counting only the completions before the first idle worker
    # (23 of 24 by 12 s) gives 1.92 tasks/s; the tasks in progress count too.
    spans = _spans(1, [1.0] * 12) + _spans(2, [1.0] * 12)
    assert busy_rate(spans, 2) == pytest.approx(2.0)
    assert busy_rate(_spans(1, [1.0] * 12), 1) == pytest.approx(1.0)


def test_tasks_in_progress_count_by_their_part_inside_the_window() -> None:
    # Worker 2 starts 0.5 s late and runs 1.5 s tasks: the window is 0.5 .. 6.0 s, in which worker 1
    # does 5.5 tasks of 1 s and worker 2 finishes 3 and is 2/3 through its fourth.
    spans = _spans(1, [1.0] * 6) + _spans(2, [1.5] * 4, start=0.5)
    assert busy_rate(spans, 2) == pytest.approx((5.5 + 3 + 2 / 3) / 5.5)


def test_too_few_tasks_are_refused() -> None:
    with pytest.raises(ValueError, match="1 of 2 workers"):
        busy_rate(_spans(1, [1.0] * 4), 2)
    with pytest.raises(ValueError, match="never kept all 2 workers busy"):
        busy_rate(_spans(1, [1.0]) + _spans(2, [1.0], start=2.0), 2)


def test_a_spawned_worker_reports_its_own_peak_memory_not_its_parents() -> None:
    ballast = np.ones(400 * 2**20 // 8)  # 400 MiB in this process before the worker is spawned
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        pid, start, end, worker_peak = pool.submit(timed_task, sum, [1, 2]).result()
    assert end >= start and pid > 0
    assert peak_rss_mib() > ballast.nbytes / 2**20 > worker_peak
