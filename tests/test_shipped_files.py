"""Every file hec ships loads with today's formats: the boards, scenarios, sweeps, cell files and
the regression baseline. A board reads back as what it was written from: its file's content, its
notes (description, frame, corner_order) aside, is exactly what the board writes again."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hec.estimator.io.board_file import board_from_dict, board_to_dict, load_board
from hec.estimator.targets.board import BoardDefinition
from hec.estimator.targets.qr_symbol import SymbolSpec
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


@pytest.mark.parametrize("name", ["hec_8qr", "qr_18_tight"])
def test_a_qr_board_file_gives_the_board_it_states(name: str) -> None:
    """The board built field by field from the file, as the hand-written reader built it."""
    d = json.loads((MODELS / "boards" / f"{name}.json").read_text())
    prefix, version, level = d["payload_prefix"], d["qr_version"], d["qr_error_correction"]
    expected = BoardDefinition(
        name=d["name"],
        size_m=(float(d["size_m"][0]), float(d["size_m"][1])),
        marker_size_m=float(d["marker_size_m"]),
        qr_version=version,
        qr_error_correction=level,
        payload_prefix=prefix,
        marker_centers_m={m["id"]: (float(m["center_m"][0]), float(m["center_m"][1])) for m in d["markers"]},
        marker_symbols={m["id"]: SymbolSpec(f"{prefix}{m['id']:02d}", version, level) for m in d["markers"]},
    )
    assert load_board(MODELS / "boards" / f"{name}.json") == expected


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
