"""Faults found by a fault-injection pass (beside the fault table's cases): values a file
must not hold (infinity, a ragged waypoint row, a NaN flange pose, frames out of order), temporary
files left when a write fails, a file replaced by a dataset, SIGTERM, SIGHUP and Ctrl-C to
commands that had no handler or while hec still imports its libraries, a signal during the clean-up,
and a resumed recording given other waypoints."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hec.cli import main
from hec.estimator.geometry.waypoints import write_waypoint_file
from hec.sim.scenario import Scenario
from hec.sim.simulate import scenario_waypoints
from tests.hec_cli import run_hec, scenario_file, simulated_dataset

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three simulated frames, detected."""
    out = simulated_dataset(tmp_path_factory.mktemp("fault_pass"), 3)
    assert run_hec(["detect", str(out), "--quiet"])[0] == 0
    return out


def _hec_process(*argv: str, env: dict[str, str] | None = None) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "hec.cli", *argv],
        cwd=REPO,
        env=os.environ | {"PYTHONPATH": str(REPO)} | (env or {}),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for(pattern: str, folder: Path, process: subprocess.Popen) -> None:
    end = time.monotonic() + 60
    while not list(folder.glob(pattern)):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < end, f"{pattern} did not appear"
        time.sleep(0.005)


# --- values a file must not hold ------------------------------------------------------------------


@pytest.mark.parametrize("value", ["inf", "nan"])
def test_a_scenario_value_that_is_not_finite_names_the_key(tmp_path: Path, value: str) -> None:
    scenario = scenario_file(tmp_path, toml=f"[noise.depth]\nsubpixel = {value}\n")
    code, _, err = run_hec(
        ["simulate", "--out", str(tmp_path / "out"), "--scenario", str(scenario), "--quiet"]
    )
    assert code == 2 and "noise.depth.subpixel" in err and not (tmp_path / "out").exists(), err


def test_a_waypoint_row_with_more_values_than_the_header_is_refused(tmp_path: Path) -> None:
    scenario = scenario_file(tmp_path)
    lines = (tmp_path / "waypoints.csv").read_text().splitlines()
    (tmp_path / "waypoints.csv").write_text("\n".join([lines[0], lines[1] + ",0.5,extra", lines[2]]) + "\n")
    code, _, err = run_hec(
        ["simulate", "--out", str(tmp_path / "out"), "--scenario", str(scenario), "--quiet"]
    )
    assert code == 2 and "waypoint 0 (data row 1): 10 values, the header has 8 columns" in err, err


@pytest.mark.parametrize(
    ("column", "value", "message"),
    [(4, "nan", "line 3: values must be finite"), (0, "0", "line 3: frame 0, expected 1")],
)
def test_frames_csv_with_a_nan_pose_or_frames_out_of_order_is_refused(
    small_dataset: Path, tmp_path: Path, column: int, value: str, message: str
) -> None:
    ds = shutil.copytree(small_dataset, tmp_path / "ds")
    lines = (ds / "frames.csv").read_text().splitlines()
    cells = lines[2].split(",")
    cells[column] = value
    lines[2] = ",".join(cells)
    (ds / "frames.csv").write_text("\n".join(lines) + "\n")
    code, _, err = run_hec(["calibrate", str(ds), "--quiet", "--verbose", "--no-loo"])
    assert code == 2 and f"{ds / 'frames.csv'}: {message}" in err, err


# --- nothing left when a write fails --------------------------------------------------------------


def test_a_cache_that_cannot_be_replaced_leaves_no_temporary_file(
    small_dataset: Path, tmp_path: Path
) -> None:
    ds = shutil.copytree(small_dataset, tmp_path / "ds")
    (ds / "detections.json").unlink()
    (ds / "detections.json").mkdir()  # the rename onto it fails
    code, _, err = run_hec(["detect", str(ds), "--quiet"])
    assert code == 2 and "detections.json" in err
    assert list(ds.glob(".detections.json*")) == []


