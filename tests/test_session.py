"""`hec record` / `hec run`: the session on the simulated cell, and on the real-cell code path
against the loopback UR controller and the RealSense software device sharing one simulated cell."""

from __future__ import annotations

import faulthandler
import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from hec.cli import main
from hec.commands import record
from hec.commands.calibrate import CalibrateSettings, calibrate_dataset
from hec.commands.table import build_parser
from hec.estimator.common.models import models_dir
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.geometry.waypoints import write_waypoint_file
from hec.estimator.io.dataset import load_dataset
from hec.rehearsal.rig import rehearsal_scenario, write_pose_waypoints
from hec.rehearsal.rtde_loopback import LoopbackController
from hec.rehearsal.software_d435 import SERIAL, SoftwareD435, d435_depth_sensor
from hec.session.plot import PLOT_FILE
from hec.sim.cell import SimCell
from hec.sim.scenario import Scenario, load_scenario
from hec.sim.simulate import scenario_waypoints, simulate
from tests.conftest import TEST_SEED
from tests.test_rtde_loopback import Q_HOME, hang_guard

HOST = "127.0.0.4"  # apart from the other loopback test files' addresses
# Longest a session test may take before the watchdog ends the process (ur_rtde calls cannot
# be interrupted); the 17-waypoint recording takes ~35 s on a quiet 2-core machine.
HANG_LIMIT_S = 240.0
CELL_TOML = """
[robot]
joint_speed_deg_s = 90.0
joint_acceleration_deg_s2 = 180.0
dwell_s = 0.1
pose_sigma_mm = 0.0   # the loopback reports the simulated arm's exact pose
pose_sigma_deg = 0.0
[camera]
colour_size = [640, 480]
warmup_frames = 2
burst = 4
timeout_s = 20.0  # a hang guard only: the stand-in renders slowly on a loaded machine
"""


@dataclass
class RealCell:
    """The loopback controller and the software camera over one simulated cell."""

    cell: SimCell
    lock: threading.Lock
    controller: LoopbackController
    device: SoftwareD435
    cell_file: Path

    def record(self, *options: str, read_line: object = None) -> int:
        argv = ["record", "--robot", HOST, "--camera", SERIAL, "--cell", str(self.cell_file), *options]
        return record.run(build_parser().parse_args(argv), self.device.context, read_line)


def _real_cell(tmp_path: Path, seed: int) -> Iterator[RealCell]:
    hang_guard(HANG_LIMIT_S)
    cell = SimCell(rehearsal_scenario(), np.random.default_rng(seed), depth_sensor=d435_depth_sensor())
    cell.set_joints(Q_HOME)
    lock = threading.Lock()
    cell_file = tmp_path / "cell.toml"
    cell_file.write_text(CELL_TOML)
    controller = LoopbackController(cell, lock, host=HOST, speedup=4.0).start()
    try:
        with SoftwareD435(cell, lock, np.random.default_rng(seed + 1)) as device:
            yield RealCell(cell, lock, controller, device, cell_file)
    finally:
        controller.close()
        faulthandler.cancel_dump_traceback_later()


@pytest.fixture
def real_cell(tmp_path: Path) -> Iterator[RealCell]:
    yield from _real_cell(tmp_path, TEST_SEED)


def _ekf(dataset: Path, T_flange_cam: np.ndarray) -> tuple[float, float, float]:
    """ekf's translation error (mm), rotation error (deg) and root-sum-square translation sigma (mm)."""
    (result,) = calibrate_dataset(dataset, CalibrateSettings(method="ekf", loo=False), quiet=True)
    dt_m, dr_rad = pose_error(result.T_flange_cam, T_flange_cam)
    return 1e3 * dt_m, float(np.degrees(dr_rad)), float(np.linalg.norm(result.sigma_translation_mm))


