"""`hec teach` against the loopback UR controller and the software RealSense, both showing one
simulated cell: the arm is guided by hand in teach mode and the stored poses are checked."""

from __future__ import annotations

import argparse
import faulthandler
import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from hec.commands import teach
from hec.commands.table import build_parser
from hec.estimator.geometry.waypoints import read_waypoint_file
from hec.rehearsal.rtde_loopback import LoopbackController
from hec.rehearsal.software_d435 import SoftwareD435, d435_depth_sensor, d435_scenario
from hec.sim.cell import SimCell
from hec.sim.scenario import load_scenario
from hec.sim.simulate import scenario_waypoints
from tests.test_rtde_loopback import Q_HOME, hang_guard

HOST = "127.0.0.6"  # apart from the other loopback tests' addresses
CELL_TOML = """\
[robot]
dwell_s = 0.1

[camera]
colour_size = [640, 480]
warmup_frames = 2
burst = 2
timeout_s = 2.0
"""


def _args(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["teach", *argv])


def _guide(controller: LoopbackController, poses: list[np.ndarray], last: str | None) -> Callable[[str], str]:
    """A read_line that hand-guides the arm to the next of poses (6,) and answers "" (store);
    after the last pose it answers `last`, or ends the input when that is None."""
    remaining = iter(poses)

    def read_line(prompt: str) -> str:
        q = next(remaining, None)
        if q is None:
            if last is None:
                raise EOFError
            return last
        controller.hand_guide(q)
        return ""

    return read_line


@pytest.fixture
def rig() -> Iterator[tuple[SimCell, LoopbackController, SoftwareD435, list[np.ndarray]]]:
    """The cell (arm at Q_HOME, looking away from the board), its controller and camera, and
    three joint vectors (6,) that show the whole board."""
    hang_guard()
    cell = SimCell(
        d435_scenario(load_scenario(None)), np.random.default_rng(0), depth_sensor=d435_depth_sensor()
    )
    views = []
    for waypoint in scenario_waypoints(cell.scenario)[:3]:
        cell.move_to(waypoint)  # IK and visibility checks only: nothing is rendered here
        views.append(cell.joints.copy())
    cell.set_joints(Q_HOME)
    assert cell.markers_visible_problem() is not None
    lock = threading.Lock()
    # Closed in reverse: the controller, then the device (it frees the cell's GL contexts in
    # its streaming thread, the one that renders the cell).
    with (
        SoftwareD435(cell, lock, np.random.default_rng(1)) as device,
        LoopbackController(cell, lock, host=HOST, speedup=4.0) as controller,
    ):
        yield cell, controller, device, views
    faulthandler.cancel_dump_traceback_later()


def test_guided_poses_that_show_the_board_are_stored(rig, tmp_path: Path, capsys) -> None:
    _, controller, device, views = rig
    (tmp_path / "cell.toml").write_text(CELL_TOML)
    out = tmp_path / "taught.csv"
    argv = ["--robot", HOST, "--camera", "--cell", str(tmp_path / "cell.toml"), "--out", str(out)]

    code = teach.run(_args(*argv), device.context, _guide(controller, [views[0], Q_HOME, views[1]], "q"))
    output = capsys.readouterr().out
    assert code == 0, output
    assert "stored waypoint 1: 8/8 markers, flange at [" in output
    refused = (
        r"not stored: markers \[0, 1, 2, 3, 4, 5, 6, 7\] not seen; .*; move so the whole board is in view"
    )
    assert re.search(refused, output)
    assert "stored waypoint 2: 8/8 markers" in output
    assert f"next: hec record --robot {HOST} --cell" in output
    assert controller.status()["teach_mode"] is False

    code = teach.run(_args(*argv, "--append"), device.context, _guide(controller, [views[2]], None))
    output = capsys.readouterr().out
    assert code == 0, output
    assert "stored waypoint 3: 8/8 markers" in output and "stored 1 waypoint (3 in" in output
    assert controller.status()["teach_mode"] is False

    waypoints = read_waypoint_file(out)
    assert [w.label for w in waypoints] == ["taught 1", "taught 2", "taught 3"]
    np.testing.assert_allclose([w.joints for w in waypoints], [views[0], views[1], views[2]], atol=1e-4)
    assert out.read_text().startswith("q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,label\n")


