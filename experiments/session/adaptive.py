"""The adaptive session (`hec run/record --target-sigma-mm X --target-sigma-deg Y`): each next view is
chosen from a pool of candidate waypoints by the information it adds at the running estimate, and the
session stops once the running estimate's RSS 1-sigma reaches the target.

The pool: in simulation, candidate views drawn around the scenario's nominal mount and board pose
(hec.session.view_plan.scenario_candidates); with --waypoints, the file's waypoints (on the real cell: a
taught pool; hec picks the order and stops early).

The choice (AdaptiveViews): one greedy D-optimal step of hec.estimator.solve.view_planning.plan_views, the
candidate that most raises the log-determinant of the mount's information (the board pose eliminated)
when added to the information of the frames recorded so far.
- Candidate informations ((12, 12) each, state = mount, board pose) come from view_informations at a
  linearisation point: the nominal values when there are some (simulation), then the running estimate's
  T_flange_cam and T_base_board, recomputed only when the running estimate has moved from the point by
  more than RELINEARISE_MM / RELINEARISE_DEG (mount or board) or the corner noise by more than
  CORNER_SIGMA_CHANGE: in practice at the first estimates, not every frame. Their noise is the
  dataset's declared depth and robot pose noise and the median corner sigma the detector reported
  on the frames so far (CORNER_SIGMA_PX before the first frame).
- The recorded frames' information: once the running estimate exists, the Fisher information of their
  own detections (the noise the EKF uses) at the running estimate; before it, the sum of the chosen
  candidates' predicted informations, so the first views are the planner's choice at the nominal
  values. A pool without nominal values (the real cell) starts with views spread over the pool
  (hec.estimator.solve.verify.spread_views), then the rest in order, until an estimate exists.
- A cell that self-calibrates (SelfCalibratedPlanning: in simulation, a scenario with model errors
  on) scores on the mount's information with the self-calibration groups marginalised
  (hec.estimator.solve.self_calibrated_planning, their declared priors); the recorded frames'
  information is then the chosen candidates' predicted one at the current linearisation point.
- Each chosen candidate goes through cell.plan([it]) (IK, limits, the cell's checks); a rejected one is
  dropped from the pool and the next best is tried.

The stop rule, checked after each frame from MIN_STOP_VIEWS views on: the RSS of the running
estimate's per-axis 1-sigmas (hec.session.session.rss_sigmas) at or below both targets
(the running EKF, on the declared noise, is over-confident on its first frames: on the default cell
at 0.2 mm / 0.02 deg, seed 1 stopped at 3 views with NEES 15); otherwise the session ends at
max_views recorded views or when no candidate is left.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from hec.estimator.geometry.kinematics import ROBOTS, URKinematics
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.geometry.waypoints import PlannedMove, Waypoint
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.observability import state_information
from hec.estimator.solve.problem import MIN_FRAMES, build_problem
from hec.estimator.solve.self_calibrated_planning import planning_groups, self_calibrated_informations
from hec.estimator.solve.verify import spread_views
from hec.estimator.solve.view_planning import plan_views, view_informations
from hec.session.session import LiveEstimate, SessionCell, rss_sigmas

if TYPE_CHECKING:
    from hec.sim.scenario import Scenario

# Candidates drawn for a simulated cell's pool.
POOL_CANDIDATES = 300
# Candidate informations are recomputed when the running estimate has moved this far from the pose they
# were computed at (mount or board; mm, degrees) ...
RELINEARISE_MM, RELINEARISE_DEG = 0.5, 0.05
# ... or the detector's median corner sigma by more than this fraction.
CORNER_SIGMA_CHANGE = 0.25
# Corner noise the informations assume before any frame is detected, pixels per coordinate.
CORNER_SIGMA_PX = 0.1
CRITERION = "d-optimal"
DEFAULT_MAX_VIEWS = 40
MIN_STOP_VIEWS = 6  # the stop rule applies from this many recorded views on


@dataclass(frozen=True)
class SelfCalibratedPlanning:
    """What a self-calibrating cell's view choice marginalises: groups (NUISANCE_GROUPS) and the
    arm's nominal kinematics (for the kinematics group, else None)."""

    groups: tuple[str, ...]
    kinematics: URKinematics | None = None


