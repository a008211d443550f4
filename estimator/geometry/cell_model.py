"""The cell as the planner sees it before the arm moves, without a simulator: the arm's links as
capsules placed by its kinematics, the camera and its cable on the flange as capsules, and the
cell's obstacles (wall, floor, table, board) as boxes in the base frame. CellModel.problem names
the first part that comes within the clearance of an obstacle; joint_path's checks call it at
every sample of a move.

The link capsules contain the arm's collision shapes of models/ur5.xml and models/ur5e.xml (the
same for both; tests/test_cell_model.py reads them from the files): each joint's cylinder and each
link's capsule, in the frame of the link that carries it, T_base_{k-1} Rz(q_k) for link k (the DH
frame before joint k turned by it, as the MJCF's bodies). The shoulder (link 1) is left out: it
only turns about its own axis at the base.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hec.estimator.geometry.kinematics import URKinematics
from hec.estimator.geometry.transforms import rotation_about

FLANGE = 7  # Capsule.link of a part carried by the flange (T_base_flange)
CLEARANCE_M = 0.01  # default distance every part keeps from every obstacle, metres


@dataclass(frozen=True)
class Capsule:
    """A part: the points within radius_m of the segment p0_m..p1_m (3,), metres, in the frame
    of link `link` (1..6: T_base_{k-1} Rz(q_k); FLANGE: T_base_flange)."""

    name: str
    link: int
    p0_m: tuple[float, float, float]
    p1_m: tuple[float, float, float]
    radius_m: float


@dataclass(frozen=True)
class Box:
    """An obstacle: a box of half sizes half_size_m (3,) along the axes of T_base_box (4, 4)."""

    name: str
    T_base_box: np.ndarray
    half_size_m: tuple[float, float, float]


UR_LINK_CAPSULES = (
    Capsule("upper arm", 2, (0.0, 0.0, 0.0), (0.0, 0.0, 0.14), 0.06),
    Capsule("upper arm", 2, (-0.06, 0.0, 0.136), (-0.37, 0.0, 0.136), 0.05),
    Capsule("forearm", 3, (0.0, 0.0, 0.015), (0.0, 0.0, 0.135), 0.05),
    Capsule("forearm", 3, (-0.05, 0.0, 0.017), (-0.34, 0.0, 0.017), 0.04),
    Capsule("wrist 1", 4, (0.0, 0.0, 0.01), (0.0, 0.0, 0.11), 0.04),
    Capsule("wrist 2", 5, (0.0, 0.0, 0.0), (0.0, 0.0, 0.09), 0.04),
    Capsule("wrist 3", 6, (0.0, 0.0, 0.018), (0.0, 0.0, 0.078), 0.0375),
)


# The camera body of the simulated cell (a D435 housing, 90 x 25 x 25 mm, its centre 14 mm behind
# the optical centre along the optical axis) and its USB cable leaving the housing's +x end back
# past the flange, in the camera frame, metres.
CAMERA_HOUSING_HALF_M = (0.045, 0.0125, 0.0125)
CAMERA_HOUSING_CENTRE_M = (0.0, 0.0, -0.014)
CABLE_RADIUS_M = 0.01
CABLE_LENGTH_M = 0.1  # how far the cable's volume reaches back along the flange's -z


def camera_parts(T_flange_cam: np.ndarray) -> tuple[Capsule, Capsule]:
    """The camera and its cable as flange parts for a camera mounted at T_flange_cam (4, 4): a
    capsule that contains the housing, and the cable from the housing's +x end CABLE_LENGTH_M
    back along the flange's -z."""
    half, centre = np.asarray(CAMERA_HOUSING_HALF_M), np.asarray(CAMERA_HOUSING_CENTRE_M)
    ends = [centre - [half[0], 0.0, 0.0], centre + [half[0], 0.0, 0.0]]
    a, b = (T_flange_cam[:3, :3] @ p + T_flange_cam[:3, 3] for p in ends)
    camera = Capsule("camera", FLANGE, _point(a), _point(b), float(np.hypot(half[1], half[2])))
    cable = Capsule("camera cable", FLANGE, _point(b), _point(b - [0.0, 0.0, CABLE_LENGTH_M]), CABLE_RADIUS_M)
    return camera, cable


