"""The regression check: the whole pipeline (render, detect, ekf) on the baseline's 10-view scenario and
seed must stay within the bounds of experiments/regress/baseline.json; the rule itself fails a result
much worse than the recorded figure, or beyond the loose bound; a bad baseline file gets a clear error.

The pipeline runs three times here (about 1.3 s each): the check itself, and `hec regress` twice.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from dataclasses import replace
from pathlib import Path

import pytest

from hec.commands.regress import compare, explain, main, measure, trial_scenario
from hec.regress.baseline_file import (
    DEFAULT_BASELINE,
    Baseline,
    BaselineError,
    Measurement,
    Threshold,
    load_baseline,
)


@pytest.fixture(scope="module")
def baseline() -> Baseline:
    return load_baseline(DEFAULT_BASELINE)


def test_pipeline_within_the_baseline(baseline: Baseline, tmp_path: Path) -> None:
    """The CI check: trial 1 of `hec regress`, through the same functions."""
    measurement = measure(baseline, trial_scenario(baseline, tmp_path), baseline.seed, tmp_path)
    result = compare(measurement, baseline)
    assert result.passed, "\n".join(explain(result, baseline))
    assert measurement.frames == len(baseline.views_deg)
    assert [c.kind for c in result.checks] == ["relative", "relative"]


def _recorded(baseline: Baseline) -> Measurement:
    return baseline.recorded[baseline.seed]


@pytest.mark.parametrize("quantity", ["translation_mm", "rotation_deg"])
def test_much_worse_than_recorded_fails_inside_the_loose_bound(baseline: Baseline, quantity: str) -> None:
    recorded = _recorded(baseline)
    threshold = baseline.thresholds[quantity]
    relative = threshold.factor * getattr(recorded, quantity) + threshold.floor
    assert relative < threshold.absolute, "the relative bound must be the tighter one for this test"
    assert compare(recorded, baseline).passed
    assert compare(replace(recorded, **{quantity: 0.99 * relative}), baseline).passed
    worse = replace(recorded, **{quantity: 0.5 * (relative + threshold.absolute)})
    result = compare(worse, baseline)
    assert not result.passed
    check = next(c for c in result.checks if c.quantity == quantity)
    assert check.kind == "relative" and check.measured < threshold.absolute
    (line,) = explain(result, baseline)
    assert f"{threshold.factor:g} x recorded" in line


@pytest.mark.parametrize("quantity", ["translation_mm", "rotation_deg"])
def test_beyond_the_loose_bound_fails(baseline: Baseline, quantity: str) -> None:
    absolute = baseline.thresholds[quantity].absolute
    unrecorded_seed = max(baseline.recorded) + 1000
    far = Measurement(unrecorded_seed, 0.0, 0.0, 10)
    assert compare(far, baseline).passed
    result = compare(replace(far, **{quantity: 1.01 * absolute}), baseline)
    assert not result.passed and "absolute bound" in explain(result, baseline)[0]
    # A loose relative rule is capped by the absolute bound.
    lax = replace(
        baseline,
        thresholds={q: Threshold(t.absolute, 100.0, t.floor) for q, t in baseline.thresholds.items()},
    )
    recorded = replace(_recorded(baseline), **{quantity: 1.01 * absolute})
    assert not compare(recorded, lax).passed


def test_not_finite_or_pipeline_failure_fails(baseline: Baseline) -> None:
    assert not compare(replace(_recorded(baseline), rotation_deg=math.nan), baseline).passed
    failed = compare(Measurement(baseline.seed, failure="SimulationError: no waypoint"), baseline)
    assert not failed.passed and "pipeline failed" in explain(failed, baseline)[0]


def _edit(document: dict, dotted: str, value: object) -> None:
    """Set (or with value ... delete) the field at a dotted path; list indices are numbers."""
    *parents, last = [int(p) if p.isdigit() else p for p in dotted.split(".")]
    for p in parents:
        document = document[p]
    if value is ...:
        del document[last]
    else:
        document[last] = value


@pytest.mark.parametrize(
    ("field", "value", "named"),
    [
        ("thresholds.translation_mm.floor", ..., "thresholds.translation_mm.floor"),
        ("thresholds.rotation_deg.factor", 0.5, "thresholds.rotation_deg.factor"),
        ("thresholds.rotation_deg.absolute", "0.1", "thresholds.rotation_deg.absolute"),
        ("scenario.views_deg.2", [20, 0], "scenario.views_deg[2]"),
        ("scenario.seed", -1, "scenario.seed"),
        ("scenario.settings.noise.rgb.sigma", -2.0, "scenario.settings"),
        ("scenario.settings.camera.colour", True, "scenario.settings"),
        ("recorded.trials.0.translation_mm", None, "recorded.trials[0].translation_mm"),
        ("recorded.trials", [], "recorded.trials"),
        ("method", "kalman", "method"),
        ("version", 2, "version"),
    ],
)
def test_malformed_baseline_names_file_and_field(
    tmp_path: Path, field: str, value: object, named: str
) -> None:
    document = json.loads(DEFAULT_BASELINE.read_text())
    _edit(document, field, value)
    path = tmp_path / "baseline.json"
    path.write_text(json.dumps(document))
    with pytest.raises(BaselineError) as info:
        load_baseline(path)
    message = str(info.value)
    assert str(path) in message and named in message, message


def _regress(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def test_command_errors_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "baseline.json"
    path.write_text("{not json")
    code, _, err = _regress("--baseline", str(path))
    assert code == 2 and f"{path}: not valid JSON" in err
    code, _, err = _regress("--baseline", str(tmp_path / "missing.json"))
    assert code == 2 and "missing.json: baseline file missing" in err
    (tmp_path / "keep").mkdir()
    (tmp_path / "keep" / "data.txt").write_text("mine")
    code, _, err = _regress("--keep", str(tmp_path / "keep"))
    assert code == 2 and "new or empty folder" in err
    assert (tmp_path / "keep" / "data.txt").read_text() == "mine"


@pytest.mark.needs("sim")
def test_command_fails_a_regression_and_update_records_the_new_figure(
    baseline: Baseline, tmp_path: Path
) -> None:
    """A baseline that claims a much better figure than the code gives: `hec regress` fails (exit 1);
    --update records the real figure and says what changed."""
    document = json.loads(DEFAULT_BASELINE.read_text())
    trial = next(t for t in document["recorded"]["trials"] if t["seed"] == baseline.seed)
    trial["translation_mm"] = 0.01
    path = tmp_path / "baseline.json"
    path.write_text(json.dumps(document))
    code, out, _ = _regress("--baseline", str(path))
    assert code == 1
    assert f"FAIL seed {baseline.seed}: translation error" in out and "2 x recorded 0.01 + 0.05" in out
    code, out, _ = _regress("--baseline", str(path), "--update", "--keep", str(tmp_path / "runs"))
    assert code == 0 and f"seed {baseline.seed}: 0.01000 -> " in out
    updated = load_baseline(path).recorded[baseline.seed]
    before = _recorded(baseline)
    floors = {q: t.floor for q, t in baseline.thresholds.items()}
    assert abs(updated.translation_mm - before.translation_mm) <= floors["translation_mm"]
    assert abs(updated.rotation_deg - before.rotation_deg) <= floors["rotation_deg"]
    recorded = json.loads(path.read_text())["recorded"]
    assert [t["seed"] for t in recorded["trials"]] == [baseline.seed]
    assert recorded["command"] == f"hec regress --trials 1 --baseline {path} --update"
    assert (tmp_path / "runs" / f"seed-{baseline.seed:04d}" / "detections.json").is_file()
