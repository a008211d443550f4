"""`hec report` on rows from real measurement-level trials: its numbers, its HTML and its errors."""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from hec.commands import report as report_command
from hec.estimator.geometry.lie import pose_minus
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.methods import run_method
from hec.estimator.solve.observability import observability
from hec.estimator.solve.problem import CalibrationInputError, build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, T_BASE_BOARD, random_mount, scene
from hec.sweep import report, summary
from hec.sweep import rows as row_schema

# opencv-andreff finds no solution on an orbit (the default views' angles at one distance to the
# board): real failed rows.
METHODS = ("ekf", "iekf", "opencv-tsai", "opencv-andreff")
PIXEL_SIGMAS = {"c0": 0.3, "c1": 1.0}
TRIALS_PER_CELL = 3
SEED = 5
# What a failed row has no value for (its trial's Cramer-Rao bound it keeps).
FAILED_NAN = (
    "error_translation_mm",
    "error_rotation_deg",
    "sigma_translation_mm",
    "sigma_rotation_deg",
    "nees",
    "time_s",
    "warnings",
)


def _rss(values: np.ndarray | None) -> float:
    return math.nan if values is None else float(np.sqrt(np.sum(np.square(values))))


def make_rows() -> list[dict]:
    """One row per trial x method as the sweep's row contract says, from real estimator runs."""
    rows = []
    for c, (cell, pixel_sigma) in enumerate(PIXEL_SIGMAS.items()):
        noise = SyntheticNoise(corner_sigma_px=pixel_sigma)
        for trial in range(TRIALS_PER_CELL):
            rng = np.random.default_rng([SEED, c, trial])
            X = random_mount(rng)
            observations = scene(X, rng, noise, trajectory="orbit")
            problem = build_problem(observations, BOARD, INTRINSICS, noise.robot)
            crb = observability(problem, HandEyeState(X, T_base_board=T_BASE_BOARD))
            observable = crb.crb_covariance is not None
            base = {
                "trial_id": f"{cell}-{trial}",
                "cell": cell,
                "fidelity": "measurements",
                "seed": f"{SEED}/{c}/{trial}",
                "pixel_sigma_px": pixel_sigma,
                "mount": "random",
                "crb_translation_mm": _rss(crb.crb_sigma_translation_mm) if observable else math.nan,
                "crb_rotation_deg": _rss(crb.crb_sigma_rotation_deg) if observable else math.nan,
            }
            for method in METHODS:
                row = {**base, "method": method}
                try:
                    result = run_method(method, problem, MethodOptions(), observations)
                except CalibrationInputError as exc:
                    nan = dict.fromkeys(FAILED_NAN, math.nan)
                    rows.append({**row, **nan, "status": "failed", "failure": str(exc)})
                    continue
                dt, dr = pose_error(result.T_flange_cam, X)
                nees = math.nan
                if result.covariance is not None:
                    delta = pose_minus(X, result.T_flange_cam)
                    nees = float(delta @ np.linalg.solve(result.covariance, delta))
                row |= {
                    "status": "ok",
                    "failure": "",
                    "error_translation_mm": 1e3 * dt,
                    "error_rotation_deg": float(np.degrees(dr)),
                    "sigma_translation_mm": _rss(result.sigma_translation_mm),
                    "sigma_rotation_deg": _rss(result.sigma_rotation_deg),
                    "nees": nees,
                    "time_s": result.diagnostics["time_s"],
                    "warnings": float(len(result.warnings)),
                }
                rows.append(row)
    return rows


def write_rows(out_dir: Path, rows: list[dict]) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    columns = [*summary.ROW_COLUMNS[:4], "pixel_sigma_px", "mount", *summary.ROW_COLUMNS[4:]]
    with (out_dir / row_schema.ROWS_FILE).open("w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(rows)


@pytest.fixture(scope="module")
def rows() -> list[dict]:
    return make_rows()


@pytest.fixture(scope="module")
def built(rows: list[dict], tmp_path_factory: pytest.TempPathFactory) -> report.Report:
    out_dir = tmp_path_factory.mktemp("sweep")
    write_rows(out_dir, rows)
    sweep = {
        "format": "hec-sweep",
        "config": {"seed": 3, "methods": list(METHODS)},
        "software": {"numpy": "9.9"},
    }
    (out_dir / row_schema.META_FILE).write_text(json.dumps(sweep))
    return report.build_report(out_dir)


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="hec")
    sub = parser.add_subparsers(dest="command", required=True)
    report_command.add_parser(sub)
    return report_command.run(parser.parse_args(argv))


