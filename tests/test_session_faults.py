"""`hec record` under faults: a second process on the same folder, a killed recording, a resume with
another seed or mount, and what the detections cache and the live estimate keep."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.geometry.waypoints import write_waypoint_file
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.lock import LOCK_FILE, FolderLockedError
from hec.estimator.io.recorder import DatasetRecorder
from hec.estimator.observe.frames import Capture
from hec.estimator.observe.observations import (
    FrameObservations,
    ObservationCacheError,
    dataset_depth_noise,
    load_observations,
    save_observations,
)
from hec.estimator.targets.qr import DetectorSettings
from hec.session.session import LiveEstimate
from hec.sim.scenario import Scenario
from hec.sim.simulate import scenario_waypoints
from tests.hec_cli import run_hec

REPO = Path(__file__).resolve().parent.parent
VIEWS = 4
SEED = 3


def _scenario(folder: Path, mount: str = "") -> Path:
    """A scenario of the first VIEWS default views (a waypoint file), with an optional [mount]."""
    folder.mkdir(parents=True, exist_ok=True)
    write_waypoint_file(folder / "waypoints.csv", scenario_waypoints(Scenario())[:VIEWS])
    text = '[trajectory]\nkind = "file"\nfile = "waypoints.csv"\n' + mount
    (folder / "scenario.toml").write_text(text)
    return folder / "scenario.toml"


def _record(scenario: Path, out: Path, *extra: str) -> list[str]:
    return ["record", "--sim", "--scenario", str(scenario), "--seed", str(SEED), "--out", str(out), *extra]


def _frames_written(out: Path) -> int:
    try:
        return len((out / "frames.csv").read_text().splitlines()) - 1
    except FileNotFoundError:
        return 0


def _wait_for(condition: object, process: subprocess.Popen, limit_s: float = 60.0) -> None:
    end = time.monotonic() + limit_s
    while not condition():
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < end, "the recording did not start in time"
        time.sleep(0.005)


def test_a_killed_recording_is_locked_while_it_runs_and_resumes_to_the_uninterrupted_frames(
    tmp_path: Path,
) -> None:
    scenario = _scenario(tmp_path / "case")
    whole = tmp_path / "whole"
    assert run_hec(_record(scenario, whole, "--no-live"))[0] == 0
    cut = tmp_path / "cut"
    env = os.environ | {"PYTHONPATH": str(REPO)}
    process = subprocess.Popen(
        [sys.executable, "-m", "hec.cli", *_record(scenario, cut, "--no-live")],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        _wait_for(lambda: _frames_written(cut) >= 1, process)
        # A second recorder on the folder while the first runs: refused, naming the process.
        with pytest.raises(FolderLockedError, match=f"in progress there \\(process {process.pid}"):
            DatasetRecorder(cut, None, None, 1e-4, "sim", resume=True)
        process.kill()
    finally:
        process.kill()
        process.communicate()
    assert 1 <= _frames_written(cut) < VIEWS and (cut / LOCK_FILE).is_file()
    code, out, err = run_hec(_record(scenario, cut, "--no-live", "--resume"))
    assert code == 0, err
    assert f"stale lock of a recording by process {process.pid}, which no longer runs" in err
    assert not (cut / LOCK_FILE).exists()
    resumed, reference = load_dataset(cut), load_dataset(whole)
    assert len(resumed) == len(reference) == VIEWS
    by_waypoint = {row["waypoint"]: row for row in resumed.rows}
    for row in reference.rows:  # every waypoint's noise is its own, however the run was split
        other = by_waypoint[row["waypoint"]]
        for column in ("rgb", "depth"):
            assert (cut / other[column]).read_bytes() == (whole / row[column]).read_bytes()
        np.testing.assert_array_equal(other["T_base_flange"], row["T_base_flange"])


def test_resume_refuses_another_seed_or_mount_and_says_what_differs(tmp_path: Path) -> None:
    scenario = _scenario(tmp_path / "case")
    out = tmp_path / "out"
    env_args = _record(scenario, out, "--no-live")
    assert run_hec(env_args)[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    code, _, err = run_hec([*env_args, "--resume", "--seed", "4"])
    # The noise seed follows --seed and is named first (the fields are compared in sorted order).
    assert code == 2 and "cannot resume, 'simulation.noise_seed' was 3 and is now 4" in err
    moved = _scenario(tmp_path / "moved", "[mount]\ntranslation_m = [0.0, 0.006, 0.050]\n")
    code, _, err = run_hec(_record(moved, out, "--no-live", "--resume"))
    assert code == 2 and "'simulation.scenario.mount.translation_m' was [0.0, 0.006, 0.04]" in err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert not (out / LOCK_FILE).exists()


def _problem_frames(root: Path, count: int) -> list[FrameObservations]:
    """Observations of the first count frames, each a frame without markers (no detection needed)."""
    rows = load_dataset(root).rows
    return [
        FrameObservations(i, rows[i]["time_s"], rows[i]["T_base_flange"], problem="x") for i in range(count)
    ]


def test_the_cache_is_refused_when_the_board_changed_or_it_covers_fewer_frames(
    default_dataset: Path, tmp_path: Path
) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(default_dataset, copy)
    dataset = load_dataset(copy)
    noise = dataset_depth_noise(dataset)
    save_observations(copy, _problem_frames(copy, len(dataset)), DetectorSettings(), noise)
    assert len(load_observations(copy)[0]) == len(dataset)
    board = (copy / "board.json").read_text()
    (copy / "board.json").write_text(board.replace('"marker_size_m": 0.06', '"marker_size_m": 0.061'))
    with pytest.raises(ObservationCacheError, match="board changed"):
        load_observations(copy)
    (copy / "board.json").write_text(board)
    save_observations(copy, _problem_frames(copy, len(dataset) - 1), DetectorSettings(), noise)
    with pytest.raises(ObservationCacheError, match=f"fewer than the dataset's {len(dataset)} frames"):
        load_observations(copy)


def test_the_live_estimate_detects_frames_it_missed_before_saving(
    default_dataset: Path, tmp_path: Path
) -> None:
    """Ctrl-C during the live detection of the last frame: the cache saved still covers every frame."""
    source = load_dataset(default_dataset)
    root = tmp_path / "session"
    recorder = DatasetRecorder(root, source.intrinsics, source.board, source.depth_scale_m, "sim")
    live = LiveEstimate(root)
    for i in range(2):
        recorder.add_frame(Capture(source.frame(i)), waypoint=i)
        if i == 0:
            live.add(0, source.frame(0))
    recorder.finish("interrupted")
    live.save(root)
    observations, _, _ = load_observations(root)
    assert [o.frame for o in observations] == [0, 1] and len(observations[1].markers) >= 7
