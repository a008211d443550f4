"""Faults of the commands that came after the first fault pass (export, import, plan, sweep --resume):
an output never replaces an input, frame names and numbers fit the format they go into, and a
file system that cannot take a write is one line in hec's words."""

from __future__ import annotations

import json
import os
import shlex
import stat
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from tests.hec_cli import run_hec
from tests.test_export import _calibration_file

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