def test_a_part_view_is_stored_only_with_allow_partial_and_an_unsettled_arm_never(
    rig, tmp_path: Path, capsys
) -> None:
    _, controller, device, views = rig
    cell_file, out = tmp_path / "cell.toml", tmp_path / "taught.csv"
    part_view = views[0] + np.array([0.28, 0.0, 0.0, 0.0, 0.0, 0.0])  # markers 0, 1, 4, 5 leave the image
    argv = ["--robot", HOST, "--cell", str(cell_file), "--out", str(out)]

    # A settle timeout shorter than the dwell: the arm never counts as settled. (The loopback reports
    # zero joint speed for a hand-guided arm, so a hand that keeps moving cannot be simulated.)
    cell_file.write_text(CELL_TOML.replace("dwell_s = 0.1", "dwell_s = 0.1\nsettle_timeout_s = 0.05"))
    assert teach.run(_args(*argv), device.context, _guide(controller, [views[0]], "q")) == 0
    output = capsys.readouterr().out
    assert "not stored: the arm did not settle within 0.05 s" in output and "stored 0 waypoints" in output
    assert "next:" not in output and not out.exists()

    cell_file.write_text(CELL_TOML)
    assert teach.run(_args(*argv), device.context, _guide(controller, [part_view], "q")) == 0
    assert "not stored: markers [0, 1, 4, 5] not seen; move so" in capsys.readouterr().out
    assert not out.exists()

    guided = _guide(controller, [part_view, Q_HOME], None)
    assert teach.run(_args(*argv, "--allow-partial"), device.context, guided) == 0
    output = capsys.readouterr().out
    assert "warning: markers [0, 1, 4, 5] not seen; storing the pose anyway (--allow-partial)" in output
    assert "stored waypoint 1: 4/8 markers" in output
    assert "not stored: markers [0, 1, 2, 3, 4, 5, 6, 7] not seen" in output  # none seen: never stored
    (waypoint,) = read_waypoint_file(out)
    np.testing.assert_allclose(waypoint.joints, part_view, atol=1e-4)
    assert controller.status()["teach_mode"] is False


def test_a_lost_connection_is_reported_not_masked_by_ending_teach_mode(rig, tmp_path: Path, capsys) -> None:
    _, controller, device, views = rig
    (tmp_path / "cell.toml").write_text(CELL_TOML)
    out = tmp_path / "taught.csv"

    def read_line(prompt: str) -> str:
        controller.hand_guide(views[0])
        controller.drop_connections()
        time.sleep(1.0)  # until the clients notice
        return ""

    args = _args("--robot", HOST, "--cell", str(tmp_path / "cell.toml"), "--out", str(out))
    assert teach.run(args, device.context, read_line) == 2
    assert f"hec: error: lost the connection to the UR controller at {HOST}" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    ("existing", "extra", "message"),
    [
        ("q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,label\n", [], "exists; give --append"),
        ("x_m,y_m,z_m,qw,qx,qy,qz\n", ["--append"], "cannot append joint waypoints, its header is not"),
        (None, ["--cell", "missing.toml"], "missing.toml: cell file not found"),
    ],
)
def test_bad_output_or_cell_file_fails_before_connecting(
    tmp_path: Path, capsys, existing: str | None, extra: list[str], message: str
) -> None:
    out = tmp_path / "taught.csv"
    if existing is not None:
        out.write_text(existing)
    # Nothing listens on this address: reaching the robot would fail differently.
    args = _args("--robot", "127.0.0.250", "--out", str(out), *extra)
    assert teach.run(args, read_line=lambda _: pytest.fail("prompted")) == 2
    assert message in capsys.readouterr().err
    assert (out.read_text() if existing is not None else None) == existing


def test_a_robot_address_is_required(tmp_path: Path, capsys) -> None:
    assert teach.run(_args("--out", str(tmp_path / "taught.csv"))) == 2
    assert "no robot address: give --robot HOST or robot.host" in capsys.readouterr().err
