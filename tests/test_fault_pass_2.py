"""Faults of the commands that came after the first fault pass (export, import, plan, sweep --resume):
an output never replaces an input, frame names and numbers fit the format they go into, and a
file system that cannot take a write is one line in hec's words."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.io.dataset import DatasetWriter, load_dataset
from hec.estimator.io.lock import LOCK_FILE
from hec.sweep.rows import load_rows
from hec.sweep.runner import same_rows
from tests.hec_cli import run_hec
from tests.test_export import _calibration_file
from tests.test_fault_pass import REPO, _wait_for
from tests.test_import import FLANGE_TO_BASE, FOLDER_OPTIONS, _import, exported, rendered_samples

__all__ = ["exported", "rendered_samples"]  # the fixtures of test_import, shared

# --- export ---------------------------------------------------------------------------------------


def test_export_over_its_calibration_file_is_refused_and_the_file_kept(tmp_path: Path) -> None:
    cal = _calibration_file(tmp_path)
    before = cal.read_bytes()
    code, _, err = run_hec(["export", str(cal), "--to", "json", "--out", str(cal)])
    assert code == 2 and f"--out {cal}: is the calibration file this command reads" in err, err
    assert cal.read_bytes() == before


def test_export_over_its_link_optical_file_is_refused_and_the_file_kept(tmp_path: Path) -> None:
    cal = _calibration_file(tmp_path)
    link = tmp_path / "link.json"
    link.write_text(json.dumps({"T_link_optical": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}))
    before = link.read_bytes()
    argv = ["export", str(cal), "--to", "urdf", "--link-optical", str(link), "--out", str(link)]
    code, _, err = run_hec(argv)
    assert code == 2 and "is the --link-optical file this command reads" in err, err
    assert link.read_bytes() == before


def test_export_onto_a_pipe_is_refused_and_the_pipe_kept(tmp_path: Path) -> None:
    """A device or pipe given as --out (/dev/full, /dev/null) is not replaced by the rename."""
    cal, pipe = _calibration_file(tmp_path), tmp_path / "pipe"
    os.mkfifo(pipe)
    code, _, err = run_hec(["export", str(cal), "--to", "json", "--out", str(pipe)])
    assert code == 2 and f"{pipe}: is a device, a pipe or a socket, not a file" in err, err
    assert stat.S_ISFIFO(pipe.stat().st_mode)


@pytest.mark.parametrize(
    "values", [["nan"] * 3 + ["0", "0", "0", "1"], ["0", "0", "inf", "0", "0", "0", "1"]]
)
def test_export_with_link_values_that_are_not_finite_is_refused(tmp_path: Path, values: list[str]) -> None:
    cal = _calibration_file(tmp_path)
    argv = [
        "export",
        str(cal),
        "--to",
        "urdf",
        "--link-optical-values",
        *values,
        "--out",
        str(tmp_path / "o"),
    ]
    code, _, err = run_hec(argv)
    assert code == 2 and "--link-optical-values: every value must be a finite number" in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("option", "name", "said"),
    [
        ("--child", "", "child frame (--child): the name is empty"),
        ("--parent", "", "parent frame (--parent): the name is empty"),
        ("--child", "camera optical_frame", "found ' '"),
        ("--parent", "tool0\nrm -rf", "found '\\n'"),
        ("--child", "cam\tera_optical_frame", "found '\\t'"),
    ],
)
def test_export_refuses_frame_names_no_tool_can_hold(
    tmp_path: Path, option: str, name: str, said: str
) -> None:
    cal = _calibration_file(tmp_path)
    code, out, err = run_hec(["export", str(cal), "--to", "ros2-args", option, name])
    assert code == 2 and said in err and out == "", err


HOSTILE_NAMES = ['cam"era_optical_frame', "a;touch_x_optical_frame", "<&'$(id)>_optical_frame"]


@pytest.mark.parametrize("child", HOSTILE_NAMES)
def test_hostile_frame_names_are_escaped_in_the_urdf(tmp_path: Path, child: str) -> None:
    code, out, err = run_hec(["export", str(_calibration_file(tmp_path)), "--to", "urdf", "--child", child])
    assert code == 0, err
    joint = ET.fromstring(out.split("\n", 1)[1]).find("joint")
    assert joint.find("child").get("link") == child and joint.find("parent").get("link") == "tool0"


@pytest.mark.parametrize("child", HOSTILE_NAMES)
def test_hostile_frame_names_are_one_shell_word_in_the_ros2_command(tmp_path: Path, child: str) -> None:
    code, out, err = run_hec(
        ["export", str(_calibration_file(tmp_path)), "--to", "ros2-args", "--child", child]
    )
    assert code == 0, err
    words = shlex.split(out.splitlines()[-1])
    assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    assert words[words.index("--child-frame-id") + 1] == child and words[-2] == "--child-frame-id"


@pytest.mark.parametrize("fmt", ["yaml", "easy_handeye2", "ros2-launch", "json"])
def test_hostile_frame_names_come_back_from_every_other_format(tmp_path: Path, fmt: str) -> None:
    import ast

    import yaml

    child = HOSTILE_NAMES[2]
    code, out, err = run_hec(["export", str(_calibration_file(tmp_path)), "--to", fmt, "--child", child])
    assert code == 0, err
    if fmt == "ros2-launch":
        tree = ast.parse(out)
        strings = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)]
        assert child in strings
    else:
        data = json.loads(out) if fmt == "json" else yaml.safe_load(out)
        found = data["parameters"]["tracking_base_frame"] if fmt == "easy_handeye2" else data["child_frame"]
        assert found == child


@pytest.mark.parametrize(
    ("out", "said"),
    [
        ("missing/x.json", "missing does not exist; create it or write somewhere else"),
        (".", "is a folder, expected a file name"),
        ("n" * 300, "the name is too long (at most 255 bytes a name)"),
    ],
)
def test_export_to_an_output_it_cannot_write_says_so_in_one_line(tmp_path: Path, out: str, said: str) -> None:
    cal = _calibration_file(tmp_path)
    target = tmp_path / out
    code, _, err = run_hec(["export", str(cal), "--to", "json", "--out", str(target)])
    assert code == 2 and said in err and "Errno" not in err and len(err.strip().splitlines()) == 1, err


# --- import: an output never replaces a source, concurrent and killed runs ------------------------

HOLD_WRITER = """
import sys
from hec.estimator.io.dataset import DatasetWriter
with DatasetWriter(sys.argv[1], None, None, 0.001, "import") as writer:
    print("writing", flush=True)
    if sys.stdin.readline().strip() == "finish":
        writer.add_pose(__import__("numpy").eye(4), 0.0)
        writer.finish()
