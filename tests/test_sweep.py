"""`hec sweep`: reproducible rows wherever trials run (local processes, a Dask cluster, --resume,
--rerun), config errors that name the file and key, and one render-fidelity trial end to end."""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

import pytest

from hec.commands.sweep import add_parser, run
from hec.sweep.config import SweepConfigError, cell_scenario, load_config
from hec.sweep.rows import ROWS_FILE, SweepError, load_rows, row_columns
from hec.sweep.runner import rerun_trial, run_sweep, same_rows

SMALL = """
fidelity = "measurements"
seed = 3
trials = 3
methods = ["ekf", "batch", "opencv-park"]

[fixed]
mount = "random"
waypoints = 6

[grid]
pixel_sigma_px = [0.3, 1.0]
trajectory = ["rotation-rich", "random"]
"""
TRIALS = 4 * 3


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[dict]]:
    """The small sweep run on two local processes: its config file, output folder and rows."""
    root = tmp_path_factory.mktemp("sweep")
    config = root / "small.toml"
    config.write_text(SMALL)
    out = root / "local"
    outcome = run_sweep(load_config(config), out, workers=2, progress=False)
    assert outcome.computed == TRIALS and not outcome.lost
    return config, out, load_rows(out)


def test_rows_follow_the_schema(small: tuple[Path, Path, list[dict]]) -> None:
    _, out, rows = small
    assert len(rows) == TRIALS * 3
    assert (out / ROWS_FILE).read_text().splitlines()[0].split(",") == row_columns("measurements")
    first = rows[0]
    assert first["trial_id"] == "c00-t0000" and first["cell"] == "c00" and first["seed"] == "3/0/0"
    assert first["waypoints"] == 6 and first["pixel_sigma_px"] == 0.3 and first["mount"] == "random"
    assert [r["method"] for r in rows[:3]] == ["ekf", "batch", "opencv-park"]
    for r in rows:
        assert r["status"] == "ok" and r["failure"] == ""
        # Park on 6 views with 1 px corners reaches 11.6 mm (the bound there is 0.8 mm); hec's
        # methods stay within 1 mm.
        largest = 25.0 if r["method"] == "opencv-park" else 10.0
        assert 0 < r["error_translation_mm"] < largest and math.isfinite(r["crb_translation_mm"])
    park = [r for r in rows if r["method"] == "opencv-park"]
    assert all(math.isnan(r["nees"]) and math.isnan(r["sigma_translation_mm"]) for r in park)


