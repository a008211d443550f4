"""`hec rehearse`: the real-cell session from the command line, the real ur_rtde clients and
librealsense's pipeline against the stand-ins in hec.rehearsal, ends with a calibration."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("pyrealsense2")

HOST = "127.0.0.8"  # apart from the other loopback tests' addresses
# A guard against a hang only (ur_rtde calls cannot be interrupted); nothing is timed.
HANG_LIMIT_S = 600


def _hec(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hec", *argv], capture_output=True, text=True, timeout=HANG_LIMIT_S
    )


def test_rehearse_runs_the_session_from_the_command_line_and_prints_a_calibration(tmp_path: Path) -> None:
    out = tmp_path / "rehearsal"
    proc = _hec("rehearse", "--out", str(out), "--views", "6", "--host", HOST)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    text = proc.stdout
    assert "plan: 6 waypoints, 6 to visit" in text and re.search(
        r"^\[6/6\] waypoint \d+ ", text, re.MULTILINE
    )
    assert "T_flange_cam by ekf" in text and "verdict:" in text
    dataset = json.loads((out / "dataset.json").read_text())
    assert dataset["source"] == "ur-realsense" and dataset["recording"] == "complete"
    assert dataset["cell"]["camera"]["device"]["serial"] == "000000000001"
    calibration = json.loads((out / "calibration.json").read_text())
    translation_mm = 1e3 * np.array(calibration["T_flange_cam"])[:3, 3]
    printed = re.search(r"translation \[mm\] ([-+.\d]+) ([-+.\d]+) ([-+.\d]+)", text)
    assert printed is not None
    np.testing.assert_allclose([float(v) for v in printed.groups()], translation_mm, atol=0.002)
    error = re.search(r"error against the simulated cell's true mount ([\d.]+) mm, ([\d.]+) deg", text)
    assert error is not None and float(error.group(1)) < 1.0 and float(error.group(2)) < 0.1


def test_rehearse_refuses_an_existing_out_folder_before_starting_anything(tmp_path: Path) -> None:
    (tmp_path / "taken").mkdir()
    proc = _hec("rehearse", "--out", str(tmp_path / "taken"), "--host", HOST)
    assert proc.returncode == 2 and "already exists" in proc.stderr
    assert list((tmp_path / "taken").iterdir()) == []


def test_preview_draws_the_planned_moves_and_never_replaces_a_file(tmp_path: Path) -> None:
    import cv2

    picture = tmp_path / "plan.png"
    argv = ["rehearse", "--dry-run", "--views", "3", "--host", HOST, "--preview", str(picture)]
    proc = _hec(*argv, "--out", str(tmp_path / "a"))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert f"preview: {picture}" in proc.stdout and "dry run: nothing moved" in proc.stdout
    sheet = cv2.imread(str(picture))
    assert sheet is not None and sheet.shape[1] == 4 + 4 * (320 + 4)  # 3 moves, 2 pictures each: 4 columns
    assert sheet.shape[0] > 2 * 240 and sheet.std() > 10  # two rows of rendered cells, not a blank
    before = picture.read_bytes()
    proc = _hec(*argv, "--out", str(tmp_path / "b"))
    assert proc.returncode == 2 and "already exists" in proc.stderr and picture.read_bytes() == before