"""


def _writer_process(out: Path) -> subprocess.Popen:
    """A real process writing a dataset at out, waiting (its partial folder made) for 'finish' or
    'stop' on its stdin: deterministic, no timing."""
    process = subprocess.Popen(
        [sys.executable, "-c", HOLD_WRITER, str(out)],
        cwd=REPO,
        env=os.environ | {"PYTHONPATH": str(REPO)},
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert process.stdout.readline().strip() == "writing"
    return process


def _frame_count(dataset: Path) -> int:
    return json.loads((dataset / "dataset.json").read_text())["frame_count"]


def _folder_import(exported: dict[str, Path], out: Path, *options: str) -> list[str]:
    return _import(exported, out, "folder", *FOLDER_OPTIONS, *FLANGE_TO_BASE, *options)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("force", [False, True])
def test_import_into_the_folder_that_holds_its_source_is_refused(
    exported: dict[str, Path], tmp_path: Path, force: bool
) -> None:
    source = shutil.copytree(exported["folder"], tmp_path / "SRC")
    before = _snapshot(source)
    argv = ["import", "folder", str(source / "images"), "--poses", str(source / "poses.csv")]
    argv += ["--out", str(source), "--board", "hec_8qr", "--intrinsics", str(exported["camera"]), "--quiet"]
    code, _, err = run_hec(argv + ["--force"] * force)
    assert code == 2 and f"--out {source}: holds the source this command reads" in err, err
    assert _snapshot(source) == before


@pytest.mark.parametrize("layout", ["visp", "easy_handeye2"])
def test_import_onto_its_own_source_is_refused(
    exported: dict[str, Path], rendered_samples: Path, tmp_path: Path, layout: str
) -> None:
    if layout == "visp":
        source = shutil.copytree(exported["visp"], tmp_path / "visp")
    else:
        source = Path(shutil.copy(rendered_samples, tmp_path / "cell.samples"))
    before = source.read_bytes() if source.is_file() else _snapshot(source)
    code, _, err = run_hec(
        ["import", layout, str(source), "--out", str(source), "--force", "--board", "hec_8qr"]
    )
    assert code == 2 and f"--out {source}: is the source this command reads" in err, err
    assert (source.read_bytes() if source.is_file() else _snapshot(source)) == before


def test_import_force_never_replaces_a_folder_that_is_not_a_dataset(exported, tmp_path: Path) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's own")
    code, _, err = run_hec(_folder_import(exported, mine, "--force", "--no-check"))
    assert code == 2 and f"{mine}: exists and is not a hec dataset; --force replaces only" in err, err
    assert _snapshot(mine) == {"notes.txt": b"the user's own"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]


def test_a_second_import_into_a_folder_being_written_is_refused(exported, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    holder = _writer_process(out)
    try:
        code, _, err = run_hec(_folder_import(exported, out, "--no-check"))
        assert code == 2 and f"{out}: another hec run (process {holder.pid}) is writing it now" in err, err
        assert not out.exists()
    finally:
        holder.communicate("finish\n")
    assert holder.returncode == 0 and _frame_count(out) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_a_dataset_that_appears_while_a_run_writes_is_kept(tmp_path: Path) -> None:
    """The first of two runs to finish keeps its dataset; the second fails and writes nothing."""
    out = tmp_path / "ds"
    with DatasetWriter(out, None, None, 0.001, "import") as writer:
        writer.add_pose(np.eye(4), 0.0)
        holder = _writer_process(tmp_path / "other")
        holder.communicate("finish\n")
        (tmp_path / "other").rename(out)
        with pytest.raises(FileExistsError, match="appeared while this run wrote it"):
            writer.finish()
    assert _frame_count(out) == 1 and [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_the_leftover_of_a_killed_import_is_removed_by_the_next(exported, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    holder = _writer_process(out)
    holder.kill()
    holder.communicate()
    assert len(list(tmp_path.glob(".ds.partial-*"))) == 1
    code, _, err = run_hec(_folder_import(exported, out, "--no-check"))
    assert code == 0, err
    assert [p.name for p in tmp_path.iterdir()] == ["ds"] and len(load_dataset(out)) == 17


def test_an_import_whose_check_fails_leaves_nothing_and_the_rerun_works(exported, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    code, _, err = run_hec(_folder_import(exported, out, "--board", "chessboard_10x5"))
    assert code == 2 and "too few frames: 0 usable of 17" in err, err
    assert list(tmp_path.iterdir()) == []
    code, stdout, err = run_hec(_folder_import(exported, out))
    assert code == 0 and f"cached in {out / 'detections.json'}" in stdout, err
    assert (out / "detections.json").is_file()


def test_ctrl_c_during_an_import_leaves_nothing(exported, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    process = subprocess.Popen(
        [sys.executable, "-m", "hec.cli", *_folder_import(exported, out)],
        cwd=REPO,
        env=os.environ | {"PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_for(".ds.partial-*/dataset.json", tmp_path, process)  # written, now being checked
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130 and "interrupted" in err, err
    assert list(tmp_path.iterdir()) == []


# --- sweep: a run and its --resume never share the folder -----------------------------------------

TINY_SWEEP = """
fidelity = "measurements"
seed = 5
trials = 2
methods = ["opencv-park"]

