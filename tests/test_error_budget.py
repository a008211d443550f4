"""The error-budget sweep: error_sources switches the scenario's model-error sections, render
trials run with them, and the report's budget table and plot come from the rows."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hec.estimator.common.models import models_dir
from hec.sim.scenario import load_scenario
from hec.sweep import report
from hec.sweep.budget import TEXT_FILE, budget_text, has_budget
from hec.sweep.config import SweepConfigError, cell_scenario, load_config, scenario_defaults
from hec.sweep.page import paired_cost
from hec.sweep.parameters import ERROR_SOURCES, error_source_set, error_sources_name
from hec.sweep.rows import load_rows
from hec.sweep.runner import run_sweep
from hec.sweep.summary import summarise
from tests.hec_cli import run_hec

REALISTIC = models_dir() / "scenarios" / "realistic.toml"


def test_error_source_names_round_trip() -> None:
    assert error_source_set("none") == () and error_source_set("all") == ERROR_SOURCES
    assert error_source_set("depth+arm") == ("arm", "depth")
    assert error_sources_name(("depth", "arm")) == "arm+depth"
    assert error_sources_name(ERROR_SOURCES) == "all" and error_sources_name(()) == "none"
    with pytest.raises(ValueError, match="unknown error source"):
        error_source_set("arm+wind")


def test_error_sources_switch_exactly_the_named_sections() -> None:
    base = load_scenario(REALISTIC)
    assert scenario_defaults(base)["error_sources"] == "all"
    assert scenario_defaults(load_scenario(None))["error_sources"] == "none"
    params = {**scenario_defaults(base), "error_sources": "lens+board"}
    scenario = cell_scenario(base.to_dict(), str(REALISTIC.parent), params)
    on = {name for name in ERROR_SOURCES if getattr(scenario.errors, name).enabled}
    assert on == {"lens", "board"}
    # The magnitudes are the realistic scenario's, not the defaults.
    assert scenario.errors.board.bend_m == base.errors.board.bend_m
    assert scenario.errors.lens.true_coefficients == base.errors.lens.true_coefficients


def test_bad_error_sources_name_the_key(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text('fidelity = "render"\n[grid]\nerror_sources = ["arm", "weather"]\n')
    with pytest.raises(SweepConfigError, match="'grid.error_sources\\[1\\]'"):
        load_config(path)
    path.write_text('[grid]\nerror_sources = ["arm"]\n')  # measurement fidelity has no images
    with pytest.raises(SweepConfigError, match="error_sources"):
        load_config(path)


def test_budget_sweep_runs_and_reports(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    path = tmp_path / "budget.toml"
    path.write_text(
        'fidelity = "render"\ntrials = 3\nmethods = ["ekf", "opencv-park"]\n'
        f"scenario = {str(REALISTIC)!r}\n"
        '[fixed]\nwaypoints = 6\n[grid]\nerror_sources = ["none", "board"]\n'
    )
    out = tmp_path / "out"
    outcome = run_sweep(load_config(path), out, workers=1, progress=False)
    assert outcome.computed == 6 and not outcome.lost
    rows = load_rows(out)
    assert [r["error_sources"] for r in rows] == ["none"] * 6 + ["board"] * 6
    assert all(r["status"] == "ok" for r in rows), [r["failure"] for r in rows]

    def park_median_mm(source: str) -> float:
        park = [r for r in rows if r["error_sources"] == source and r["method"] == "opencv-park"]
        assert len(park) == 3
        return float(np.median([r["error_translation_mm"] for r in park]))

    # The realistic board (0.3 % scale, 0.7 mm bend) costs Park accuracy; the ideal cell does not.
    # Medians of three trials: on six waypoints one trial's noise can hide the print's bias.
    assert park_median_mm("none") < 1.0
    assert park_median_mm("board") > park_median_mm("none")

    built = report.build_report(out)
    assert (out / "plots" / "error_budget.png").is_file()
    assert "Error budget" in built.html.read_text()
    text = (out / TEXT_FILE).read_text().splitlines()
    assert text[0].split()[:2] == ["source", "method"] and len(text) == 1 + 4

    # The results page: a budget row per source, ekf beside Park (the only, so the best, OpenCV).
    code, stdout, stderr = run_hec(["report", str(out), "--page", str(tmp_path / "budget.md")])
    assert code == 0 and "page: " in stdout, stderr
    page = (tmp_path / "budget.md").read_text()
    assert page.startswith("# Sweep results: budget\n") and "Written by `hec report DIR" in page
    budget = page.split("## Error budget (medians)")[1].split("## ")[0]
    for source in ("none", "board"):
        cells = next(line for line in budget.splitlines() if line.startswith(f"| {source} |")).split(" | ")
        assert float(cells[3].split(" / ")[0]) == pytest.approx(park_median_mm(source), abs=1e-3)
        assert cells[4].startswith("park ") and cells[5].endswith("x") and cells[6] == "- |"  # unpaired

    # A page of a sweep still running (or stopped) says what it lacks.
    lines = (out / "rows.csv").read_text().splitlines(keepends=True)
    (out / "rows.csv").write_text("".join(lines[:-2]))  # the last trial's two method rows
    code, _, stderr = run_hec(["report", str(out), "--page", str(tmp_path / "partial.md")])
    assert code == 0 and "unfinished sweep: 1 of 6 trials missing" in stderr, stderr
    partial = (tmp_path / "partial.md").read_text()
    assert "**Not every trial is in these tables**: unfinished sweep: 1 of 6 trials missing" in partial
    assert "**Not every trial" not in page


def test_budget_table_gives_median_p95_and_mean_nees() -> None:
    rng = np.random.default_rng(3)
    rows = []
    for c, source in enumerate(("none", "arm")):
        for t in range(5):
            error = float(rng.uniform(0.1, 1.0)) * (1 + 9 * c)
            rows.append(
                {
                    "trial_id": f"c{c:02d}-t{t:04d}",
                    "cell": f"c{c:02d}",
                    "fidelity": "render",
                    "seed": f"0/{c}/{t}",
                    "error_sources": source,
                    "method": "ekf",
                    "status": "ok",
                    "failure": "",
                    "error_translation_mm": error,
                    "error_rotation_deg": error / 10,
                    "sigma_translation_mm": 0.1,
                    "sigma_rotation_deg": 0.01,
                    "nees": float(t),
                    "crb_translation_mm": 0.1,
                    "crb_rotation_deg": 0.01,
                    "time_s": 0.01,
                }
            )
    summaries = summarise(rows)
    assert has_budget(summaries)
    lines = budget_text(summaries).splitlines()
    for line, source in zip(lines[1:], ("none", "arm"), strict=True):
        errors = np.array([r["error_translation_mm"] for r in rows if r["error_sources"] == source])
        fields = line.split()
        assert fields[0] == source and fields[1] == "ekf"
        assert math.isclose(float(fields[2]), np.median(errors), abs_tol=1e-3)
        assert math.isclose(float(fields[3]), np.percentile(errors, 95), abs_tol=1e-3)
        assert math.isclose(float(fields[6]), 2.0, abs_tol=1e-2)  # mean of 0..4
        assert fields[7] == "5/5"
    assert not has_budget([s for s in summaries if s.parameters["error_sources"] == "arm"])

    # Paired: arm's extra error over the ideal cell, trial by trial (the same t in both cells).
    ideal, arm = (
        [r["error_translation_mm"] for r in rows if r["error_sources"] == c] for c in ("none", "arm")
    )
    differences = np.subtract(arm, ideal)
    mean, standard_error = paired_cost(rows, "ekf")["arm"].split(" +- ")
    assert math.isclose(float(mean), differences.mean(), abs_tol=1e-3)
    assert math.isclose(float(standard_error), differences.std(ddof=1) / np.sqrt(5), abs_tol=1e-3)