def test_rows_read_back_typed(rows: list[dict], built: report.Report) -> None:
    read = summary.load_report_rows(built.html.parent)
    assert len(read) == len(rows)
    for mine, theirs in zip(rows, read, strict=True):
        assert theirs["seed"] == mine["seed"] and isinstance(theirs["pixel_sigma_px"], float)
        assert theirs["mount"] == "random"
        for column in row_schema.FLOAT_COLUMNS:
            assert theirs[column] == pytest.approx(mine[column], rel=1e-12, nan_ok=True)


def test_summary_matches_numpy(rows: list[dict], built: report.Report) -> None:
    summaries = {(s.cell, s.method): s for s in built.summaries}
    assert set(summaries) == {(cell, method) for cell in PIXEL_SIGMAS for method in METHODS}
    for (cell, method), s in summaries.items():
        mine = [r for r in rows if r["cell"] == cell and r["method"] == method]
        ok = [r for r in mine if r["status"] == "ok"]
        assert (s.trials, s.ok) == (len(mine), len(ok))
        assert s.success_rate == len(ok) / len(mine)
        assert s.parameters == {"pixel_sigma_px": PIXEL_SIGMAS[cell]}
        for stats, error_col, crb_col in (
            (s.translation_mm, "error_translation_mm", "crb_translation_mm"),
            (s.rotation_deg, "error_rotation_deg", "crb_rotation_deg"),
        ):
            if not ok:
                assert math.isnan(stats.rms) and math.isnan(stats.ratio)
                continue
            e = np.array([r[error_col] for r in ok])
            b = np.array([r[crb_col] for r in ok])
            assert np.all(np.isfinite(b))
            assert stats.median == pytest.approx(np.median(e), rel=1e-9)
            assert stats.p95 == pytest.approx(np.percentile(e, 95), rel=1e-9)
            assert stats.rms == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-9)
            assert stats.ratio == pytest.approx(np.sqrt(np.mean(e**2)) / np.sqrt(np.mean(b**2)), rel=1e-9)
        if method in ("ekf", "iekf"):  # the estimators reach the bound; OpenCV does not report NEES
            assert s.translation_mm.ratio < 3.0 and s.rotation_deg.ratio < 3.0
            assert s.mean_nees == pytest.approx(np.mean([r["nees"] for r in ok]), rel=1e-9)
        else:
            assert math.isnan(s.mean_nees)


def test_failed_rows_count_in_success_rate(rows: list[dict], built: report.Report) -> None:
    failed = [r for r in rows if r["status"] == "failed"]
    assert failed, "the test needs a method that fails on these views"
    for s in built.summaries:
        n_failed = sum(1 for r in failed if r["cell"] == s.cell and r["method"] == s.method)
        assert s.trials == TRIALS_PER_CELL and s.ok == TRIALS_PER_CELL - n_failed
        assert sum(s.failures.values()) == n_failed
    andreff = [s for s in built.summaries if s.method == "opencv-andreff"]
    assert all(s.success_rate < 1.0 for s in andreff)
    page = built.html.read_text()
    assert f"0/{TRIALS_PER_CELL} (0 %)" in page
    assert "OpenCV found no solution" in page


def test_html_embeds_plots_methods_and_cells(built: report.Report) -> None:
    page = built.html.read_text()
    plots = sorted(p.name for p in (built.html.parent / report.PLOTS_DIR).glob("*.png"))
    assert plots == ["boxes.png", "convergence.png", "error_vs_pixel_sigma_px.png"]
    assert page.count('<img src="data:image/png;base64,') == len(plots) == built.images
    for method in METHODS:
        assert f"<td class=name>{method}</td>" in page
    for cell in PIXEL_SIGMAS:
        assert f"cell {cell} " in page
    ekf = next(s for s in built.summaries if s.method == "ekf" and s.cell == "c1")
    assert report.fmt(ekf.translation_mm.rms) in page and report.fmt(ekf.rotation_deg.ratio, ".2f") in page
    assert "Rendered example" not in page  # measurement fidelity only
    assert "swept: pixel_sigma_px; fixed: mount = random." in page
    assert "software: numpy</td><td class=name>9.9" in page and "(ekf, representative trial, seed 3)" in page
    assert not list(built.html.parent.glob(".*partial*"))


