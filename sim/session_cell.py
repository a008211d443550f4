"""The simulated cell behind the calibration session's interface
(hec.session.session.SessionCell), as hec.hardware.cell.HardwareCell is the real one."""

from __future__ import annotations

from hec.estimator.geometry.waypoints import PlannedMove, Waypoint, WaypointRejected
from hec.estimator.observe.frames import Capture
from hec.sim.cell import SimCell
from hec.sim.noise import waypoint_rng


class SimulatedCell:
    """A SimCell behind the session interface. Planning moves the simulated arm through the
    waypoints and back without drawing noise, and each capture draws the noise of its waypoint
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
        start_joints, start_time = self.cell.joints.copy(), self.cell.time_s
        moves = []
        try:
            for waypoint in waypoints:
                try:
                    self.cell.move_to(waypoint)
                    moves.append(PlannedMove(waypoint, self.cell.joints.copy()))
                except WaypointRejected as rejected:
                    moves.append(PlannedMove(waypoint, None, rejected.reason))
        finally:
            self.cell.set_joints(start_joints)
            self.cell.time_s = start_time
        return moves

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
