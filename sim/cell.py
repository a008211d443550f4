"""The simulated cell: move the arm to a waypoint, report the flange pose, capture an RGB-D frame.

This is the same small interface the real cell offers (hardware/), so a
calibration session cannot tell them apart. The simulator also knows the
truth: true joint angles and flange pose per frame, the mount and the board pose, and with
model errors (hec.sim.model_errors) the true kinematics, camera and printed board.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import mujoco
import numpy as np

from hec.estimator.geometry.camera import project
from hec.estimator.geometry.cell_model import UR_LINK_CAPSULES, Box, CellModel, camera_parts
from hec.estimator.geometry.kinematics import (
    IK_RESTARTS,
    forward,
    has_ur_structure,
    solve_ik,
    ur_ik_nearest_first,
)
from hec.estimator.geometry.transforms import invert, make_transform
from hec.estimator.geometry.waypoints import Waypoint, WaypointRejected
from hec.estimator.observe.frames import Frame, GroundTruth
from hec.sim.model_errors import draw_true_cell, reported_intrinsics
from hec.sim.noise import apply_depth_models, apply_rgb_models, perturb_flange_pose
from hec.sim.real_camera import RealCamera
from hec.sim.render import RGBDRenderer
from hec.sim.scenario import Scenario
from hec.sim.scene import CAMERA_NAME, DEPTH_SENSOR_NAME, DepthSensor, EyeToHandMounts, build_cell

# Simulated timing: joint speed while moving and the settle time at each waypoint.
JOINT_SPEED_RAD_S = 0.5
SETTLE_S = 1.0
# QR modules (or any board's smallest features) narrower than this in the image do not decode
# (measured: 8/8 QR markers at 2.2 px, 7/8 at 2.0, 1/8 at 1.7 on the default board).
MIN_MODULE_PX = 2.0


@dataclass(frozen=True)
class FrameTruth:
    """What the simulator knows about a captured frame."""

    T_base_flange: np.ndarray
    joints: np.ndarray


class SimCell:
    """A MuJoCo cell built from a scenario. Noise comes from ``rng``. ``depth_sensor``
    adds a separate depth imager beside the colour camera (see render_depth_sensor)."""

    def __init__(
        self, scenario: Scenario, rng: np.random.Generator, depth_sensor: DepthSensor | None = None
    ) -> None:
        self.scenario = scenario
        self.rng = rng
        self.intrinsics = reported_intrinsics(scenario)
        self.board = scenario.board_definition()
        self.true = draw_true_cell(scenario, self.board, rng)
        self.camera = RealCamera(scenario, self.true)
        mounts = (
            EyeToHandMounts(scenario.stand.transform(), scenario.board_mount.transform())
            if scenario.eye_to_hand
            else None
        )
        self.cell = build_cell(
            scenario.robot,
            scenario.mount.transform(),
            self.camera.render_intrinsics,
            self.board,
            scenario.board.transform(),
            depth_sensor=depth_sensor,
            kinematics=self.true.kinematics,
            printed_board=self.true.board,
            eye_to_hand=mounts,
        )
        self._true_corners = self.true.board.true_corners().reshape(-1, 3)
        self.depth_sensor = depth_sensor
        self._depth_renderer: RGBDRenderer | None = None
        self.model = self.cell.model
        self.data = mujoco.MjData(self.model)
        self._qpos = self.cell.joint_qpos_addresses()
        self._renderer: RGBDRenderer | None = None
        self._camera_body = self.model.body("camera_body").id
        self._board_geom = self.cell.board_geom_id()
        self.joints = np.array(IK_RESTARTS[0])
        self.time_s = 0.0
        self.set_joints(self.joints)

    @property
    def renderer(self) -> RGBDRenderer:
        if self._renderer is None:
            k = self.camera.render_intrinsics
            self._renderer = RGBDRenderer(self.model, k.width, k.height)
        return self._renderer

    def close(self) -> None:
        for renderer in (self._renderer, self._depth_renderer):
            if renderer is not None:
                renderer.close()
        self._renderer = self._depth_renderer = None

    # --- the cell interface -------------------------------------------------------------

    def move_to(self, waypoint: Waypoint) -> None:
        """Solve IK from the current joints, check the result, and move there.

        Raises WaypointRejected (and stays put) when the waypoint is out of reach,
        outside the joint limits, in collision, or does not show every marker.
        """
        previous = self.joints
        problem = "out of reach: IK found no solution within the joint limits"
        for q in self._ik_candidates(waypoint):
            self.set_joints(q)
            problem = self._collision() or self.markers_visible_problem()
            if problem is None:
                self.time_s += float(np.max(np.abs(q - previous))) / JOINT_SPEED_RAD_S + SETTLE_S
                return
        self.set_joints(previous)
        raise WaypointRejected(problem)

    def accepts(self, waypoint: Waypoint) -> bool:
        """Whether the cell takes the waypoint from the current joints (see move_to); it moves
        there when it does."""
        try:
            self.move_to(waypoint)
        except WaypointRejected:
            return False
        return True

    def flange_pose(self) -> np.ndarray:
        """Reported T_base_flange (4, 4): the nominal kinematics of the measured joints, with the
        robot pose noise (without arm errors: the true pose with the robot pose noise)."""
        return self._reported_pose_and_joints(self.rng)[0]

    def _reported_pose_and_joints(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """What the controller reports: T_base_flange (4, 4) and the joints (6,) it read."""
        arm = self.scenario.errors.arm
        joints = self.joints.copy()
        if arm.enabled:
            if arm.encoder_sigma_deg > 0:
                joints = joints + np.radians(arm.encoder_sigma_deg) * rng.standard_normal(6)
            T_base_flange = forward(self.cell.kinematics, joints)
        else:
            T_base_flange = self.true_flange_pose()
        return perturb_flange_pose(T_base_flange, self.scenario.noise.robot_pose, rng), joints

    def capture(self, rng: np.random.Generator | None = None) -> tuple[Frame, FrameTruth]:
        """Render and apply the sensor models with noise from rng (default: the cell's; see
        hec.sim.noise.waypoint_rng). Returns the frame and its ground truth."""
        rng = self.rng if rng is None else rng
        rgb, depth_true = self.camera.view(*self.render_true(), rng)
        T_cam_board = self.T_cam_board()
        noise = self.scenario.noise
        rgb = apply_rgb_models(self.camera.light(rgb, T_cam_board, rng), noise.rgb, rng)
        k = self.camera.intrinsics
        depth = apply_depth_models(depth_true, k, noise, rng, self.camera.depth_correlation_px())
        T_base_flange, joints = self._reported_pose_and_joints(rng)
        frame = Frame(
            rgb=rgb,
            depth_m=self.camera.holes(depth, rng),
            intrinsics=self.intrinsics,
            T_base_flange=T_base_flange,
            joints=joints,
            time_s=self.time_s,
        )
        return frame, FrameTruth(self.true_flange_pose(), self.joints.copy())

    # --- ground truth and checks ---------------------------------------------------------

    def ground_truth(self) -> GroundTruth:
        """The mount and board poses (and the true cell when the scenario has model errors),
        with empty per-frame lists to fill as frames are taken. Eye-to-hand: T_base_cam and
        T_flange_board."""
        errors = self.true.to_dict() if self.scenario.errors.any_enabled() else None
        cell = self.cell
        if cell.eye_to_hand:
            return GroundTruth(
                None,
                None,
                cell.T_world_base,
                errors,
                T_base_cam=cell.T_base_cam,
                T_flange_board=cell.T_flange_board,
            )
        return GroundTruth(cell.T_flange_cam, cell.T_base_board, cell.T_world_base, errors)

    def true_flange_pose(self) -> np.ndarray:
        return forward(self.cell.true_kinematics, self.joints)

    def T_base_cam(self) -> np.ndarray:
        """(4, 4) the camera now: on its stand (eye-to-hand), else on the true flange."""
        if self.cell.eye_to_hand:
            return self.cell.T_base_cam
        return self.true_flange_pose() @ self.cell.T_flange_cam

    def T_base_board(self) -> np.ndarray:
        """(4, 4) the board now: on the true flange (eye-to-hand), else where it is fixed."""
        if self.cell.eye_to_hand:
            return self.true_flange_pose() @ self.cell.T_flange_board
        return self.cell.T_base_board

    def T_cam_board(self) -> np.ndarray:
        """(4, 4) the board in the camera frame now."""
        return invert(self.T_base_cam()) @ self.T_base_board()

    def render_true(self) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free rgb (H, W, 3) uint8 and depth (H, W) float32 metres from the camera."""
        return self.renderer.render(self.data, CAMERA_NAME)

    def render_depth_sensor(self) -> np.ndarray:
        """Noise-free depth (H, W) float32 metres along the depth sensor's optical axis, in
        its own image (depth_sensor.intrinsics)."""
        if self.depth_sensor is None:
            raise ValueError("this cell was built without a depth sensor")
        if self._depth_renderer is None:
            k = self.depth_sensor.intrinsics
            self._depth_renderer = RGBDRenderer(self.model, k.width, k.height)
        return self._depth_renderer.render(self.data, DEPTH_SENSOR_NAME)[1]

    def markers_visible_problem(self) -> str | None:
        """None if every marker corner is in the image with the margin, faces the camera
        within the allowed angle and is not hidden; else the reason."""
        settings = self.scenario.trajectory
        T_cam_board = self.T_cam_board()
        corners = self._true_corners
        p_cam = corners @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
        if np.any(p_cam[:, 2] <= 0.05):
            return "the board is behind the camera or closer than 5 cm"
        normal_cam = T_cam_board[:3, 2]
        cos_view = -(p_cam @ normal_cam) / np.linalg.norm(p_cam, axis=1)
        worst = np.degrees(np.arccos(np.clip(cos_view.min(), -1, 1)))
        if worst > settings.max_view_angle_deg:
            limit = settings.max_view_angle_deg
            return f"the board is seen at {worst:.0f} degrees, more than max_view_angle_deg {limit:g}"
        k = self.camera.intrinsics
        uv = project(T_cam_board, corners, k)
        m = settings.margin_px
        outside = (
            (uv[:, 0] < m - 0.5)
            | (uv[:, 0] > k.width - 0.5 - m)
            | (uv[:, 1] < m - 0.5)
            | (uv[:, 1] > k.height - 0.5 - m)
        )
        if np.any(outside):
            ids = sorted(
                {self.board.marker_ids[i // self.board.points_per_marker] for i in np.nonzero(outside)[0]}
            )
            return f"markers {ids} are not inside the image with a {m:g} px margin"
        hidden = self._hidden_corners(corners)
        if hidden:
            what = ", ".join(f"{i} by {label}" for i, label in sorted(hidden.items()))
            return f"markers hidden: {what}"
        return None

    def smallest_module_px(self) -> float:
        """The width in pixels of the board's smallest feature (a QR module, a tag bit, a square:
        board.feature_m) where the image shows it smallest, along the board's x or y at any of
        its points: below MIN_MODULE_PX nothing decodes."""
        T_cam_board = self.T_cam_board()
        step = self.board.feature_m * np.eye(3)[:2]
        points = self._true_corners[:, None, :] + np.concatenate([np.zeros((1, 3)), step])[None]
        uv = project(T_cam_board, points.reshape(-1, 3), self.camera.intrinsics).reshape(-1, 3, 2)
        return float(np.linalg.norm(uv[:, 1:] - uv[:, :1], axis=2).min())

    def _hidden_corners(self, corners_board: np.ndarray) -> dict[int, str]:
        """Markers with a corner whose line of sight hits something else first: ID -> what.
        corners_board: (N, 3) board frame, metres; one batch of rays from the camera."""
        origin = (self.cell.T_world_base @ self.T_base_cam())[:3, 3]
        T_world_board = self.cell.T_world_base @ self.T_base_board()
        rays = corners_board @ T_world_board[:3, :3].T + T_world_board[:3, 3] - origin
        distance = np.linalg.norm(rays, axis=1)
        n = len(rays)
        geom_id, hit = np.empty(n, dtype=np.int32), np.empty(n)
        unit = np.ascontiguousarray(rays / distance[:, None]).ravel()
        mujoco.mj_multiRay(
            self.model,
            self.data,
            origin,
            unit,
            None,
            1,
            self._camera_body,
            geom_id,
            hit,
            None,
            n,
            mujoco.mjMAXVAL,
        )
        hidden: dict[int, str] = {}
        for i in np.flatnonzero((hit >= 0) & (hit < distance - 1e-3) & (geom_id != self._board_geom)):
            marker = self.board.marker_ids[i // self.board.points_per_marker]
            hidden.setdefault(marker, self._geom_label(geom_id[i]))
        return hidden

    def _collision(self) -> str | None:
        if self.data.ncon == 0:
            return None
        pairs = {
            tuple(sorted((self._geom_label(c.geom1), self._geom_label(c.geom2))))
            for c in self.data.contact[: self.data.ncon]
        }
        return "collision: " + ", ".join(f"{a} touches {b}" for a, b in sorted(pairs))

    def _geom_label(self, geom_id: int) -> str:
        """A geom's name, or its body's name when it has none."""
        geom = self.model.geom(geom_id)
        return geom.name or self.model.body(geom.bodyid[0]).name

    def collision_at(self, q: np.ndarray) -> str | None:
        """What the arm or the camera would touch at joints q (6,), radians (MuJoCo's contacts with
        the cell: wall, floor, table, board), or None; the arm is put back where it was."""
        before = self.joints.copy()
        self.set_joints(q)
        problem = self._collision()
        self.set_joints(before)
        return problem

    def cell_model(self) -> CellModel:
        """This cell as the real cell's planner sees it (hec.estimator.geometry.cell_model): the
        nominal arm's link capsules, the camera and its cable on the flange (eye-in-hand), and every
        box the arm collides with here (wall, floor, table, board, a camera's stand) in the base frame."""
        T_base_world = invert(self.cell.T_world_base)
        obstacles = []
        for g in range(self.model.ngeom):
            if self.model.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX or self.model.geom_conaffinity[g] == 0:
                continue
            T_world_geom = make_transform(self.data.geom_xmat[g].reshape(3, 3), self.data.geom_xpos[g])
            half = tuple(float(v) for v in self.model.geom_size[g])
            obstacles.append(Box(self._geom_label(g), T_base_world @ T_world_geom, half))
        parts = UR_LINK_CAPSULES + (() if self.cell.eye_to_hand else camera_parts(self.cell.T_flange_cam))
        return CellModel(self.cell.kinematics, parts, tuple(obstacles))

    def set_joints(self, q: np.ndarray) -> None:
        """Put the arm at joint angles q (6,), radians, without any check (the loopback
        RTDE controller in tests drives the arm this way)."""
        self.joints = np.array(q, dtype=float)
        offsets = self.cell.true_kinematics.theta_offset
        self.data.qpos[self._qpos] = self.joints + offsets if any(offsets) else self.joints
        mujoco.mj_forward(self.model, self.data)

    def _ik_candidates(self, waypoint: Waypoint) -> Iterator[np.ndarray]:
        """Joint solutions for the waypoint, the smallest move from the current joints first.

        A UR arm's nominal model: every closed-form solution. Otherwise the current joints are tried
        as the IK seed first; the fixed restarts only when that fails or asks for a large move.
        """
        kin = self.cell.kinematics
        if waypoint.joints is not None:
            q = np.asarray(waypoint.joints, dtype=float)
            if np.any(q < kin.q_lower) or np.any(q > kin.q_upper):
                raise WaypointRejected("joint target outside the joint limits")
            yield q
            return
        if has_ur_structure(kin):
            yield from ur_ik_nearest_first(kin, waypoint.T_base_flange, self.joints)
            return
        first = solve_ik(kin, waypoint.T_base_flange, self.joints)
        tried = []
        if first.converged and np.max(np.abs(first.q - self.joints)) < 1.0:
            tried.append(first.q)
            yield first.q
        solutions = [first.q] if first.converged else []
        for seed in IK_RESTARTS:
            result = solve_ik(kin, waypoint.T_base_flange, seed)
            if result.converged and not any(np.allclose(result.q, q, atol=1e-6) for q in solutions):
                solutions.append(result.q)
        remaining = [q for q in solutions if not any(q is t for t in tried)]
        yield from sorted(remaining, key=lambda q: float(np.max(np.abs(q - self.joints))))
