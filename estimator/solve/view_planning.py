"""View planning: candidate views of the board and the greedy choice of the next one by the
information about T_flange_cam it adds.

A candidate is a camera pose aimed at the board (hec.estimator.geometry.waypoints.look_at_board: a
distance, a tilt about an in-plane axis, a roll about the optical axis) turned into a flange pose
through the nominal mount. It is kept when every marker lies inside the image with a margin
(predicted with the nominal camera and board) and, given the arm's nominal kinematics, the flange
pose is reachable within the joint limits (and, given one, inside the workspace box). Its
information is what one exact frame of it adds to the batch state (mount, board pose), with the
flange pose noise marginalised (hec.estimator.solve.observability.frame_information); on a cell that
self-calibrates, to that state and the self-calibration corrections
(hec.estimator.solve.self_calibrated_planning), eliminated with their priors.

Eye-to-hand (setup 'eye-to-hand') the camera is fixed and the board rides on the flange: the same
functions take T_flange_cam = T_base_cam and T_base_board = T_flange_board (the roles swapped,
hec.estimator.solve.setup_roles) and return flange poses that put the board before the camera.

Selection adds, one at a time, the candidate that most improves a criterion of the mount's
information (the state's, the board pose eliminated by its Schur complement):
- "d-optimal": the log-determinant (the volume of the bound's ellipsoid);
- "worst-direction": the smallest eigenvalue in units of the target 1-sigmas (the bound's worst
  direction, translation and rotation weighed by what is asked of each).
Before the views determine the mount a weak prior (WEAK_PRIOR_M, WEAK_PRIOR_RAD per axis on every
state coordinate) keeps both criteria finite; it is left out of the predicted 1-sigmas.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from hec.estimator.common.setups import EYE_IN_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import URKinematics, solve_ik_nearest
from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import NEAR, Waypoint, look_at_board
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.observability import frame_information
from hec.estimator.solve.problem import build_problem
from hec.estimator.solve.setup_roles import model_pose
from hec.estimator.targets.target import Target

CRITERIA = ("d-optimal", "worst-direction")
# The prior that keeps the first views' criteria finite: 1 m and 1 rad, far wider than any view.
WEAK_PRIOR_M, WEAK_PRIOR_RAD = 1.0, 1.0
# Every marker corner at least this far inside the image (pixels), so a view survives the mount
# being a few millimetres and a degree off its nominal.
VIEW_MARGIN_PX = 20.0


@dataclass(frozen=True)
class ViewRange:
    """Where candidates are drawn: distance_factors (near, far) times the nominal distance from the
    board centre, tilts up to max_tilt_deg about any in-plane axis, rolls up to max_roll_deg either
    way."""

    distance_factors: tuple[float, float] = (NEAR, 1.5)
    max_tilt_deg: float = 40.0
    max_roll_deg: float = 60.0


@dataclass(frozen=True)
class PlanStep:
    """After adding candidate `candidate`: the predicted RSS 1-sigmas of T_flange_cam (mm, deg),
    inf while the views do not determine it."""

    candidate: int
    sigma_translation_mm: float
    sigma_rotation_deg: float


def candidate_views(
    T_base_board: np.ndarray,
    T_flange_cam: np.ndarray,
    distance_m: float,
    count: int,
    rng: np.random.Generator,
    view_range: ViewRange = ViewRange(),
    setup: str = EYE_IN_HAND,
) -> list[Waypoint]:
    """count random flange-pose waypoints (base frame) whose camera, mounted as T_flange_cam (4, 4),
    looks at the centre of the board at T_base_board (4, 4) from within view_range of the nominal
    distance_m (eye-to-hand: the module doc)."""
    near, far = (f * distance_m for f in view_range.distance_factors)
    waypoints = []
    for i in range(count):
        tilt = view_range.max_tilt_deg * np.sqrt(rng.uniform())  # uniform over the cone's area
        azimuth = rng.uniform(0.0, 360.0)
        roll = rng.uniform(-view_range.max_roll_deg, view_range.max_roll_deg)
        distance = rng.uniform(near, far)
        T_model = T_base_board @ look_at_board(tilt, azimuth, roll, distance) @ invert(T_flange_cam)
        T_base_flange = model_pose(setup, T_model)
        label = f"candidate {i}: tilt {tilt:.1f} az {azimuth:.1f} roll {roll:.1f} at {distance:.3f} m"
        waypoints.append(Waypoint(i, label, T_base_flange=T_base_flange))
    return waypoints


def reachable(
    waypoint: Waypoint,
    kinematics: URKinematics,
    seed_joints: np.ndarray,
    workspace_m: tuple[Sequence[float], Sequence[float]] | None = None,
) -> np.ndarray | None:
    """Joints (6,) that reach the waypoint's flange pose within the joint limits (from seed_joints
    or a restart), None when none does or the flange leaves the workspace box (lower, upper)."""
    if workspace_m is not None:
        p = waypoint.T_base_flange[:3, 3]
        if np.any(p < workspace_m[0]) or np.any(p > workspace_m[1]):
            return None
    return solve_ik_nearest(kinematics, waypoint.T_base_flange, seed_joints)


def whole_board_views(
    waypoints: Sequence[Waypoint],
    board: Target,
    intrinsics: CameraIntrinsics,
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray,
    noise: SyntheticNoise,
    setup: str = EYE_IN_HAND,
) -> tuple[list, list[int]]:
    """Exact synthetic observations of every waypoint (at the nominal T_flange_cam, T_base_board,
    (4, 4), metres) and the indices of those holding every marker VIEW_MARGIN_PX inside the image."""
    observations = synthetic_observations(
        board,
        intrinsics,
        T_flange_cam,
        T_base_board,
        [w.T_base_flange for w in waypoints],
        noise,
        None,
        exact=True,
        margin_px=VIEW_MARGIN_PX,
        setup=setup,
    )
    return observations, [i for i, o in enumerate(observations) if len(o.markers) == len(board.marker_ids)]


def view_informations(
    waypoints: Sequence[Waypoint],
    board: Target,
    intrinsics: CameraIntrinsics,
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray,
    noise: SyntheticNoise,
    use_depth: bool = True,
    setup: str = EYE_IN_HAND,
) -> tuple[list[int], np.ndarray]:
    """The waypoints whose views hold every marker VIEW_MARGIN_PX inside the image (their indices
    into waypoints) and the (n, 12, 12) information each adds to the state (mount, board pose;
    hec.estimator.geometry.lie perturbations), from an exact frame with noise's covariances."""
    observations, whole = whole_board_views(
        waypoints, board, intrinsics, T_flange_cam, T_base_board, noise, setup
    )
    if not whole:
        return [], np.zeros((0, 12, 12))
    chosen = [observations[i] for i in whole]
    problem = build_problem(chosen, board, intrinsics, noise.robot, use_depth, None, setup)
    state = HandEyeState(T_flange_cam, T_base_board=T_base_board)
    return whole, np.array([frame_information(problem, state, f) for f in problem.frames])


