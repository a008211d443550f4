"""Measurement-level scenes for tests and Monte-Carlo runs: the default scenario's board,
camera and views (no rendering, no inverse kinematics) with a chosen mount."""

from __future__ import annotations

import numpy as np

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.lie import so3_exp
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.geometry.waypoints import paper_waypoints, rotation_rich_waypoints
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.sim.scenario import load_scenario

SCENARIO = load_scenario(None)
BOARD = SCENARIO.board_definition()
INTRINSICS: CameraIntrinsics = SCENARIO.camera.intrinsics()
T_BASE_BOARD = SCENARIO.board.transform()


def random_mount(rng: np.random.Generator) -> np.ndarray:
    """A T_flange_cam near the default mount: up to 50 mm and about 20 degrees away."""
    return SCENARIO.mount.transform() @ make_transform(
        so3_exp(rng.normal(0.0, np.radians(12.0), 3)), rng.uniform(-0.05, 0.05, 3)
    )


def scene(
    T_flange_cam: np.ndarray,
    rng: np.random.Generator,
    noise: SyntheticNoise | None = None,
    exact: bool = False,
    trajectory: str = "rotation-rich",
    views: int | None = None,
) -> list[FrameObservations]:
    """Synthetic observations of the default board along the default views (trajectory
    'rotation-rich'), their angles all at one distance ('orbit') or the paper's views ('paper');
    views: keep only the first this many."""
    distance = SCENARIO.trajectory.distance_m
    if trajectory == "paper":
        waypoints = paper_waypoints(T_BASE_BOARD, T_flange_cam, distance)
    else:
        waypoints = rotation_rich_waypoints(T_BASE_BOARD, T_flange_cam, distance, trajectory == "orbit")
    flange_poses = [w.T_base_flange for w in waypoints]
    return synthetic_observations(
        BOARD,
        INTRINSICS,
        T_flange_cam,
        T_BASE_BOARD,
        flange_poses[:views],
        noise or SyntheticNoise(),
        rng,
        exact,
    )
