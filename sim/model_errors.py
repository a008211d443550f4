"""The true cell behind a scenario's model errors (hec.sim.scenario.ModelErrors): the arm's true
kinematics, the camera's true intrinsics and lens, the depth imager's true registration and the
board as printed, drawn once per cell from the cell's generator. With every error off the true
cell is the nominal one and nothing is drawn, so the ideal cell's noise draws are unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import ROBOTS, URKinematics
from hec.estimator.geometry.lie import so3_exp
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.targets.board import BoardDefinition
from hec.estimator.targets.target import Target
from hec.sim.scenario import ArmErrors, BoardErrors, ModelErrors, Scenario


@dataclass(frozen=True)
class PrintedBoard:
    """The board as printed: ``printed`` is the definition with each marker where the printer put
    it (before scaling), the sheet is then scaled by scale (sx, sy) about its centre and bent by
    bend_m (bx, by): z = bx (1 - u^2) + by (1 - v^2), u = 2 x / width, v = 2 y / height."""

    printed: Target
    scale: tuple[float, float] = (1.0, 1.0)
    bend_m: tuple[float, float] = (0.0, 0.0)

    @property
    def is_exact(self) -> bool:
        return self.scale == (1.0, 1.0) and self.bend_m == (0.0, 0.0)

    def to_board_frame(self, p_printed: np.ndarray) -> np.ndarray:
        """(N, 3) points of the printed definition's plane (z = 0) to where they are on the
        scaled, bent sheet, in the (nominal) board frame, metres."""
        p = np.asarray(p_printed, dtype=float)
        x, y = p[:, 0] * self.scale[0], p[:, 1] * self.scale[1]
        return np.column_stack([x, y, self.height(x, y)])

    def height(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """z (metres) of the sheet at board-frame x, y (metres, on the scaled sheet)."""
        w, h = self.printed.size_m[0] * self.scale[0], self.printed.size_m[1] * self.scale[1]
        u, v = 2.0 * np.asarray(x_m) / w, 2.0 * np.asarray(y_m) / h
        return self.bend_m[0] * (1.0 - u * u) + self.bend_m[1] * (1.0 - v * v)

    def true_corners(self) -> np.ndarray:
        """(M, P, 3) every marker's points where they really are, in the board frame (the
        definition's marker order and corner order), metres."""
        corners = self.printed.all_corners()
        return self.to_board_frame(corners.reshape(-1, 3)).reshape(corners.shape)


@dataclass(frozen=True)
class TrueCell:
    """What the simulated cell really is. kinematics: the arm's true DH table and joint zero
    offsets; intrinsics: the K and distortion the image is formed with (the dataset reports the
    scenario's); T_cam_depthmeasured (4, 4): where a point at p in the colour camera frame
    appears in the aligned depth image (identity: registered exactly); board: as printed."""

    kinematics: URKinematics
    intrinsics: CameraIntrinsics
    T_cam_depthmeasured: np.ndarray
    board: PrintedBoard

    def to_dict(self) -> dict:
        """The true values, for ground_truth.json."""
        k = self.kinematics
        return {
            "kinematics": {
                "d_m": list(k.d),
                "a_m": list(k.a),
                "alpha_rad": list(k.alpha),
                "joint_offset_rad": list(k.theta_offset),
            },
            "intrinsics": self.intrinsics.to_dict(),
            "T_cam_depthmeasured": [[float(v) for v in row] for row in self.T_cam_depthmeasured],
            "board": {
                "scale": list(self.board.scale),
                "bend_m": list(self.board.bend_m),
                "true_corners_m": self.board.true_corners().tolist(),
            }
            | self._marker_centers(),
        }

    def _marker_centers(self) -> dict:
        """Where the printer put each QR marker (other kinds print as one pattern)."""
        printed = self.board.printed
        if not isinstance(printed, BoardDefinition):
            return {}
        return {"marker_centers_m": {str(i): list(c) for i, c in printed.marker_centers_m.items()}}


def reported_intrinsics(scenario: Scenario) -> CameraIntrinsics:
    """The camera the dataset reports: the scenario's K with the lens' reported coefficients
    (zero, the ideal lens, unless errors.lens is on)."""
    k = scenario.camera.intrinsics()
    lens = scenario.errors.lens
    return replace(k, dist=tuple(lens.reported_coefficients)) if lens.enabled else k