def eliminate_board(state_information: np.ndarray) -> np.ndarray:
    """(..., 6, 6) information of the mount from (..., d, d) state informations, the mount first: the
    rest (the board pose, and any self-calibration corrections after it) eliminated (Schur
    complement)."""
    A, B, C = state_information[..., :6, :6], state_information[..., :6, 6:], state_information[..., 6:, 6:]
    return A - B @ np.linalg.solve(C, np.swapaxes(B, -1, -2))


def _weak_prior(dim: int) -> np.ndarray:
    """(dim, dim) WEAK_PRIOR_M, WEAK_PRIOR_RAD on the mount and the board pose, nothing after them."""
    weak = np.zeros((dim, dim))
    sigmas = np.tile(np.r_[np.full(3, WEAK_PRIOR_M), np.full(3, WEAK_PRIOR_RAD)], 2)
    weak[:12, :12] = np.diag(1.0 / sigmas**2)
    return weak


def _scores(mount: np.ndarray, criterion: str, units: np.ndarray) -> np.ndarray:
    """(n,) criterion of (n, 6, 6) mount informations; larger is better. units: (6,) target
    1-sigmas (m, rad) the worst direction is measured in."""
    if criterion == "d-optimal":
        return np.linalg.slogdet(mount)[1]
    if criterion == "worst-direction":
        scaled = mount * units[:, None] * units[None, :]
        return np.linalg.eigvalsh(scaled)[..., 0]
    raise ValueError(f"unknown criterion {criterion!r}: one of {', '.join(CRITERIA)}")


def predicted_sigmas(state_information: np.ndarray) -> tuple[float, float]:
    """RSS 1-sigmas of T_flange_cam (mm, deg) from a (d, d) state information (the mount first, with
    any priors it has); inf when the mount is not determined."""
    mount = eliminate_board(state_information)
    eigenvalues = np.linalg.eigvalsh(mount)
    if eigenvalues[0] <= 1e-9 * max(eigenvalues[-1], 1e-300):
        return float("inf"), float("inf")
    C = np.linalg.inv(mount)
    return 1e3 * float(np.sqrt(np.trace(C[:3, :3]))), float(np.degrees(np.sqrt(np.trace(C[3:, 3:]))))


def plan_views(
    informations: np.ndarray,
    max_views: int,
    criterion: str = "d-optimal",
    target_sigma: tuple[float, float] | None = None,
    accept: Callable[[int], bool] | None = None,
    recorded: np.ndarray | None = None,
    prior: np.ndarray | None = None,
) -> list[PlanStep]:
    """Candidates chosen greedily from (n, d, d) informations (view_informations: d = 12;
    hec.estimator.solve.self_calibrated_planning: the self-calibration corrections after the board
    pose), each at most once, up to max_views or until the predicted RSS 1-sigmas reach
    target_sigma (mm, deg). recorded: (d, d) information of the views already taken, added to the
    chosen ones'. prior: (d, d) information of the corrections' priors, part of every criterion and
    prediction (the corrections are eliminated with it).
    The worst-direction criterion weighs translation and rotation by target_sigma (default
    0.15 mm and 0.015 deg). accept: asked of the best candidate before it is taken (a costly
    check, such as inverse kinematics, run only on the candidates that would be chosen); a
    refused one is never offered again."""
    if criterion not in CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}: one of {', '.join(CRITERIA)}")
    target_mm, target_deg = target_sigma if target_sigma is not None else (0.15, 0.015)
    units = np.r_[np.full(3, 1e-3 * target_mm), np.full(3, np.radians(target_deg))]
    n, dim = len(informations), informations.shape[-1]
    total = np.zeros((dim, dim)) if recorded is None else recorded.copy()
    if prior is not None:
        total = total + prior
    weak = _weak_prior(dim)
    free = np.ones(n, bool)
    steps: list[PlanStep] = []
    while len(steps) < max_views and free.any():
        scores = np.full(n, -np.inf)
        scores[free] = _scores(eliminate_board(total + weak + informations[free]), criterion, units)
        best = int(np.argmax(scores))
        free[best] = False
        if accept is not None and not accept(best):
            continue
        total = total + informations[best]
        steps.append(PlanStep(best, *predicted_sigmas(total)))
        if target_sigma is not None and steps[-1].sigma_translation_mm <= target_mm:
            if steps[-1].sigma_rotation_deg <= target_deg:
                break
    return steps