def test_dask_cluster_gives_the_local_rows_bit_for_bit_with_few_trials_in_flight(
    small: tuple[Path, Path, list[dict]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from distributed import LocalCluster

    from hec.sweep import runner

    config, _, local = small
    monkeypatch.setattr(runner, "DASK_TRIALS_IN_FLIGHT", 1)
    monkeypatch.setattr(runner, "DASK_MIN_IN_FLIGHT", 3)
    clients, held = [], []  # the sweep's client; the trials it holds whenever rows arrive
    connect, format_rows = runner._dask_client, runner.format_rows
    monkeypatch.setattr(
        runner, "_dask_client", lambda address: clients.append(connect(address)) or clients[0]
    )
    monkeypatch.setattr(
        runner, "format_rows", lambda *a: held.append(len(clients[0].futures)) or format_rows(*a)
    )
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        outcome = run_sweep(
            load_config(config), tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False
        )
    assert outcome.computed == TRIALS and not outcome.lost
    assert same_rows(load_rows(tmp_path / "dask"), local) == []
    assert len(held) == TRIALS and max(held) <= 3  # of 12: the rest waited to be submitted


def _copied(small: tuple[Path, Path, list[dict]], folder: Path) -> tuple[Path, Path]:
    """The small sweep's config file and a copy of its output folder made at folder."""
    config, local_out, _ = small
    shutil.copytree(local_out, folder)
    return config, folder


def test_resume_after_a_half_written_line_computes_only_the_missing_trials(
    small: tuple[Path, Path, list[dict]], tmp_path: Path
) -> None:
    config, out = _copied(small, tmp_path / "resumed")
    local = small[2]
    lines = (out / ROWS_FILE).read_text().splitlines(keepends=True)
    # header, trial c00-t0000 (3 rows), two rows of c00-t0001, half of its third row
    (out / ROWS_FILE).write_text("".join(lines[:6]) + lines[6][:40])
    assert [r["trial_id"] for r in load_rows(out)] == ["c00-t0000"] * 3
    with pytest.raises(SweepError, match="--resume"):
        run_sweep(load_config(config), out, workers=2, progress=False)
    outcome = run_sweep(load_config(config), out, workers=2, resume=True, progress=False)
    assert (outcome.skipped, outcome.computed) == (1, TRIALS - 1)
    rows = load_rows(out)
    assert same_rows(rows, local) == []
    # the kept trial was not recomputed: its run times are the stored ones
    assert [r["time_s"] for r in rows[:3]] == [r["time_s"] for r in local[:3]]


def test_rerun_reproduces_one_trial(
    small: tuple[Path, Path, list[dict]], capsys: pytest.CaptureFixture
) -> None:
    config, out, local = small
    rows = rerun_trial(load_config(config), "c03-t0002")
    assert same_rows(rows, [r for r in local if r["trial_id"] == "c03-t0002"]) == []
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["sweep", str(config), "--out", str(out), "--rerun", "c03-t0002"])
    assert run(args) == 0
    assert "identical to" in capsys.readouterr().out
    with pytest.raises(SweepError, match="c00..c03"):
        rerun_trial(load_config(config), "c09-t0000")


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("trials = 0\n", "'trials'"),
        ('paired = "yes"\n', "'paired'"),
        ("colour = 1\n", "'colour'"),
        ('methods = ["ekf", "nope"]\n', "'methods[1]'"),
        ("[grid]\npixel_sigma_px = [0.3, -1.0]\n", "'grid.pixel_sigma_px[1]'"),
        ('[fixed]\nmount = "loose"\n', "'fixed.mount'"),
        ("[levels]\ndepth_subpixel = [0.1, 0.2]\nrobot_rotation_sigma_deg = [0.01]\n", "'levels'"),
        ('fidelity = "render"\n[grid]\npixel_sigma_px = [0.3]\n', "rgb_sigma_grey"),
        ('[fixed]\ntrajectory = "paper"\nwaypoints = 16\n', "'fixed.waypoints'"),
        ("[fixed]\nwaypoints = 5\n[grid]\nwaypoints = [4, 5]\n", "'grid.waypoints'"),
        ('scenario = "missing.toml"\n', "'scenario'"),
        ("trials = [\n", "not valid TOML"),
    ],
)
def test_config_errors_name_the_file_and_key(tmp_path: Path, text: str, key: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SweepConfigError) as info:
        load_config(path)
    assert str(path) in str(info.value) and key in str(info.value)


def test_depth_bias_reaches_the_trial_and_learned_noise_contains_it(tmp_path: Path) -> None:
    path = tmp_path / "bias.toml"
    path.write_text('trials = 1\nmethods = ["ekf"]\n[grid]\ndepth_bias_scale = [1.0, 1.02]\n')
    run_sweep(load_config(path), tmp_path / "out", workers=1, progress=False)
    unbiased, biased = load_rows(tmp_path / "out")
    assert unbiased["depth_bias_scale"] == 1.0 and biased["depth_bias_scale"] == 1.02
    # The bias reaches the trial (its error changes), and the depth noise learned from the data keeps
    # it cheap: with the declared noise a 2 % bias cost 3x the error and a NEES above 100.
    assert biased["error_translation_mm"] != unbiased["error_translation_mm"]
    assert biased["error_translation_mm"] < 3 * unbiased["error_translation_mm"]
    assert biased["nees"] < 100.0


