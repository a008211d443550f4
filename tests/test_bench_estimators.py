"""The Monte-Carlo benchmark runs end to end and reports every method and acceptance figure."""

from __future__ import annotations

import json
from pathlib import Path

from hec.bench.estimators import CASES, main
from hec.estimator.solve.methods import METHODS


def test_benchmark_reports_every_method_case_and_check(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    page = tmp_path / "estimators.md"
    main(["--trials", "3", "--workers", "1", "--timing-rounds", "1", "--json", str(out), "--page", str(page)])
    data = json.loads(out.read_text())
    assert set(data["summaries"]) == set(CASES)
    rows = data["summaries"]["robot noise"]["methods"]
    assert set(rows) == set(METHODS)
    for method in ("ekf", "iekf", "ukf", "batch"):
        assert rows[method]["failures"] == 0
        assert rows[method]["ratio_translation"] < 2.0 and rows[method]["ratio_rotation"] < 2.0
    assert len(data["acceptance"]) == 2 * (3 + 4) + 2  # accuracy, NEES per case; two OpenCV gains
    assert data["time_s"]["ekf"] > 0.0
    assert page.with_suffix(".png").stat().st_size > 10_000
    text = page.read_text()
    assert text.startswith("# Estimators against the bound\n")
    assert "`python -m hec.bench.estimators --trials 3" in text and "## acceptance" in text
    assert "(estimators.png)" in text and "## time for" in text
