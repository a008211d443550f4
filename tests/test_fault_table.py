"""The fault table over every verb (tests/fault_cases.py, classified by tests/fault_table.py): each
case must end in a clear refusal or be handled; none vague, silent, lost, left behind or a
traceback. `python -m tests.fault_table` prints the count per class."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.fault_cases import CASES, build_inputs
from tests.fault_table import Case, run_case


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return build_inputs(tmp_path_factory.mktemp("fault_table") / "inputs")


def test_the_table_has_at_least_150_cases_over_every_verb() -> None:
    from hec.commands.verbs import HELP

    verbs = {case.name.split()[0] for case in CASES} | {case.name.split()[1] for case in CASES}
    assert len(CASES) >= 150 and set(HELP) <= verbs


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_a_fault_ends_in_a_clear_refusal_or_is_handled(
    case: Case, inputs: dict[str, Path], tmp_path: Path
) -> None:
    try:
        kind, text = run_case(case, inputs, tmp_path / "work")
    except PermissionError:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    assert kind in ("clear", "handled"), f"{kind}\n{text}"