def test_board_whose_definition_cannot_be_written_writes_neither_file(tmp_path: Path) -> None:
    (tmp_path / "dd").mkdir()
    code, _, err = run_hec(["board", "--out", str(tmp_path / "b.png"), "--definition", str(tmp_path / "dd")])
    assert code == 2 and "dd" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dd"] and list((tmp_path / "dd").iterdir()) == []


# --- signals to real processes --------------------------------------------------------------------


@pytest.mark.parametrize(("sig", "name"), [(signal.SIGTERM, "SIGTERM"), (signal.SIGHUP, "SIGHUP")])
def test_sigterm_or_sighup_during_simulate_cleans_up_as_ctrl_c_does(
    tmp_path: Path, sig: signal.Signals, name: str
) -> None:
    out = tmp_path / "out"
    process = _hec_process(
        "simulate", "--out", str(out), "--scenario", str(scenario_file(tmp_path, 4)), "--quiet"
    )
    _wait_for(".out.partial-*/rgb/*.png", tmp_path, process)
    process.send_signal(sig)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 128 + sig and "Traceback" not in err, err
    assert f"interrupted: nothing written to {out}" in err
    assert list(tmp_path.glob(".out*")) == [] and not out.exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_during_detect_is_a_message_and_writes_no_cache(
    small_dataset: Path, tmp_path: Path, sig: signal.Signals
) -> None:
    ds = shutil.copytree(small_dataset, tmp_path / "ds")
    (ds / "detections.json").unlink()
    process = _hec_process("detect", str(ds), "--overlay", "--quiet")
    _wait_for("overlay/*.png", ds, process)
    process.send_signal(sig)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 128 + sig and "Traceback" not in err, err
    assert err.strip().splitlines()[-1].startswith("hec: interrupted"), err
    assert not (ds / "detections.json").exists() and list(ds.glob(".detections.json*")) == []


def test_ctrl_c_while_a_board_is_drawn_writes_nothing(tmp_path: Path) -> None:
    """The signal lands once the board module has loaded, the last import before drawing (tens of
    seconds at 2400 dpi): a fixed wait had sometimes landed inside pyrealsense2's import on a busy
    machine, which turns it into an ImportError."""
    process = _hec_process(
        "board", "--out", str(tmp_path / "b.png"), "--dpi", "2400", env={"PYTHONPROFILEIMPORTTIME": "1"}
    )
    for line in process.stderr:
        if line.split("|")[-1].strip() == "hec.commands.printable":
            break
    time.sleep(0.5)
    assert process.poll() is None, process.communicate()
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130 and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("sig", "name"), [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "stopped by SIGTERM")])
def test_a_signal_while_hec_still_imports_its_libraries_is_one_line(
    tmp_path: Path, sig: signal.Signals, name: str
) -> None:
    """The signal lands once numpy has loaded and OpenCV, SciPy and the rest have not (Python's
    import-time report on stderr says when)."""
    process = _hec_process("detect", str(tmp_path / "none"), env={"PYTHONPROFILEIMPORTTIME": "1"})
    for line in process.stderr:
        if line.split("|")[-1].strip() == "numpy":
            break
    assert process.poll() is None, process.communicate()
    process.send_signal(sig)
    _, err = process.communicate(timeout=30)
    said = [line for line in err.splitlines() if line and not line.startswith("import time:")]
    assert process.returncode == 128 + sig, err[-3000:]
    assert said == [f"hec: interrupted ({name}) while starting; nothing done"], said


