"""The rehearsal rig: one simulated cell that the loopback UR controller moves and the software D435
films, with the cell file and waypoints a real session would be given."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hec.estimator.common.files import write_atomic
from hec.estimator.geometry.transforms import xyz_quat_from_transform
from hec.rehearsal.rtde_loopback import LoopbackController
from hec.rehearsal.software_d435 import SoftwareD435, d435_depth_sensor, d435_scenario
from hec.sim.cell import SimCell
from hec.sim.scenario import Scenario, load_scenario
from hec.sim.simulate import scenario_waypoints

REHEARSAL_BURST = 4  # frames averaged per capture
# Where the arm starts, radians (shoulder and elbow bent, wrist down, as a UR5 is often parked).
HOME_JOINTS = np.array([-1.57, -1.57, 1.57, -1.57, -1.57, 0.0])
# The session's cell file: faster moves than a first session on a real arm should use, the D435
# stand-in's 640x480 colour, and exact robot poses (the loopback reports the simulated arm's pose).
REHEARSAL_CELL_TOML = """\
[robot]
joint_speed_deg_s = 90.0
joint_acceleration_deg_s2 = 180.0
dwell_s = 0.1
pose_sigma_mm = 0.0
pose_sigma_deg = 0.0
[camera]
colour_size = [640, 480]
warmup_frames = 2
burst = {burst}
timeout_s = {timeout_s!r}
"""


def rehearsal_scenario(scenario_file: Path | None = None) -> Scenario:
    """The scenario (default: the built-in one) with the D435 stand-in's colour intrinsics and
    no robot pose noise (the loopback controller reports the simulated arm's exact pose)."""
    scenario = d435_scenario(load_scenario(scenario_file))
    robot_pose = scenario.noise.robot_pose.model_copy(update={"enabled": False})
    return scenario.model_copy(update={"noise": scenario.noise.model_copy(update={"robot_pose": robot_pose})})


def write_pose_waypoints(path: Path, scenario: Scenario, count: int | None = None) -> Path:
    """The scenario's trajectory (its first `count` waypoints) as a flange-pose waypoint CSV
    (metres, quaternion w x y z in the base frame), written atomically; returns the path."""
    lines = ["x_m,y_m,z_m,qw,qx,qy,qz,label"]
    for w in scenario_waypoints(scenario)[:count]:
        t, q = xyz_quat_from_transform(w.T_base_flange)
        lines.append(",".join(repr(float(v)) for v in (*t, *q)) + f",{w.label}")
    return write_atomic(path, "\n".join(lines) + "\n")


@dataclass
class Rig:
    """The loopback controller and the software camera over one simulated cell (lock guards it)."""

    cell: SimCell
    lock: threading.Lock
    controller: LoopbackController
    device: SoftwareD435


@contextmanager
def rehearsal_rig(scenario: Scenario, seed: int, host: str, speedup: float = 4.0) -> Iterator[Rig]:
    """Start the stand-ins over a cell drawn from `seed` (its model errors; the camera's noise
    from seed + 1), the arm at HOME_JOINTS, the controller on loopback address `host` with its
    clock `speedup` times wall time; both are stopped on leaving."""
    cell = SimCell(scenario, np.random.default_rng(seed), depth_sensor=d435_depth_sensor())
    cell.set_joints(HOME_JOINTS)
    lock = threading.Lock()
    controller = LoopbackController(cell, lock, host=host, speedup=speedup).start()
    try:
        with SoftwareD435(cell, lock, np.random.default_rng(seed + 1), burst=REHEARSAL_BURST) as device:
            yield Rig(cell, lock, controller, device)
    finally:
        controller.close()