def scenario_planning(scenario: Scenario) -> SelfCalibratedPlanning | None:
    """A simulated scenario's: every planning_groups group when it switches model errors on (the
    arm's kinematics with its arm errors), None when it switches none on."""
    if not scenario.errors.any_enabled():
        return None
    arm = scenario.errors.arm.enabled
    groups = planning_groups(scenario.board_definition(), arm)
    return SelfCalibratedPlanning(groups, ROBOTS[scenario.robot] if arm else None)


class TargetError(ValueError):
    """The adaptive session's options do not fit together."""


@dataclass(frozen=True)
class SigmaTarget:
    """Stop when the running estimate's RSS 1-sigmas are at most sigma_mm and sigma_deg, or after
    max_views views."""

    sigma_mm: float
    sigma_deg: float
    max_views: int = DEFAULT_MAX_VIEWS

    def __post_init__(self) -> None:
        if not (self.sigma_mm > 0 and self.sigma_deg > 0):
            raise ValueError(
                f"--target-sigma-mm {self.sigma_mm:g} / --target-sigma-deg {self.sigma_deg:g}: "
                "both must be > 0"
            )
        if self.max_views < MIN_FRAMES:
            raise ValueError(f"--max-views {self.max_views}: at least {MIN_FRAMES} views determine a mount")

    def reached(self, rss: tuple[float, float] | None) -> bool:
        return rss is not None and rss[0] <= self.sigma_mm and rss[1] <= self.sigma_deg


def sigma_target(args: argparse.Namespace) -> SigmaTarget | None:
    """The adaptive session's target from --target-sigma-mm/--target-sigma-deg/--max-views, None
    without one. Raises TargetError for a half-given target, values that are not positive, and the
    options an adaptive session does not go with."""
    mm, deg = args.target_sigma_mm, args.target_sigma_deg
    if mm is None and deg is None:
        if args.max_views is not None:
            raise TargetError("--max-views goes with a target (--target-sigma-mm and --target-sigma-deg)")
        return None
    if mm is None or deg is None:
        raise TargetError("--target-sigma-mm and --target-sigma-deg go together: give both or neither")
    refused = (
        (args.no_live, "--no-live: the target is checked on the running estimate"),
        (args.resume, "--resume: an adaptive session cannot be resumed (start a new one in another --out)"),
        (getattr(args, "verify", None) is not None, "--verify: a verification session visits a fixed plan"),
    )
    for given, why in refused:
        if given:
            raise TargetError(f"a target (--target-sigma-mm/--target-sigma-deg) does not go with {why}")
    try:
        return SigmaTarget(mm, deg, DEFAULT_MAX_VIEWS if args.max_views is None else args.max_views)
    except ValueError as exc:
        raise TargetError(str(exc)) from None


@dataclass(frozen=True)
class _Linearisation:
    """Where the candidate informations were computed: T_flange_cam, T_base_board (4, 4), corner sigma."""

    T_flange_cam: np.ndarray
    T_base_board: np.ndarray
    corner_sigma_px: float

    def near(self, other: _Linearisation) -> bool:
        for a, b in ((self.T_flange_cam, other.T_flange_cam), (self.T_base_board, other.T_base_board)):
            dt, dr = pose_error(a, b)
            if 1e3 * dt > RELINEARISE_MM or np.degrees(dr) > RELINEARISE_DEG:
                return False
        return abs(other.corner_sigma_px / self.corner_sigma_px - 1.0) <= CORNER_SIGMA_CHANGE


