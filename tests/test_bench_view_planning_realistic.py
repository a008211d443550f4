"""The realistic-cell view-planning benchmark's summary: medians per strategy and count, the ratio to
the default list and the acceptance line at TARGET_RATIO (rows as run_placement writes them)."""

from __future__ import annotations

from hec.bench.view_planning_realistic import COUNTS, STRATEGIES, TARGET_RATIO, acceptance, summarise


def _placement(index: int, errors_mm: dict[str, float]) -> dict:
    run = {
        name: {"error_mm": e, "error_deg": 0.1, "nees": 6.0, "floor_mm": 0.3, "error_vs_reachable_mm": e}
        for name, e in errors_mm.items()
    }
    keys = [str(c) for c in COUNTS] + ["all"]
    return {"placement": index, "frames": 15, "runs": {k: dict(run) for k in keys}}


def test_the_summary_compares_each_plan_with_the_default_at_the_same_count() -> None:
    better = [_placement(i, {"mount-only": 1.0, "self-calibrated": 0.7, "default": 1.0}) for i in range(3)]
    worse = [_placement(3, {"mount-only": 1.0, "self-calibrated": 5.0, "default": 1.0})]
    summary = summarise(better + worse)
    rows = summary["all"]["strategies"]
    assert set(rows) == set(STRATEGIES)
    assert rows["self-calibrated"]["median_error_mm"] == 0.7  # the median, not the mean
    assert rows["self-calibrated"]["ratio_to_default"] == 0.7 <= TARGET_RATIO
    assert all(passed for _, passed in acceptance(summary))
    summary = summarise(worse)
    assert not any(passed for _, passed in acceptance(summary))
