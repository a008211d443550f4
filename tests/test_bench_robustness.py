"""The robustness benchmark's core: two measurement trials of two cases give a table with a row per
method and the default method's acceptance lines."""

from __future__ import annotations

import pytest

from hec.bench.robustness import CASES, format_case, run_cases
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS


@pytest.mark.needs("sim")
def test_two_cases_give_every_row_and_the_acceptance_lines() -> None:
    cases = [c for c in CASES if c.key in ("measurements: ideal", "measurements: arm noise 3x")]
    assert len(cases) == 2
    summaries = run_cases(cases, trials=2, seed=0, workers=1, progress=False)
    assert list(summaries) == [c.key for c in cases]
    for key, summary in summaries.items():
        lines = format_case(key, summary)
        assert lines[0].strip() == f"## {key} (2 trials)"
        rows = {line.split()[0] for line in lines[2:] if line.split() and line.split()[0] in METHODS}
        assert rows == set(METHODS)
        default = summary["methods"][DEFAULT_METHOD]
        assert default["failures"] == 0 and default["mean_nees"] is not None
        acceptance = [line for line in lines if line.startswith("acceptance: ")]
        assert len(acceptance) == 3
        assert acceptance[0].startswith("acceptance: default median translation <= 0.8x best OpenCV: ")
        assert acceptance[1].startswith("acceptance: default median rotation <= 0.8x best OpenCV: ")
        assert acceptance[2].startswith("acceptance: mean NEES in [4, 9]: ")
        assert all(("PASS (" in line) != ("FAIL (" in line) for line in acceptance)
        assert any(line.startswith("Cramer-Rao bound at the truth: median RSS 1-sigma ") for line in lines)
        assert 0.0 < summary["crb_error_median_mm"] < summary["crb_median_mm"]
    # The arm's noise, 3x what is declared, is noticed.
    assert summaries["measurements: arm noise 3x"]["methods"][DEFAULT_METHOD]["warned"] > 0
