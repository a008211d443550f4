"""The Monte-Carlo benchmark runs end to end and reports every method and acceptance figure."""

from __future__ import annotations

import json
from pathlib import Path

from hec.bench.estimators import CASES, main
from hec.estimator.solve.methods import METHODS


def test_benchmark_reports_every_method_case_and_check(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    plot = tmp_path / "bench.png"
    main(["--trials", "3", "--workers", "1", "--timing-rounds", "1", "--json", str(out), "--plot", str(plot)])
    data = json.loads(out.read_text())
    assert set(data["summaries"]) == set(CASES)
    rows = data["summaries"]["robot noise"]["methods"]
    assert set(rows) == set(METHODS)
    for method in ("ekf", "iekf", "ukf", "batch"):
        assert rows[method]["failures"] == 0
        assert rows[method]["ratio_translation"] < 2.0 and rows[method]["ratio_rotation"] < 2.0
    assert len(data["acceptance"]) == 2 * (3 + 4) + 2  # accuracy, NEES per case; two OpenCV gains
    assert data["time_s"]["ekf"] > 0.0
    assert plot.stat().st_size > 10_000