def test_record_on_the_real_cell_path_calibrates_like_the_simulator(
    real_cell: RealCell, tmp_path: Path
) -> None:
    """The loopback reports exact flange poses, so both datasets have no robot pose noise and
    differ only in the camera path (librealsense, a 4-frame burst) and the session's timing."""
    scenario = rehearsal_scenario()
    waypoints = write_pose_waypoints(tmp_path / "waypoints.csv", scenario)
    out = tmp_path / "recorded"
    assert real_cell.record("--waypoints", str(waypoints), "--out", str(out), "--yes") == 0
    dataset = load_dataset(out)
    assert dataset.metadata["recording"] == "complete" and dataset.metadata["source"] == "ur-realsense"
    assert len(dataset) == len(scenario_waypoints(scenario))
    assert dataset.metadata["cell"]["camera"]["device"]["serial"] == SERIAL
    assert (out / "depth_samples" / "000000.png").is_file()
    # A frame's reported pose is the simulated arm's pose at its joints.
    with real_cell.lock:
        real_cell.cell.set_joints(dataset.rows[-1]["joints"])
        dt, dr = pose_error(dataset.rows[-1]["T_base_flange"], real_cell.cell.true_flange_pose())
    assert dt < 1e-6 and dr < 1e-6
    simulated = simulate(scenario, tmp_path / "simulated", TEST_SEED, progress=False).out_dir
    truth = scenario.mount.transform()
    on_cell, in_sim = _ekf(out, truth), _ekf(simulated, truth)
    print(f"ekf (error mm, error deg, sigma mm): real-cell path {on_cell}, simulator {in_sim}")
    # Same views and noise models: the same uncertainty, and an error no larger than the
    # simulator's by more than three of those sigmas.
    assert on_cell[2] == pytest.approx(in_sim[2], rel=0.1)
    assert on_cell[0] <= in_sim[0] + 3 * in_sim[2]


