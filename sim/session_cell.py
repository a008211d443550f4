"""The simulated cell behind the calibration session's interface
(hec.session.session.SessionCell), as hec.hardware.cell.HardwareCell is the real one."""

from __future__ import annotations

import numpy as np

from hec.estimator.geometry.joint_path import CABLE_LIMIT_RAD
from hec.estimator.geometry.kinematics import has_ur_structure, solve_ik_nearest, ur_ik_branches
from hec.estimator.geometry.move_plan import plan_joint_moves
from hec.estimator.geometry.waypoints import PlannedMove, Waypoint
from hec.estimator.observe.frames import Capture
from hec.sim.cell import SimCell
from hec.sim.noise import waypoint_rng


class SimulatedCell:
    """A SimCell behind the session interface. Planning is the real cell's (plan_joint_moves: the
    visit order, least-swing branches of the nominal kinematics, the joint and cable limits, and
    every move's joint path checked against the cell model, hec.estimator.geometry.cell_model, built
    from this cell by SimCell.cell_model), with the simulator's own checks on top (MuJoCo's contacts
    along the path, every marker in view at each target); each capture draws the noise of its waypoint
    (hec.sim.noise.waypoint_rng(noise_seed, waypoint index)), so a session, resumed or not, draws the
    same noise as `hec simulate` with the same seed and noise seed. The cell (its model errors) is
    the SimCell's own, drawn from its seed."""

    source = "sim"

    def __init__(self, cell: SimCell, noise_seed: int) -> None:
        self.cell = cell
        self.noise_seed = noise_seed
        self._waypoint: int | None = None
        self.intrinsics = cell.intrinsics
        self.board = cell.board
        self.depth_scale_m = cell.scenario.noise.depth_quantisation.depth_scale_m

    def plan(self, waypoints: list[Waypoint]) -> list[PlannedMove]:
        kinematics = self.cell.cell.kinematics
        cell_model = self.cell.cell_model()
        branches = None
        if has_ur_structure(kinematics):

            def branches(T_base_flange, q_near, lower, upper):  # noqa: ANN001, ANN202
                return ur_ik_branches(kinematics, T_base_flange, q_near, lower, upper)

        return plan_joint_moves(
            waypoints,
            self.cell.joints.copy(),
            np.array(kinematics.q_lower),
            np.array(kinematics.q_upper),
            CABLE_LIMIT_RAD,
            lambda q: cell_model.problem(q) or self._target_problem(q),
            lambda q: cell_model.problem(q) or self.cell.collision_at(q),
            lambda T_base_flange, q: solve_ik_nearest(kinematics, T_base_flange, q),
            branches,
        )

    def _target_problem(self, q: np.ndarray) -> str | None:
        """What keeps the arm from capturing at joints q (6,): a contact with the cell or a marker
        out of view; the arm is put back where it was."""
        before = self.cell.joints.copy()
        self.cell.set_joints(q)
        try:
            return self.cell.collision_at(q) or self.cell.markers_visible_problem()
        finally:
            self.cell.set_joints(before)

    def move_to(self, move: PlannedMove) -> None:
        """Raises WaypointRejected when the planned joints cannot be used from here."""
        self.cell.move_to(Waypoint(move.waypoint.index, move.waypoint.label, joints=move.joints))
        self._waypoint = move.waypoint.index

    def capture(self) -> Capture:
        if self._waypoint is None:
            raise ValueError("capture before the first move: no waypoint to draw the noise of")
        frame, truth = self.cell.capture(waypoint_rng(self.noise_seed, self._waypoint))
        return Capture(frame, true_T_base_flange=truth.T_base_flange, true_joints=truth.joints)

    def close(self) -> None:
        self.cell.close()
