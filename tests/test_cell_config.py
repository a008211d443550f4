"""Real-cell files: the example spells out the defaults, and bad keys are named."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hec.session.cell_config import CellConfig, CellConfigError, load_cell_config

EXAMPLE = Path(__file__).resolve().parent.parent / "models" / "cells" / "ur5_d435.toml"


def test_the_example_spells_out_the_code_defaults() -> None:
    assert load_cell_config(EXAMPLE).to_dict() == CellConfig().to_dict()
    text = EXAMPLE.read_text()
    for key in ("host", "serial"):
        assert re.search(rf"^# {key} = ", text, re.MULTILINE), f"optional key {key} not shown commented out"


def test_settings_reach_the_robot_and_camera_in_their_units(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(
        '[robot]\nhost = "10.0.0.2"\njoint_speed_deg_s = 90\n[camera]\nserial = "42"\nburst = 3\n'
    )
    config = load_cell_config(path)
    assert config.robot.host == "10.0.0.2"
    assert config.robot.motion().joint_speed == pytest.approx(np.pi / 2)
    assert config.robot.limits().joint_upper_rad[2] == pytest.approx(np.pi)
    assert config.robot.pose_noise().translation_sigma_m == pytest.approx(1e-4)
    settings = config.camera.realsense()
    assert settings.serial == "42" and settings.burst == 3
    assert config.camera.depth_noise(1e-4).depth_step_m == 1e-4


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ("[robot]\nhots = 'x'\n", ["robot.hots", "unknown key"]),
        ("[robot]\nworkspace_lower_m = [0, 0, 0]\nworkspace_upper_m = [1, 1, -1]\n", ["workspace_lower_m"]),
        ("[camera]\nfilters = ['median']\n", ["camera.filters.0", "'median'"]),
        ("[camera]\nburst = 0\n", ["camera.burst"]),
        ("[robot\n", ["not valid TOML"]),
    ],
)
def test_bad_files_name_the_file_and_the_key(tmp_path: Path, toml: str, expected: list[str]) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(toml)
    with pytest.raises(CellConfigError) as error:
        load_cell_config(path)
    for text in [str(path), *expected]:
        assert text in str(error.value)


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(CellConfigError, match="cell file not found"):
        load_cell_config(tmp_path / "nope.toml")