def draw_true_cell(scenario: Scenario, board: Target, rng: np.random.Generator) -> TrueCell:
    """The true cell of a scenario, drawn from rng in a fixed order (arm, intrinsics, depth
    registration, board); a section that is off draws nothing."""
    errors = scenario.errors
    kinematics = ROBOTS[scenario.robot]
    if errors.arm.enabled:
        kinematics = _true_kinematics(kinematics, errors.arm, rng)
    intrinsics = reported_intrinsics(scenario)
    if errors.intrinsics.enabled:
        e = errors.intrinsics
        fx, fy = intrinsics.fx, intrinsics.fy
        scale = 1.0 + e.focal_sigma_fraction * rng.standard_normal(2)
        shift = e.principal_point_sigma_px * rng.standard_normal(2)
        intrinsics = replace(
            intrinsics,
            fx=float(fx * scale[0]),
            fy=float(fy * scale[1]),
            cx=float(intrinsics.cx + shift[0]),
            cy=float(intrinsics.cy + shift[1]),
        )
    if errors.lens.enabled:
        intrinsics = replace(intrinsics, dist=tuple(errors.lens.true_coefficients))
    T_cam_depthmeasured = np.eye(4)
    depth = errors.depth
    if depth.enabled and (depth.registration_translation_sigma_m or depth.registration_rotation_sigma_deg):
        t = depth.registration_translation_sigma_m * rng.standard_normal(3)
        w = np.radians(depth.registration_rotation_sigma_deg) * rng.standard_normal(3)
        T_cam_depthmeasured = make_transform(so3_exp(w), t)
    printed = PrintedBoard(board)
    if errors.board.enabled:
        printed = _printed_board(board, errors.board, rng)
    return TrueCell(kinematics, intrinsics, T_cam_depthmeasured, printed)


def _true_kinematics(nominal: URKinematics, arm: ArmErrors, rng: np.random.Generator) -> URKinematics:
    def drawn(values: tuple[float, ...], sigma: float) -> tuple[float, ...]:
        return tuple(float(v) for v in np.asarray(values) + sigma * rng.standard_normal(len(values)))

    return replace(
        nominal,
        name=f"{nominal.name} (true)",
        theta_offset=drawn(nominal.theta_offset, np.radians(arm.joint_offset_sigma_deg)),
        d=drawn(nominal.d, arm.link_length_sigma_m),
        a=drawn(nominal.a, arm.link_length_sigma_m),
        alpha=drawn(nominal.alpha, np.radians(arm.twist_sigma_deg)),
    )


def _printed_board(board: Target, errors: BoardErrors, rng: np.random.Generator) -> PrintedBoard:
    scale = (1.0 + errors.scale_error[0], 1.0 + errors.scale_error[1])
    if not board.markers_placed_one_by_one:
        if errors.marker_placement_sigma_m:
            raise ValueError(
                f"errors.board.marker_placement_sigma_m places markers one by one; board "
                f"'{board.name}' is a {board.kind} board, printed as one pattern (set it to 0)"
            )
        return PrintedBoard(board, scale, tuple(errors.bend_m))
    shifts = errors.marker_placement_sigma_m * rng.standard_normal((len(board.marker_ids), 2))
    centers = {
        i: (c[0] + float(dx), c[1] + float(dy))
        for (i, c), (dx, dy) in zip(board.marker_centers_m.items(), shifts, strict=True)
    }
    return PrintedBoard(replace(board, marker_centers_m=centers), scale, tuple(errors.bend_m))


def scaled_model_errors(errors: ModelErrors, factor: float) -> ModelErrors:
    """The model errors with every systematic magnitude multiplied by factor (>= 0): the arm's
    joint offsets, lengths and twists, the intrinsics' focal and principal-point errors, the
    lens' departure from its reported coefficients, the depth registration error, and the
    print's scale error, sag and marker placement. Per-frame noise (encoder, image) and what is
    not a magnitude (depth correlation length, flying pixels, holes) stay as they are; so do the
    sections' on/off switches. factor 1 returns the errors unchanged."""
    if factor == 1.0:
        return errors
    arm, intrinsics, lens = errors.arm, errors.intrinsics, errors.lens
    depth, board = errors.depth, errors.board
    reported = np.asarray(lens.reported_coefficients, dtype=float)
    true_lens = reported + factor * (np.asarray(lens.true_coefficients, dtype=float) - reported)
    return errors.model_copy(
        update={
            "arm": arm.model_copy(
                update={
                    "joint_offset_sigma_deg": factor * arm.joint_offset_sigma_deg,
                    "link_length_sigma_m": factor * arm.link_length_sigma_m,
                    "twist_sigma_deg": factor * arm.twist_sigma_deg,
                }
            ),
            "intrinsics": intrinsics.model_copy(
                update={
                    "focal_sigma_fraction": factor * intrinsics.focal_sigma_fraction,
                    "principal_point_sigma_px": factor * intrinsics.principal_point_sigma_px,
                }
            ),
            "lens": lens.model_copy(update={"true_coefficients": tuple(float(c) for c in true_lens)}),
            "depth": depth.model_copy(
                update={
                    "registration_translation_sigma_m": factor * depth.registration_translation_sigma_m,
                    "registration_rotation_sigma_deg": factor * depth.registration_rotation_sigma_deg,
                }
            ),
            "board": board.model_copy(
                update={
                    "scale_error": tuple(factor * s for s in board.scale_error),
                    "bend_m": tuple(factor * b for b in board.bend_m),
                    "marker_placement_sigma_m": factor * board.marker_placement_sigma_m,
                }
            ),
        }
    )


def scaled_depth_bias(scale: float, offset_m: float, factor: float) -> tuple[float, float]:
    """A depth bias z_measured = scale * z + offset_m with its departure from the exact depth
    multiplied by factor: (1 + factor (scale - 1), factor offset_m)."""
    return 1.0 + factor * (scale - 1.0), factor * offset_m
