"""Every file hec ships loads with today's formats: the boards, scenarios, sweeps, cell files and
the regression baseline. A board reads back as what it was written from: its file's content, its
notes (description, frame, corner_order) aside, is exactly what the board writes again."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hec.estimator.io.board_file import board_from_dict, board_to_dict, load_board
from hec.regress.baseline_file import load_baseline
from hec.session.cell_config import load_cell_config
from hec.sim.scenario import load_scenario
from hec.sweep.config import load_config

MODELS = Path(__file__).resolve().parent.parent / "models"
REGRESS = Path(__file__).resolve().parent.parent / "experiments" / "regress"
NOTES = ("description", "frame", "corner_order")


@pytest.mark.parametrize("path", sorted((MODELS / "boards").glob("*.json")), ids=lambda p: p.name)
def test_every_shipped_board_reads_back_as_its_file(path: Path) -> None:
    board = load_board(path)
    written = {k: v for k, v in json.loads(path.read_text()).items() if k not in NOTES}
    assert board_to_dict(board) == written
    assert board_from_dict(board_to_dict(board), "copy") == board
    assert len(board.marker_ids) >= 8


@pytest.mark.parametrize("path", sorted((MODELS / "scenarios").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_scenario_loads(path: Path) -> None:
    scenario = load_scenario(path)
    assert scenario.board_definition().marker_ids


@pytest.mark.parametrize("path", sorted((MODELS / "sweeps").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_sweep_loads(path: Path) -> None:
    assert load_config(path).to_dict()


@pytest.mark.parametrize("path", sorted((MODELS / "cells").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_cell_file_loads(path: Path) -> None:
    assert load_cell_config(path).to_dict()


def test_the_regression_baseline_loads() -> None:
    assert load_baseline(REGRESS / "baseline.json").recorded
