"""A render sweep stopped by real signals: Ctrl-C removes the workers' scratch folders without a
leaked-semaphore warning, and the workers of a killed sweep exit by themselves."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
RENDER = 'fidelity = "render"\ntrials = 4\nmethods = ["opencv-tsai"]\n[fixed]\nwaypoints = 5\n'


def _children(pid: int) -> list[int]:
    """PIDs whose parent is pid (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _start_render_sweep(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    """`hec sweep` of render trials on one worker, once a trial renders (its scratch folder exists)."""
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    config = tmp_path / "render.toml"
    config.write_text(RENDER)
    env = os.environ | {"TMPDIR": str(scratch), "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "hec.cli", "sweep", str(config), "--out", str(tmp_path / "out")]
    process = subprocess.Popen(
        [*argv, "--workers", "1", "--quiet"],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    end = time.monotonic() + 120
    while not list(scratch.glob("hec-sweep-*/waypoints.csv")):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < end, "no render trial started"
        time.sleep(0.02)
    return process, scratch


@pytest.mark.needs("sim")
def test_ctrl_c_during_a_render_sweep_leaves_no_scratch_folder(tmp_path: Path) -> None:
    process, scratch = _start_render_sweep(tmp_path)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted:" in err.decode() and "leaked semaphore" not in err.decode(), err
    assert list(scratch.iterdir()) == []


@pytest.mark.needs("sim")
def test_the_workers_of_a_killed_sweep_exit(tmp_path: Path) -> None:
    process, scratch = _start_render_sweep(tmp_path)
    workers = _children(process.pid)  # the pool's worker and multiprocessing's resource tracker
    assert workers
    process.kill()
    process.wait(timeout=30)  # not communicate(): a surviving worker would hold the pipes open
    end = time.monotonic() + 10
    while any(_alive(pid) for pid in workers) and time.monotonic() < end:
        time.sleep(0.05)
    survivors = [pid for pid in workers if _alive(pid)]
    for pid in survivors:  # this test's own processes: leave nothing running when it fails
        os.kill(pid, signal.SIGKILL)
    assert not survivors, "a worker outlived the sweep by 10 s"
    assert list(scratch.iterdir()) == []
