"""The findings benchmark (hec.bench.findings) counts a trial as right only when every finding given
as advice names the cell's true source, and has a cell for every error source the simulator has."""

from __future__ import annotations

from hec.bench.findings import CELLS, GROUPS, FindingsCell, summarise
from hec.estimator.solve.self_calibration import NUISANCE_GROUPS
from hec.sweep.parameters import ERROR_SOURCES, error_source_set


def _record(advice: list[str], cannot_tell: list[str] = (), failure: str = "") -> dict:
    return {"advice": advice, "cannot_tell": list(cannot_tell), "failure": failure, "error_mm": 0.1}


def test_advice_naming_another_group_is_a_miss_and_no_advice_is_not() -> None:
    cell = FindingsCell("print scale", "board", ("board_scale",))
    records = [
        _record(["board_scale"]),
        _record(["board_scale", "intrinsics"]),
        _record([], ["depth_bias"]),
        _record([], failure="simulation: no view"),
    ]
    s = summarise(cell, records)
    assert s["trials"] == 3 and s["failures"] == 1
    assert s["right_share"] == 2 / 3
    assert s["true_advised_share"] == 2 / 3
    assert s["wrong_advised_share"] == 1 / 3 and s["wrong_groups"] == ["intrinsics"]
    assert s["cannot_tell_share"] == 1 / 3 and s["cannot_tell_groups"] == ["depth_bias"]


def test_on_the_ideal_cell_any_advice_is_a_miss() -> None:
    s = summarise(FindingsCell("ideal", "none", ()), [_record([]), _record(["kinematics"])])
    assert s["right_share"] == 0.5


def test_every_error_source_of_the_simulator_has_a_cell_and_names_real_groups() -> None:
    sources = {s for c in CELLS for s in error_source_set(c.error_sources)}
    assert sources == set(ERROR_SOURCES)
    assert any(c.error_sources == "none" for c in CELLS)
    assert set(GROUPS) == set(NUISANCE_GROUPS)
    assert all(set(c.truth) <= set(GROUPS) for c in CELLS)