def test_signals_during_the_clean_up_are_ignored_and_said_once() -> None:
    """A second and a third signal while the first one's clean-up runs: it goes on to its end."""
    code = (
        "import os, signal, time\n"
        "from hec.support.interrupts import stop_signals\n"
        "with stop_signals():\n"
        "    try:\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"
        "        time.sleep(10)\n"
        "    except KeyboardInterrupt:\n"
        "        for sig in (signal.SIGINT, signal.SIGTERM):\n"
        "            os.kill(os.getpid(), sig)\n"
        "            time.sleep(0.05)\n"
        "        print('cleaned up')\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"  # the process is ending: ignored
        "print('exiting')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=REPO,
        env=os.environ | {"PYTHONPATH": str(REPO)},
        capture_output=True,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.decode().split() == ["cleaned", "up", "exiting"]
    assert done.stderr.decode() == "\nhec: still cleaning up, please wait\n"


def test_resume_with_other_waypoints_is_refused_naming_the_field(tmp_path: Path) -> None:
    """--waypoints overrides the scenario's trajectory: the same scenario and seed, other views."""
    out = tmp_path / "rec"
    scenario = str(scenario_file(tmp_path, 2))
    argv = ["record", "--sim", "--scenario", scenario, "--out", str(out), "--yes", "--no-live"]
    assert run_hec(argv)[0] == 0
    write_waypoint_file(tmp_path / "other.csv", scenario_waypoints(Scenario())[1:3])
    code, _, err = run_hec([*argv, "--resume", "--waypoints", str(tmp_path / "other.csv")])
    assert code == 2 and f"{out / 'dataset.json'}: cannot resume, 'waypoints.sha256' was '" in err, err
    assert len((out / "frames.csv").read_text().splitlines()) == 3
    meta = json.loads((out / "dataset.json").read_text())
    del meta["waypoints"]  # as an older hec recorded it: resumed, and said so
    (out / "dataset.json").write_text(json.dumps(meta))
    code, _, err = run_hec([*argv, "--resume"])
    assert code == 0 and f"{out / 'dataset.json'} has no 'waypoints' (an older recording): not checked" in err


def test_teach_append_to_a_binary_file_names_it(tmp_path: Path) -> None:
    (tmp_path / "t.csv").write_bytes(b"\x00\xffgarbage\n")
    code, _, err = run_hec(["teach", "--robot", "127.0.0.1", "--append", "--out", str(tmp_path / "t.csv")])
    assert code == 2 and f"{tmp_path / 't.csv'}: not a text file (byte 1 is not UTF-8)" in err, err


def test_simulate_force_does_not_replace_a_file_with_a_dataset(tmp_path: Path) -> None:
    (tmp_path / "out").write_text("a file of mine")
    code, _, err = run_hec(
        [
            "simulate",
            "--out",
            str(tmp_path / "out"),
            "--scenario",
            str(scenario_file(tmp_path, 1)),
            "--force",
            "--quiet",
        ]
    )
    assert code == 2 and "is a file, not a dataset folder; it is not replaced" in err, err
    assert (tmp_path / "out").read_text() == "a file of mine"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_detect_with_no_pass_names_the_option(small_dataset: Path) -> None:
    code, _, err = run_hec(["detect", str(small_dataset), "--passes", ",", "--quiet"])
    assert code == 2 and "--passes ',': give at least one decoding pass" in err, err


def test_sigterm_during_a_recording_keeps_its_frames_and_frees_the_lock(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    scenario = str(scenario_file(tmp_path, 5))
    process = _hec_process("record", "--sim", "--scenario", scenario, "--out", str(out), "--yes", "--no-live")
    _wait_for("rec/rgb/000001.png", tmp_path, process)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 3 and "Traceback" not in err, err
    assert "hec: session stopped: stopped by SIGTERM" in err
    assert not (out / ".hec-lock").exists()
    assert '"interrupted"' in (out / "dataset.json").read_text()


def test_a_robot_sigma_too_large_to_square_is_refused(
    small_dataset: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["calibrate", str(small_dataset), "--robot-sigma-mm", "1e308", "--quiet", "--verbose"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert "--robot-sigma-mm: must be at most 10000, got '1e308'" in err
