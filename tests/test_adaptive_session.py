"""The adaptive session (`hec run/record --sim --target-sigma-mm X --target-sigma-deg Y`), end to end:
MuJoCo rendering, the real detector and the running EKF; the stop rule recomputed from the recording.
About 25 s on a quiet 2-core machine."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hec.commands.record import CALIBRATION_FILE
from hec.estimator.geometry.waypoints import write_waypoint_file
from hec.estimator.io.dataset import load_dataset
from hec.session.adaptive import MIN_STOP_VIEWS
from hec.session.session import LiveEstimate, rss_sigmas
from hec.sim.scenario import load_scenario
from hec.sim.simulate import scenario_waypoints
from tests.hec_cli import run_hec

TARGET = (0.2, 0.02)  # mm, deg


def _session_block(out: Path) -> dict:
    return json.loads((out / "dataset.json").read_text())["session"]


def _above(rss: tuple[float, float] | None) -> bool:
    return rss is None or rss[0] > TARGET[0] or rss[1] > TARGET[1]


@pytest.fixture(scope="module")
def adaptive_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int, str]:
    out = tmp_path_factory.mktemp("adaptive") / "run"
    argv = ["run", "--sim", "--target-sigma-mm", str(TARGET[0]), "--target-sigma-deg", str(TARGET[1])]
    code, stdout, stderr = run_hec([*argv, "--out", str(out)])
    assert code == 0, stderr
    return out, code, stdout


def test_it_stops_when_the_running_estimate_reaches_the_target_and_calibrates(adaptive_run) -> None:
    out, _, stdout = adaptive_run
    block = _session_block(out)["adaptive"]
    views = block["views"]
    assert block["reached"] and block["outcome"] == "target reached"
    assert MIN_STOP_VIEWS <= views < block["max_views"] == 40
    assert f"target reached after {views} views: " in stdout
    # The running estimate recomputed from the recording: at the target with the last view, not before
    # (or the target was met before the stop rule applies).
    history = dict(LiveEstimate(out).history())
    assert len(LiveEstimate(out).observations) == views
    last = rss_sigmas(history[views])
    assert not _above(last)
    assert views == MIN_STOP_VIEWS or _above(rss_sigmas(history[views - 1]) if views - 1 in history else None)
    assert last == pytest.approx((block["rss_sigma_mm"], block["rss_sigma_deg"]), rel=1e-6)
    assert [v["waypoint"] for v in block["chosen"]] == [int(r["waypoint"]) for r in load_dataset(out).rows]
    assert (out / CALIBRATION_FILE).is_file()
    assert "vs ground truth" in stdout


def test_each_frame_line_shows_the_running_rss_sigma_against_the_target(adaptive_run) -> None:
    _, _, stdout = adaptive_run
    assert "RSS " in stdout and "target 0.2 mm / 0.02 deg" in stdout
    assert "view informations of" in stdout


def test_an_unreachable_target_stops_at_the_maximum_and_says_not_reached(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    argv = [
        "record",
        "--sim",
        "--target-sigma-mm",
        "0.001",
        "--target-sigma-deg",
        "0.0001",
        "--max-views",
        "4",
    ]
    code, stdout, stderr = run_hec([*argv, "--out", str(out)])
    assert code == 0, stderr
    assert "not reached: 4 views, the maximum (--max-views)" in stdout
    block = _session_block(out)["adaptive"]
    assert block["outcome"] == "maximum views" and not block["reached"] and block["views"] == 4
    assert len(LiveEstimate(out).observations) == 4


def test_a_waypoint_file_is_the_pool(tmp_path: Path) -> None:
    waypoints = scenario_waypoints(load_scenario(None))
    write_waypoint_file(tmp_path / "pool.csv", waypoints)
    out = tmp_path / "rec"
    argv = ["record", "--sim", "--waypoints", str(tmp_path / "pool.csv"), "--target-sigma-mm", "0.2"]
    code, stdout, stderr = run_hec([*argv, "--target-sigma-deg", "0.02", "--out", str(out)])
    assert code == 0, stderr
    block = _session_block(out)
    chosen = [v["waypoint"] for v in block["adaptive"]["chosen"]]
    assert block["waypoints"] == len(waypoints) and set(chosen) <= {w.index for w in waypoints}
    assert len(set(chosen)) == len(chosen) < len(waypoints)  # stopped early, each view once
    assert block["adaptive"]["reached"]


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--target-sigma-mm", "0.2"], "go together"),
        (["--target-sigma-deg", "0.02"], "go together"),
        (["--target-sigma-mm", "0", "--target-sigma-deg", "0.02"], "both must be > 0"),
        (["--target-sigma-mm", "0.2", "--target-sigma-deg", "-1"], "both must be > 0"),
        (["--target-sigma-mm", "0.2", "--target-sigma-deg", "0.02", "--max-views", "2"], "at least 3"),
        (["--max-views", "10"], "--max-views goes with a target"),
        (["--target-sigma-mm", "0.2", "--target-sigma-deg", "0.02", "--no-live"], "--no-live"),
        (["--target-sigma-mm", "0.2", "--target-sigma-deg", "0.02", "--resume"], "cannot be resumed"),
        (
            ["--target-sigma-mm", "0.2", "--target-sigma-deg", "0.02", "--verify", "c.json"],
            "--verify: a verification session",
        ),
    ],
)
def test_bad_target_options_are_refused_before_anything_moves(
    tmp_path: Path, options: list[str], message: str
) -> None:
    out = tmp_path / "out"
    code, stdout, stderr = run_hec(["run", "--sim", *options, "--out", str(out)])
    assert code == 2
    assert message in stderr and stderr.startswith("hec: error: ")
    assert not out.exists()