def test_render_fidelity_embeds_the_example_or_says_it_is_missing(rows: list[dict], tmp_path: Path) -> None:
    render_rows = [{**r, "fidelity": "render"} for r in rows if r["method"] in ("ekf", "opencv-andreff")]
    write_rows(tmp_path, render_rows)
    (tmp_path / report.PLOTS_DIR).mkdir()
    (tmp_path / report.PLOTS_DIR / "error_vs_mount.png").write_bytes(b"from an earlier report")
    page = report.build_report(tmp_path).html.read_text()
    assert not (tmp_path / report.PLOTS_DIR / "error_vs_mount.png").exists()
    assert "Rendered example" in page and "No detection overlay" in page and "No overview picture" in page
    png = (tmp_path / report.PLOTS_DIR / "boxes.png").read_bytes()
    for name in (report.EXAMPLE_OVERVIEW, "example/overlay/000003.png"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(png)
    built = report.build_report(tmp_path)
    page = built.html.read_text()
    assert "No detection overlay" not in page and "example/overlay/000003.png" in page
    assert page.count('<img src="data:image/png;base64,') == built.images == 3 + 2


def test_missing_or_empty_folder_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert _run(["report", str(tmp_path / "nowhere")]) == 2
    assert "nowhere: folder does not exist" in capsys.readouterr().err
    assert _run(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'rows.csv'}: file missing" in err and "hec sweep" in err
    write_rows(tmp_path, [])
    assert _run(["report", str(tmp_path)]) == 2
    assert "no result rows" in capsys.readouterr().err
    assert not (tmp_path / report.REPORT_FILE).exists()


def test_bad_value_names_file_line_and_column(rows: list[dict], tmp_path: Path) -> None:
    write_rows(tmp_path, [rows[0], {**rows[1], "error_rotation_deg": "abc"}])
    with pytest.raises(summary.ReportError, match=r"rows.csv, line 3, column 'error_rotation_deg'"):
        report.build_report(tmp_path)
    write_rows(tmp_path, [{**rows[0], "status": "done"}])
    with pytest.raises(summary.ReportError, match=r"column 'status' must be one of ok, failed"):
        report.build_report(tmp_path)


def test_cli_prints_where_the_report_is(
    rows: list[dict], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    write_rows(tmp_path, [r for r in rows if r["method"] == "ekf"])
    assert _run(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"report: {tmp_path / 'report.html'}" in out and "ekf" in out


def test_convergence_ends_at_the_ekf_estimate_with_its_covariance() -> None:
    rng = np.random.default_rng(11)
    X = random_mount(rng)
    observations = scene(X, rng, SyntheticNoise())
    problem = build_problem(observations, BOARD, INTRINSICS, SyntheticNoise().robot)
    conv = summary.convergence(problem, X, MethodOptions())
    result = run_method("ekf", problem, MethodOptions(), observations)
    assert conv.method == "ekf" and conv.error.shape == conv.sigma.shape == (len(conv.waypoints), 6)
    assert conv.waypoints[-1] == len(problem.frames) and np.all(np.diff(conv.waypoints) == 1)
    np.testing.assert_allclose(conv.error[-1], pose_minus(result.T_flange_cam, X), atol=1e-12)
    np.testing.assert_allclose(conv.sigma[-1], np.sqrt(np.diag(result.covariance)), rtol=1e-9)
    assert np.all(conv.sigma[-1] < conv.sigma[0])  # the band narrows as waypoints come in


def test_an_unfinished_sweep_says_which_trials_and_cells_are_missing(
    rows: list[dict], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Rows of cell c0 only (one trial without ekf) of a three-cell sweep: the page and the terminal
    say what is missing."""

    def sweep_id(row: dict) -> str:
        return row_schema.trial_id(int(row["cell"][1:]), int(row["trial_id"].split("-")[1]))

    present = [
        {**r, "trial_id": sweep_id(r)}
        for r in rows
        if r["cell"] == "c0" and not (r["method"] == "ekf" and r["trial_id"].endswith("-2"))
    ]
    write_rows(tmp_path, present)
    cells = [{"cell": f"c{i}", "index": i, "parameters": {}} for i in range(3)]
    sweep = {"config": {"cells": cells, "trials": TRIALS_PER_CELL, "methods": list(METHODS)}}
    (tmp_path / row_schema.META_FILE).write_text(json.dumps(sweep))
    assert _run(["report", str(tmp_path)]) == 0
    expected = "unfinished sweep: 6 of 9 trials missing (no trial at all of cells c1, c2); 1 method rows"
    assert expected in capsys.readouterr().err
    assert expected in (tmp_path / report.REPORT_FILE).read_text()
