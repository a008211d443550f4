"""Bad input and faults on the command line end in a clear message, with nothing lost and nothing
left behind: real signals to `hec simulate`, read-only and full file systems (small tmpfs mounts),
bad option values, broken files, and results that must not pass without a warning."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from hec.cli import main
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.lock import LOCK_FILE
from hec.estimator.observe.observations import CACHE_FILE, load_observations
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import run_method
from hec.estimator.solve.problem import build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene
from tests.hec_cli import run_hec, scenario_file

REPO = Path(__file__).resolve().parent.parent


def _uncached_copy(dataset: Path, copy: Path) -> Path:
    """A copy of dataset without its detections cache."""
    shutil.copytree(dataset, copy)
    (copy / CACHE_FILE).unlink(missing_ok=True)
    return copy


@contextlib.contextmanager
def _tmpfs(where: Path, size: str, read_only: bool = False) -> Iterator[Path]:
    """A small tmpfs at where (root runs the tests, so chmod would not stop a write)."""
    where.mkdir(parents=True, exist_ok=True)
    options = f"size={size}" + (",ro" if read_only else "")
    if subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True
    ).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def _hec_process(*argv: str) -> subprocess.Popen:
    env = os.environ | {"PYTHONPATH": str(REPO)}
    return subprocess.Popen(
        [sys.executable, "-m", "hec.cli", *argv],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_partial(out: Path, process: subprocess.Popen) -> Path:
    """The .OUT.partial-PID folder of a running `hec simulate`, once it holds its first frame."""
    end = time.monotonic() + 60
    while not list(out.parent.glob(f".{out.name}.partial-*/rgb/*.png")):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < end, "the simulation did not start"
        time.sleep(0.005)
    return next(out.parent.glob(f".{out.name}.partial-*"))


# --- signals -------------------------------------------------------------------------------------


def test_ctrl_c_during_simulate_is_a_message_and_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out"
    process = _hec_process(
        "simulate", "--out", str(out), "--scenario", str(scenario_file(tmp_path, 4)), "--quiet"
    )
    _wait_for_partial(out, process)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 130 and "Traceback" not in err, err
    assert f"interrupted: nothing written to {out}" in err
    assert list(tmp_path.glob(".out*")) == [] and not out.exists()


def test_ctrl_c_held_down_during_simulate_does_not_cut_its_clean_up_short(tmp_path: Path) -> None:
    out = tmp_path / "out"
    process = _hec_process(
        "simulate", "--out", str(out), "--scenario", str(scenario_file(tmp_path, 4)), "--quiet"
    )
    _wait_for_partial(out, process)
    while process.poll() is None:  # one Ctrl-C every 10 ms until hec has ended
        process.send_signal(signal.SIGINT)
        time.sleep(0.01)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 130 and "Traceback" not in err, err
    assert f"interrupted: nothing written to {out}" in err and err.count("still cleaning up") <= 1, err
    assert list(tmp_path.glob(".out*")) == [] and not out.exists()


def test_the_partial_folder_of_a_killed_simulate_is_removed_by_the_next_run(tmp_path: Path) -> None:
    out, scenario = tmp_path / "out", scenario_file(tmp_path, 4)
    process = _hec_process("simulate", "--out", str(out), "--scenario", str(scenario), "--quiet")
    partial = _wait_for_partial(out, process)
    process.kill()
    process.communicate()
    assert partial.is_dir()
    code, _, err = run_hec(
        ["simulate", "--out", str(out), "--scenario", str(scenario_file(tmp_path / "one", 1)), "--quiet"]
    )
    assert code == 0 and f"note: removed {partial}, left behind by a run that was killed" in err
    assert not partial.exists() and (out / "dataset.json").is_file()


# --- file systems --------------------------------------------------------------------------------


@pytest.mark.parametrize("fault", ["read-only", "full"])
def test_simulate_on_a_file_system_that_cannot_take_it_is_a_message(tmp_path: Path, fault: str) -> None:
    scenario = scenario_file(tmp_path / "case")
    with _tmpfs(tmp_path / "fs", "300k", read_only=fault == "read-only") as fs:
        code, _, err = run_hec(["simulate", "--out", str(fs / "out"), "--scenario", str(scenario), "--quiet"])
        assert code == 2 and f"hec: error: cannot write {fs / 'out'}: " in err and "nothing written" in err
        assert ("Read-only file system" if fault == "read-only" else "No space left on device") in err
        assert list(fs.iterdir()) == []


def _tmpfs_size(folder: Path, more_kib: int) -> str:
    """A tmpfs size that holds folder's files (in 4 KiB pages) and more_kib KiB more."""
    pages = sum(-(-p.stat().st_size // 4096) for p in folder.rglob("*") if p.is_file())
    return f"{4 * pages + more_kib}k"


def test_detect_overlay_on_a_full_file_system_names_the_image(default_dataset: Path, tmp_path: Path) -> None:
    """cv2.imwrite only returns False on a full disk: the overlay's error must still say which and why."""
    with _tmpfs(tmp_path / "fs", _tmpfs_size(default_dataset, 64)) as fs:
        ds = _uncached_copy(default_dataset, fs / "ds")
        code, _, err = run_hec(["detect", str(ds), "--overlay", "--quiet"])
        assert code == 2 and f"{ds / 'overlay' / '000000.png'}: No space left on device; " in err, err
        assert list((ds / "overlay").iterdir()) == [] and not (ds / CACHE_FILE).exists()


def test_record_on_a_full_file_system_stops_naming_the_file_and_unlocks(tmp_path: Path) -> None:
    scenario = scenario_file(tmp_path / "case", 3)
    with _tmpfs(tmp_path / "fs", "700k") as fs:  # room for the first frame, not the second
        out = fs / "rec"
        code, _, err = run_hec(
            ["record", "--sim", "--scenario", str(scenario), "--out", str(out), "--yes", "--no-live"]
        )
        assert code == 3 and "hec: session stopped: [Errno 28] No space left on device: " in err, err
        assert f"'{out}/" in err and "frames recorded are kept" in err
        assert not (out / LOCK_FILE).exists() and not list(out.rglob(".*partial*"))
        assert load_dataset(out).metadata["recording"] == "interrupted"


def test_calibrate_json_on_a_read_only_file_system_fails_before_the_work(
    default_dataset: Path, tmp_path: Path
) -> None:
    with _tmpfs(tmp_path / "fs", "64k", read_only=True) as fs:
        code, out, err = run_hec(
            ["calibrate", str(default_dataset), "--json", str(fs / "r.json"), "--quiet", "--verbose"]
        )
    assert code == 2 and f"{fs / 'r.json'}: cannot write in {fs} (Read-only file system; " in err
    assert out == "" and "Traceback" not in err


# --- option values -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["board", "--dpi", "0"], "argument --dpi: must be 72 to 2400 dots per inch, got '0'"),
        (["board", "--dpi", "5"], "argument --dpi: must be 72 to 2400 dots per inch, got '5'"),
        (["board", "--dpi", "-300"], "argument --dpi: must be 72 to 2400 dots per inch, got '-300'"),
        (["board", "--dpi", "100000"], "argument --dpi: must be 72 to 2400 dots per inch, got '100000'"),
        (["simulate", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
        (["record", "--sim", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
        (["run", "--sim", "--noise-seed", "x"], "argument --noise-seed: must be an integer >= 0, got 'x'"),
        (
            ["calibrate", "DS", "--robot-sigma-mm", "inf"],
            "argument --robot-sigma-mm: must be a number >= 0, got 'inf'",
        ),
    ],
)
def test_bad_option_values_name_the_option(
    argv: list[str], expected: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--out", str(tmp_path / "x.png")] if argv[0] != "calibrate" else argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_board_whose_modules_are_too_small_at_this_dpi_is_refused(tmp_path: Path) -> None:
    board = json.loads((REPO / "models" / "boards" / "hec_8qr.json").read_text())
    small = board | {"marker_size_m": 0.01, "markers": [{"id": 0, "center_m": [0.0, 0.0]}], "name": "tiny"}
    (tmp_path / "tiny.json").write_text(json.dumps(small))
    code, _, err = run_hec(
        ["board", "--board", str(tmp_path / "tiny.json"), "--out", str(tmp_path / "b.png"), "--dpi", "72"]
    )
    expected = "the smallest printed feature of qr board 'tiny' is 1.3 px wide; give --dpi 213 or more"
    assert code == 2 and expected in err
    assert not (tmp_path / "b.png").exists()


# --- scenario files ------------------------------------------------------------------------------


@pytest.mark.needs("sim")
def test_a_binary_scenario_file_is_named(tmp_path: Path) -> None:
    (tmp_path / "s.toml").write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    code, _, err = run_hec(
        ["simulate", "--out", str(tmp_path / "out"), "--scenario", str(tmp_path / "s.toml")]
    )
    assert code == 2 and f"{tmp_path / 's.toml'}: not a text file (byte 0 is not UTF-8)" in err


def test_a_board_too_low_for_its_table_names_the_key(tmp_path: Path) -> None:
    scenario = scenario_file(tmp_path, 1, "[board]\ntranslation_m = [0.15, -1.44, 0.45]\n")
    code, _, err = run_hec(["simulate", "--out", str(tmp_path / "out"), "--scenario", str(scenario)])
    assert code == 2 and "key 'board.translation_m': it puts the board 0.007 m above the floor" in err
    assert "table_leg" not in err and not (tmp_path / "out").exists()


def test_markers_too_small_to_decode_are_warned_of(tmp_path: Path) -> None:
    scenario = scenario_file(tmp_path, 1, "[camera]\nfovy_deg = 110\n")
    code, _, err = run_hec(
        ["simulate", "--out", str(tmp_path / "out"), "--scenario", str(scenario), "--quiet"]
    )
    assert code == 0
    assert (
        "warning: in 1 of 1 frames the markers are too small to decode: a QR module (or tag bit) is "
        "1.2 px wide" in err
    )


# --- datasets and results ------------------------------------------------------------------------


def test_calibrate_says_which_frame_had_a_depth_image_of_another_size(
    default_dataset: Path, tmp_path: Path
) -> None:
    copy = _uncached_copy(default_dataset, tmp_path / "copy")
    depth = cv2.imread(str(copy / "depth" / "000003.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(copy / "depth" / "000003.png"), depth[::2, ::2])
    code, out, _ = run_hec(
        ["calibrate", str(copy), "--method", "opencv-tsai", "--no-loo", "--quiet", "--verbose"]
    )
    assert code == 0
    assert "warning: frame 3: depth image is 320x240 but colour is 640x480" in out


def test_a_nan_corner_in_the_cache_names_the_file_and_calibrate_detects_again(
    default_dataset: Path, tmp_path: Path
) -> None:
    copy = _uncached_copy(default_dataset, tmp_path / "copy")
    assert run_hec(["detect", str(copy), "--quiet"])[0] == 0
    cache = json.loads((copy / CACHE_FILE).read_text())
    cache["frames"][2]["markers"][0]["corners_px"][1][0] = float("nan")
    (copy / CACHE_FILE).write_text(json.dumps(cache))
    with pytest.raises(ValueError, match=f"{copy / CACHE_FILE}: malformed .*'corners_px' is not finite"):
        load_observations(copy)
    code, _, err = run_hec(
        ["calibrate", str(copy), "--method", "opencv-tsai", "--no-loo", "--quiet", "--verbose"]
    )
    assert code == 0 and "is not finite); detecting the board in 17 frames" in err
    assert len(load_observations(copy)[0]) == 17


def test_a_filter_result_far_off_its_observations_is_warned_of() -> None:
    """Intrinsics 15 % off and the noise as declared: seed-ekf's residuals are 22 px."""
    rng = np.random.default_rng(1)
    noise = SyntheticNoise()
    observations = scene(random_mount(rng), rng, noise)
    wrong = replace(INTRINSICS, fx=1.15 * INTRINSICS.fx, fy=1.15 * INTRINSICS.fy)
    problem = build_problem(observations, BOARD, wrong, noise.robot)
    result = run_method("seed-ekf", problem, MethodOptions(learn_noise=False), observations)
    assert result.residual_rms_px > 20
    assert any("seed-ekf's result does not fit its data: RMS residual 22.2 px" in w for w in result.warnings)


def test_calibrate_on_a_read_only_dataset_detects_without_caching(
    default_dataset: Path, tmp_path: Path
) -> None:
    with _tmpfs(tmp_path / "fs", "40m") as fs:
        _uncached_copy(default_dataset, fs / "ds")
        subprocess.run(["mount", "-o", "remount,ro", str(fs)], check=True)
        code, out, err = run_hec(
            ["calibrate", str(fs / "ds"), "--method", "opencv-tsai", "--no-loo", "--quiet", "--verbose"]
        )
    assert code == 0, err
    assert f"note: cannot write {fs / 'ds' / CACHE_FILE} (Read-only file system): not cached" in err
    assert "observations detected now, not cached" in out