[fixed]
mount = "random"
waypoints = 6
"""
HOLD_LOCK = """
import sys
from hec.estimator.io.lock import acquire_lock
acquire_lock(sys.argv[1], "a sweep")
print("locked", flush=True)
sys.stdin.readline()
"""


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A finished two-trial sweep: its config file and folder."""
    root = tmp_path_factory.mktemp("sweep")
    (root / "tiny.toml").write_text(TINY_SWEEP)
    code, _, err = run_hec(
        ["sweep", str(root / "tiny.toml"), "--out", str(root / "out"), "--workers", "1", "--quiet"]
    )
    assert code == 0, err
    return root / "tiny.toml", root / "out"


def test_a_finished_sweep_leaves_no_lock(tiny_sweep: tuple[Path, Path]) -> None:
    _, out = tiny_sweep
    assert not (out / LOCK_FILE).exists() and (out / "rows.csv").is_file()


@pytest.mark.parametrize("resume", [True, False])
def test_a_sweep_into_a_folder_another_sweep_holds_is_refused(
    tiny_sweep: tuple[Path, Path], tmp_path: Path, resume: bool
) -> None:
    config, finished = tiny_sweep
    out = shutil.copytree(finished, tmp_path / "out") if resume else tmp_path / "out"
    out.mkdir(exist_ok=True)
    before = _snapshot(out)
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD_LOCK, str(out)],
        cwd=REPO,
        env=os.environ | {"PYTHONPATH": str(REPO)},
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        argv = ["sweep", str(config), "--out", str(out), "--workers", "1", "--quiet"] + ["--resume"] * resume
        code, _, err = run_hec(argv)
        assert code == 2 and f"a sweep is in progress there (process {holder.pid}" in err, err
        assert {k: v for k, v in _snapshot(out).items() if k != LOCK_FILE} == before
    finally:
        holder.communicate("\n")
    code, _, err = run_hec(["sweep", str(config), "--out", str(out), "--workers", "1", "--quiet", "--resume"])
    assert code == 0 and not (out / LOCK_FILE).exists(), err
    assert not same_rows(load_rows(out), load_rows(finished))  # every trial once, as the first run's