def test_a_dropped_connection_stops_the_session_and_resume_finishes_it(
    real_cell: RealCell, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    waypoints = write_pose_waypoints(tmp_path / "waypoints.csv", rehearsal_scenario(), count=6)
    out = tmp_path / "recorded"
    options = ("--waypoints", str(waypoints), "--out", str(out), "--yes", "--no-live")

    def drop_during_the_third_move() -> None:
        """The cable pulled while the arm moves. Not while a command is being sent: ur_rtde
        then waits for the controller's answer for up to 300 s whatever we do."""
        frames = out / "frames.csv"
        while not frames.is_file() or len(frames.read_text().splitlines()) < 3:
            threading.Event().wait(0.01)
        while not real_cell.controller.status()["moving"]:
            threading.Event().wait(0.005)
        threading.Event().wait(0.05)
        real_cell.controller.drop_connections()

    dropper = threading.Thread(target=drop_during_the_third_move, daemon=True)
    dropper.start()
    assert real_cell.record(*options) == record.EXIT_STOPPED
    dropper.join(timeout=5)
    err = capsys.readouterr().err
    assert f"session stopped: lost the connection to the UR controller at {HOST}" in err
    assert "run the same command with --resume" in err
    kept = load_dataset(out)
    assert kept.metadata["recording"] == "interrupted" and 2 <= len(kept) < 6
    first_rgb = (out / "rgb" / "000000.png").read_bytes()

    real_cell.controller.restore_connections()
    assert real_cell.record(*options) == 2  # --out exists: refused before anything moves
    assert "add --resume" in capsys.readouterr().err
    assert real_cell.record(*options, "--resume") == 0
    done = load_dataset(out)
    assert done.metadata["recording"] == "complete" and len(done) == 6
    assert sorted(row["waypoint"] for row in done.rows) == list(range(6))
    assert (out / "rgb" / "000000.png").read_bytes() == first_rgb


def test_a_protective_stop_stops_the_session_and_says_so(real_cell: RealCell, tmp_path: Path, capsys) -> None:
    waypoints = write_pose_waypoints(tmp_path / "waypoints.csv", rehearsal_scenario(), count=2)
    out = tmp_path / "recorded"
    real_cell.controller.obstruct_next_move(0.5, protective_stop=True)  # a collision on the first move
    assert real_cell.record("--waypoints", str(waypoints), "--out", str(out), "--yes", "--no-live") == 3
    err = capsys.readouterr().err
    assert "session stopped: the arm is in protective stop: clear the cause, then unlock it" in err
    stopped = load_dataset(out)
    assert stopped.metadata["recording"] == "interrupted" and len(stopped) == 0
    assert "protective stop" in stopped.metadata["session"]["stopped"]


def test_dry_run_and_refusals_move_nothing(real_cell: RealCell, tmp_path: Path, capsys) -> None:
    scenario = rehearsal_scenario()
    waypoints = write_pose_waypoints(tmp_path / "waypoints.csv", scenario, count=3)
    boxed = tmp_path / "boxed.toml"  # a workspace box that leaves out the waypoint farthest along base y
    y = sorted(w.T_base_flange[1, 3] for w in scenario_waypoints(scenario)[:3])
    upper = 0.5 * (y[1] + y[2])
    boxed.write_text(CELL_TOML.replace("[robot]", f"[robot]\nworkspace_upper_m = [1.0, {upper}, 1.0]"))
    out = tmp_path / "recorded"
    with real_cell.lock:
        start = real_cell.cell.joints.copy()

    real_cell.cell_file = boxed
    assert real_cell.record("--waypoints", str(waypoints), "--out", str(out), "--dry-run") == 0
    printed = capsys.readouterr().out
    assert "plan: 3 waypoints, 2 to visit, 1 skipped" in printed
    assert "outside the workspace box" in printed and "dry run: nothing moved" in printed

    answers = iter(["no"])
    assert (
        real_cell.record("--waypoints", str(waypoints), "--out", str(out), read_line=lambda _: next(answers))
        == 2
    )
    assert "not started: nothing moved" in capsys.readouterr().out
    # Without --yes and without a terminal to ask on (pytest's stdin), the session refuses.
    assert real_cell.record("--waypoints", str(waypoints), "--out", str(out)) == 2
    assert "pass --yes" in capsys.readouterr().err
    with real_cell.lock:
        np.testing.assert_array_equal(real_cell.cell.joints, start)
    assert not out.exists()


def test_record_sim_is_the_simulation_and_run_calibrates(tmp_path: Path, capsys) -> None:
    """The session on the simulated cell draws the same noise as `hec simulate`, waypoint for
    waypoint, though it visits them in its planner's order (short joint moves)."""
    simulated = simulate(load_scenario(None), tmp_path / "simulated", TEST_SEED, progress=False).out_dir
    out = tmp_path / "recorded"
    assert main(["run", "--sim", "--seed", str(TEST_SEED), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "[17/17] waypoint " in printed and "ekf: t [" in printed and "vs ground truth" in printed
    recorded, reference = load_dataset(out), load_dataset(simulated)
    assert recorded.metadata["recording"] == "complete" and len(recorded) == len(reference)
    visited = [row["waypoint"] for row in recorded.rows]
    assert visited[0] == 0 and sorted(visited) == list(range(len(reference)))
    assert visited != sorted(visited)  # the planner's order, not the file's
    for row in recorded.rows:
        same = reference.rows[row["waypoint"]]  # hec simulate renders every waypoint, in order
        for column in ("rgb", "depth"):
            assert (out / row[column]).read_bytes() == (simulated / same[column]).read_bytes()
        np.testing.assert_allclose(row["T_base_flange"], same["T_base_flange"], rtol=0.0, atol=1e-9)
    assert (out / record.CALIBRATION_FILE).is_file()
    plot = cv2.imread(str(out / PLOT_FILE))
    assert plot is not None and plot.shape[0] > 400


def _realistic_views(folder: Path, views: int = 2) -> Path:
    """The realistic cell (models/scenarios/realistic.toml: arm, lens and print errors drawn from the
    seed) over the first views default waypoints, as a scenario file in folder."""
    folder.mkdir(parents=True)
    write_waypoint_file(folder / "waypoints.csv", scenario_waypoints(Scenario())[:views])
    realistic = (models_dir() / "scenarios" / "realistic.toml").read_text()
    trajectory = '\n[trajectory]\nkind = "file"\nfile = "waypoints.csv"\n'
    (folder / "scenario.toml").write_text(realistic + trajectory)
    return folder / "scenario.toml"


def test_record_sim_noise_seed_draws_new_noise_in_the_same_cell(tmp_path: Path, capsys) -> None:
    """--noise-seed keeps the cell of --seed (mount, board, true arm, lens, print: ground_truth.json)
    and draws other noise in every frame; without it the noise is the seed's, as `hec simulate`'s."""
    scenario = _realistic_views(tmp_path / "case")
    simulated = simulate(load_scenario(scenario), tmp_path / "simulated", TEST_SEED, progress=False).out_dir
    default, other = tmp_path / "default", tmp_path / "other"
    argv = ["record", "--sim", "--scenario", str(scenario), "--seed", str(TEST_SEED), "--no-live", "--out"]
    assert main([*argv, str(default)]) == 0
    assert main([*argv, str(other), "--noise-seed", str(TEST_SEED + 1)]) == 0
    truth = [json.loads((root / "ground_truth.json").read_text()) for root in (simulated, default, other)]
    assert "model_errors" in truth[0] and truth[0] == truth[1] == truth[2]
    reference, recorded, renoised = load_dataset(simulated), load_dataset(default), load_dataset(other)
    assert recorded.metadata["simulation"]["noise_seed"] == TEST_SEED
    assert renoised.metadata["simulation"]["noise_seed"] == TEST_SEED + 1
    assert len(reference) == len(recorded) == len(renoised) == 2
    for row, same, new in zip(reference.rows, recorded.rows, renoised.rows, strict=True):
        for column in ("rgb", "depth"):
            assert (default / same[column]).read_bytes() == (simulated / row[column]).read_bytes()
            assert (other / new[column]).read_bytes() != (simulated / row[column]).read_bytes()
        np.testing.assert_array_equal(same["T_base_flange"], row["T_base_flange"])
        assert not np.allclose(new["T_base_flange"], row["T_base_flange"], rtol=0.0, atol=1e-9)
    _check_resume_keeps_the_noise_seed(argv, default, other, capsys)


def _check_resume_keeps_the_noise_seed(argv: list[str], default: Path, other: Path, capsys) -> None:
    """A resume must draw the recording's noise: another noise seed is refused, and a recording of an
    older hec (no simulation.noise_seed, its noise drawn from the seed) resumes with the seed's."""
    capsys.readouterr()
    assert main([*argv, str(other), "--resume"]) == 2
    assert f"'simulation.noise_seed' was {TEST_SEED + 1} and is now {TEST_SEED}" in capsys.readouterr().err
    meta = json.loads((default / "dataset.json").read_text())
    del meta["simulation"]["noise_seed"]
    (default / "dataset.json").write_text(json.dumps(meta))
    assert main([*argv, str(default), "--resume"]) == 0
    assert main([*argv, str(default), "--resume", "--noise-seed", str(TEST_SEED + 1)]) == 2
    assert f"'simulation.noise_seed' was None and is now {TEST_SEED + 1}" in capsys.readouterr().err


def test_an_adaptive_session_on_the_real_cell_path_picks_from_the_taught_pool(
    real_cell: RealCell, tmp_path: Path, capsys
) -> None:
    """Without nominal values the first views are spread over the pool; then the running estimate
    chooses, and the session stops at the target (hec.session.adaptive)."""
    waypoints = write_pose_waypoints(tmp_path / "waypoints.csv", rehearsal_scenario())
    out = tmp_path / "adaptive"
    target = ("--target-sigma-mm", "0.2", "--target-sigma-deg", "0.02")
    assert real_cell.record("--waypoints", str(waypoints), *target, "--out", str(out), "--yes") == 0
    block = load_dataset(out).metadata["session"]["adaptive"]
    chosen = [v["waypoint"] for v in block["chosen"]]
    assert block["reached"] and len(chosen) < 17 and len(set(chosen)) == len(chosen)
    assert chosen[:3] == [3, 8, 14]  # spread_views over the 17 waypoints
    assert f"target reached after {len(chosen)} views" in capsys.readouterr().out