def test_render_trial_end_to_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setenv("TMPDIR", str(scratch))  # the worker renders its dataset in there
    path = tmp_path / "render.toml"
    path.write_text('fidelity = "render"\ntrials = 1\nmethods = ["ekf"]\n[fixed]\nwaypoints = 5\n')
    outcome = run_sweep(load_config(path), tmp_path / "out", workers=1, progress=False)
    assert outcome.computed == 1 and not outcome.lost
    (row,) = load_rows(tmp_path / "out")
    assert row["fidelity"] == "render" and row["rgb_sigma_grey"] == 2.0 and row["waypoints"] == 5
    assert row["status"] == "ok", row["failure"]
    assert row["error_translation_mm"] < 1.0 and row["error_rotation_deg"] < 0.1
    assert math.isfinite(row["nees"]) and math.isfinite(row["crb_translation_mm"])
    assert not list(scratch.iterdir()) and not (tmp_path / "out" / "datasets").exists()  # deleted
    # The first render trial is kept for the report, with the cell overview and detection overlays.
    example = tmp_path / "out" / "example"
    assert (example / "preview" / "overview.png").is_file() and len(
        list((example / "overlay").glob("*.png"))
    ) == 5


def test_a_board_in_the_grid_reaches_each_cell_and_an_unknown_one_is_named(tmp_path: Path) -> None:
    board = json.loads((Path(__file__).parents[1] / "models" / "boards" / "hec_8qr.json").read_text())
    board["size_m"] = [0.5, 0.3]
    (tmp_path / "wide.json").write_text(json.dumps(board))
    path = tmp_path / "boards.toml"
    path.write_text(
        f'fidelity = "render"\ntrials = 1\nmethods = ["ekf"]\nscenario = "{tmp_path / "s.toml"}"\n'
        '[grid]\nboard = ["hec_8qr", "wide.json"]\n'
    )
    (tmp_path / "s.toml").write_text("")
    config = load_config(path)
    boards = [
        cell_scenario(config.scenario.to_dict(), config.scenario.base_dir, c.parameters) for c in config.cells
    ]
    assert [b.board_definition().size_m for b in boards] == [(0.4, 0.22), (0.5, 0.3)]
    path.write_text(path.read_text().replace("wide.json", "missing.json"))
    with pytest.raises(SweepConfigError, match="missing.json"):
        load_config(path)


@pytest.mark.parametrize("paired", [True, False])
def test_paired_trials_draw_alike_in_every_cell(tmp_path: Path, paired: bool) -> None:
    # Two cells with the same parameters: paired, trial t is the same trial in both (mount, views,
    # noise); unpaired, each cell draws its own.
    path = tmp_path / "paired.toml"
    path.write_text(
        f'seed = 3\npaired = {str(paired).lower()}\ntrials = 2\nmethods = ["opencv-park"]\n'
        '[fixed]\nmount = "random"\n[grid]\ndepth_bias_scale = [1.0, 1.0]\n'
    )
    run_sweep(load_config(path), tmp_path / "out", workers=1, progress=False)
    rows = {(r["cell"], r["seed"]): r["error_translation_mm"] for r in load_rows(tmp_path / "out")}
    cells = sorted({cell for cell, _ in rows})
    if paired:
        assert sorted(rows) == [(c, s) for c in cells for s in ("3/0", "3/1")]
        assert all(rows[cells[0], s] == rows[cells[1], s] for s in ("3/0", "3/1"))
    else:
        assert sorted(rows) == [(c, f"3/{i}/{t}") for i, c in enumerate(cells) for t in (0, 1)]
        assert all(rows[cells[0], f"3/0/{t}"] != rows[cells[1], f"3/1/{t}"] for t in (0, 1))
    meta = json.loads((tmp_path / "out" / "sweep.json").read_text())
    assert meta["config"]["paired"] is paired and ("[seed, trial]" in meta["trial_seed"]) is paired


def test_a_folder_from_before_the_paired_key_resumes_as_unpaired(
    small: tuple[Path, Path, list[dict]], tmp_path: Path
) -> None:
    config, out = _copied(small, tmp_path / "old")
    meta = json.loads((out / "sweep.json").read_text())
    del meta["config"]["paired"]
    (out / "sweep.json").write_text(json.dumps(meta))
    outcome = run_sweep(load_config(config), out, workers=1, resume=True, progress=False)
    assert (outcome.skipped, outcome.computed) == (TRIALS, 0)
    paired = tmp_path / "paired.toml"
    paired.write_text("paired = true\n" + config.read_text())
    with pytest.raises(SweepError, match="config.paired"):
        run_sweep(load_config(paired), out, workers=1, resume=True, progress=False)