def _point(p: np.ndarray) -> tuple[float, float, float]:
    return (float(p[0]), float(p[1]), float(p[2]))


def link_frames(kinematics: URKinematics, q: np.ndarray) -> np.ndarray:
    """(8, 4, 4) poses in the base frame: [0] the base, [k] link k's frame T_base_{k-1} Rz(q_k)
    for k = 1..6, [FLANGE] T_base_flange, at joints q (6,), radians."""
    q = np.asarray(q, dtype=float) + np.asarray(kinematics.theta_offset, dtype=float)
    frames = np.empty((8, 4, 4))
    frames[0] = T = np.eye(4)
    for k in range(6):
        turn = np.eye(4)
        turn[:3, :3] = rotation_about("z", q[k])
        body = T @ turn
        frames[k + 1] = body
        step = np.eye(4)
        step[:3, :3] = rotation_about("x", kinematics.alpha[k])
        step[:3, 3] = (kinematics.a[k], 0.0, kinematics.d[k])
        T = body @ step
    frames[FLANGE] = T
    return frames


class CellModel:
    """The arm's kinematics with its parts (capsules) and the cell's obstacles (boxes), every part
    kept clearance_m from every obstacle. The parts are sampled as spheres along their segments,
    at most a fifth of their radius apart (an error under 0.5 % of the radius)."""

    def __init__(
        self,
        kinematics: URKinematics,
        parts: tuple[Capsule, ...],
        obstacles: tuple[Box, ...],
        clearance_m: float = CLEARANCE_M,
    ) -> None:
        self.kinematics, self.parts, self.obstacles = kinematics, parts, obstacles
        self.clearance_m = clearance_m
        links, points, radii, owners = [], [], [], []
        for i, part in enumerate(parts):
            p0, p1 = np.asarray(part.p0_m, dtype=float), np.asarray(part.p1_m, dtype=float)
            n = max(2, int(np.ceil(np.linalg.norm(p1 - p0) / (part.radius_m / 5.0))) + 1)
            s = np.linspace(0.0, 1.0, n)[:, None]
            points.append(p0 + s * (p1 - p0))
            links += [part.link] * n
            radii += [part.radius_m] * n
            owners += [i] * n
        self._links = np.array(links)
        self._points = np.vstack(points)  # (P, 3) in each point's link frame
        self._radii = np.array(radii)
        self._owners = np.array(owners)

    def gaps(self, q: np.ndarray) -> np.ndarray:
        """(len(parts), len(obstacles)) the distance between each part's surface and each
        obstacle at joints q (6,), metres; negative: inside it."""
        frames = link_frames(self.kinematics, q)[self._links]  # (P, 4, 4)
        p_base = np.einsum("pij,pj->pi", frames[:, :3, :3], self._points) + frames[:, :3, 3]
        gaps = np.full((len(self.parts), len(self.obstacles)), np.inf)
        for j, box in enumerate(self.obstacles):
            p_box = (p_base - box.T_base_box[:3, 3]) @ box.T_base_box[:3, :3]
            excess = np.abs(p_box) - np.asarray(box.half_size_m)
            outside = np.linalg.norm(np.maximum(excess, 0.0), axis=1)
            distance = outside + np.minimum(excess.max(axis=1), 0.0) - self._radii
            np.minimum.at(gaps[:, j], self._owners, distance)
        return gaps

    def problem(self, q: np.ndarray) -> str | None:
        """Which part comes within clearance_m of which obstacle at joints q (6,), radians (the
        closest such pair), or None."""
        gaps = self.gaps(q)
        if gaps.size == 0 or gaps.min() >= self.clearance_m:
            return None
        i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
        part, obstacle = self.parts[i].name, self.obstacles[j].name
        gap_mm = 1000.0 * gaps[i, j]
        if gap_mm < 0:
            return f"the {part} hits the {obstacle} ({-gap_mm:.0f} mm into it)"
        return (
            f"the {part} comes within {gap_mm:.0f} mm of the {obstacle} "
            f"(clearance {1000.0 * self.clearance_m:.0f} mm)"
        )