class AdaptiveViews:
    """The adaptive session's moves (a session.MoveSource): iterate to get each next move, chosen once the
    frames before it are recorded and detected into live (see the module doc for the choice).

    pool: candidate waypoints, each with its flange pose T_base_flange (4, 4), base frame (joint waypoints
    also carry it, from the nominal kinematics). nominal: (T_flange_cam, T_base_board) (4, 4) to choose
    the first views at, or None. self_calibration: the groups to marginalise, None for the mount and
    board pose alone. After the iteration ends, stop says why: 'target reached',
    'maximum views' or 'pool exhausted'."""

    def __init__(
        self,
        cell: SessionCell,
        pool: list[Waypoint],
        live: LiveEstimate,
        target: SigmaTarget,
        nominal: tuple[np.ndarray, np.ndarray] | None = None,
        say: Callable[[str], None] = print,
        self_calibration: SelfCalibratedPlanning | None = None,
    ) -> None:
        self.cell, self.pool, self.live, self.target, self.say = cell, pool, live, target, say
        self.self_calibration = self_calibration
        self._prior: np.ndarray | None = None  # the corrections' priors, with self_calibration
        self.max_moves = target.max_views
        self.free = np.ones(len(pool), bool)  # neither chosen nor rejected by the cell
        self.visited: list[int] = []  # pool indices recorded, in order
        self.rejected: list[tuple[int, str]] = []  # (pool index, the cell's reason)
        self.views: list[dict] = []  # per recorded view: waypoint, RSS sigmas after it, choice time
        self.stop: str | None = None
        self.relinearisations = 0
        self._opening = spread_views(list(range(len(pool))), MIN_FRAMES)
        self._at: _Linearisation | None = None
        self._informations: dict[int, np.ndarray] = {}  # pool index -> (12, 12), at self._at
        if nominal is not None:
            self._relinearise(_Linearisation(*nominal, CORNER_SIGMA_PX))

    def __iter__(self) -> Iterator[PlannedMove]:
        while True:
            rss = self.rss()
            if len(self.visited) >= MIN_STOP_VIEWS and self.target.reached(rss):
                self.stop = "target reached"
                return
            if len(self.visited) >= self.target.max_views:
                self.stop = "maximum views"
                return
            started = time.perf_counter()
            choice = self._choose()
            choice_s = time.perf_counter() - started
            if choice is None:
                self.stop = "pool exhausted"
                return
            k, move = choice
            frames = len(self.live.observations)
            yield move
            if len(self.live.observations) > frames:
                self.visited.append(k)
                rss = self.rss()
                self.views.append(
                    {
                        "waypoint": self.pool[k].index,
                        "rss_sigma_mm": None if rss is None else rss[0],
                        "rss_sigma_deg": None if rss is None else rss[1],
                        "choice_s": round(choice_s, 4),
                    }
                )

    def rss(self) -> tuple[float, float] | None:
        """The running estimate's RSS 1-sigmas (mm, deg), None before it exists."""
        return None if self.live.latest is None else rss_sigmas(self.live.latest)

    @property
    def reached(self) -> bool:
        return self.stop == "target reached"

    def summary(self) -> str:
        """One line: the target reached after how many views, or what was reached instead."""
        rss = self.rss()
        sigma = "no estimate" if rss is None else f"{rss[0]:.3f} mm / {rss[1]:.4f} deg (RSS 1-sigma)"
        if self.reached:
            return f"target reached after {len(self.visited)} views: {sigma}"
        why = {"maximum views": "the maximum (--max-views)", "pool exhausted": "no candidate view left"}
        return (
            f"target {self.target.sigma_mm:g} mm / {self.target.sigma_deg:g} deg not reached: "
            f"{len(self.visited)} views, {why.get(self.stop or '', 'stopped')}; reached {sigma}"
        )

    def record(self) -> dict:
        """dataset.json's session fields: the pool's size and the adaptive block (target, outcome,
        the self-calibration groups the choice marginalised, each view's RSS sigmas, the candidates
        the cell rejected)."""
        rss = self.rss()
        return {
            "waypoints": len(self.pool),
            "adaptive": {
                "target_sigma_mm": self.target.sigma_mm,
                "target_sigma_deg": self.target.sigma_deg,
                "max_views": self.target.max_views,
                "criterion": CRITERION,
                "self_calibration_groups": []
                if self.self_calibration is None
                else list(self.self_calibration.groups),
                "candidates": len(self.pool),
                "outcome": self.stop,
                "reached": self.reached,
                "views": len(self.visited),
                "rss_sigma_mm": None if rss is None else rss[0],
                "rss_sigma_deg": None if rss is None else rss[1],
                "relinearisations": self.relinearisations,
                "chosen": self.views,
                "rejected_candidates": [{"index": self.pool[k].index, "reason": r} for k, r in self.rejected],
            },
        }

    # ------------------------------------------------------------ the choice

    def _choose(self) -> tuple[int, PlannedMove] | None:
        """The best free candidate the cell accepts (pool index, its move), None when none is left."""
        estimate = self.live.latest
        if estimate is not None and estimate.T_base_board is not None:
            point = _Linearisation(estimate.T_flange_cam, estimate.T_base_board, self._corner_sigma_px())
            if self._at is None or not self._at.near(point):
                self._relinearise(point)
        if not self._informations:
            return self._first_acceptable(self._opening_order())
        offered = [k for k in self._informations if self.free[k]]
        if not offered:
            return None
        recorded = self._recorded_information(estimate)
        chosen: list[tuple[int, PlannedMove]] = []

        def accept(j: int) -> bool:
            found = self._first_acceptable([offered[j]])
            if found is not None:
                chosen.append(found)
            return found is not None

        candidates = np.array([self._informations[k] for k in offered])
        plan_views(candidates, 1, CRITERION, None, accept, recorded, self._prior)
        return chosen[0] if chosen else None

    def _opening_order(self) -> list[int]:
        """Free pool indices before any information: the spread views, then the pool's order."""
        first = [k for k in self._opening if self.free[k]]
        return first + [k for k in range(len(self.pool)) if self.free[k] and k not in first]

    def _first_acceptable(self, order: list[int]) -> tuple[int, PlannedMove] | None:
        """The first of the pool indices the cell plans a move to; each tried one leaves the pool."""
        for k in order:
            self.free[k] = False
            move = self.cell.plan([self.pool[k]])[0]
            if move.joints is not None:
                return k, move
            self.rejected.append((k, move.problem or "rejected"))
            self.say(f"  candidate {self.pool[k].index} rejected by the cell: {move.problem}")
        return None

    def _relinearise(self, point: _Linearisation) -> None:
        """Candidate informations at point, for every candidate the cell has not rejected."""
        started = time.perf_counter()
        rejected = {k for k, _ in self.rejected}
        kept = [k for k in range(len(self.pool)) if k not in rejected]
        noise = SyntheticNoise(point.corner_sigma_px, self.live.depth_noise, self.live.robot_noise)
        nominal = (self.live.board, self.live.intrinsics, point.T_flange_cam, point.T_base_board, noise)
        waypoints = [self.pool[k] for k in kept]
        if self.self_calibration is None:
            usable, informations = view_informations(waypoints, *nominal)
        else:
            groups, kinematics = self.self_calibration.groups, self.self_calibration.kinematics
            usable, informations, self._prior = self_calibrated_informations(
                waypoints, *nominal, groups, kinematics
            )
        self._informations = {kept[i]: info for i, info in zip(usable, informations, strict=True)}
        self._at = point
        self.relinearisations += 1
        where = "the nominal values" if self.live.latest is None else "the running estimate"
        self.say(
            f"  view informations of {len(usable)} of {len(kept)} candidates at {where}, corners "
            f"{point.corner_sigma_px:.3f} px ({time.perf_counter() - started:.1f} s)"
        )

    def _recorded_information(self, estimate: Calibration | None) -> np.ndarray:
        """(d, d) information of the frames so far: their detections at the running estimate, or,
        before it exists or with self_calibration, the chosen candidates' predicted informations."""
        if self.self_calibration is None and estimate is not None and estimate.T_base_board is not None:
            problem = build_problem(
                self.live.observations, self.live.board, self.live.intrinsics, self.live.robot_noise
            )
            state = HandEyeState(estimate.T_flange_cam, T_base_board=estimate.T_base_board)
            return state_information(problem, state)
        dim = 12 if self._prior is None else len(self._prior)
        return sum(
            (self._informations[k] for k in self.visited if k in self._informations), np.zeros((dim, dim))
        )

    def _corner_sigma_px(self) -> float:
        """Median per-coordinate corner sigma the detector reported on the frames so far, pixels."""
        sigmas = [
            np.sqrt(np.diag(m.corners_cov))
            for o in self.live.observations
            if o.problem is None
            for m in o.markers
        ]
        return float(np.median(np.concatenate(sigmas))) if sigmas else CORNER_SIGMA_PX
