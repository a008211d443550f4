"""The rendered images agree with the documented camera model and the board's ground truth.

Marker corners are measured in the image itself, by rendering the board with
each marker filled solid and locating its edges to sub-pixel precision, and
compared with the ground-truth corners projected with the documented K. IDs
and orientation are checked by decoding the real QR texture.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import zxingcpp
from scipy.ndimage import map_coordinates

from hec.estimator.geometry.camera import project_points
from hec.estimator.geometry.transforms import invert
from hec.estimator.io.board_file import board_to_dict
from hec.estimator.targets.board import BoardDefinition, board_image
from hec.sim.cell import SimCell
from hec.sim.noise import depth_sigma
from hec.sim.scenario import CameraSettings, Scenario
from hec.sim.scene import BOARD_TEXTURE_PX_PER_M, INK_REFLECTANCE, PAPER_REFLECTANCE, _sheet_texture
from hec.sim.simulate import scenario_waypoints

# A camera with unequal focal lengths and an off-centre principal point.
OFF_CENTRE = CameraSettings(width=640, height=480, fx=600.0, fy=612.0, cx=331.3, cy=228.6)


class _SolidBoard(BoardDefinition):
    """The same layout with every module dark: each marker renders as a filled square."""

    def module_matrix(self, marker_id: int) -> np.ndarray:
        return np.ones((self.modules, self.modules), dtype=bool)


def _noise_free(camera: CameraSettings | None = None) -> Scenario:
    return Scenario(camera=camera or CameraSettings(), noise=Scenario().noise.all_off())


def _fill_markers(cell: SimCell) -> None:
    """Replace the board texture in the compiled model (before the renderer uploads it)."""
    solid = _SolidBoard(**{f: getattr(cell.board, f) for f in BoardDefinition.__dataclass_fields__})
    image = board_image(solid, BOARD_TEXTURE_PX_PER_M)
    texture = cell.model.texture("board")
    size = texture.width[0] * texture.height[0] * 3
    adr = texture.adr[0]
    cell.model.tex_data[adr : adr + size] = np.repeat(image[:, :, None], 3, axis=2).ravel()


def _measured_corners(grey: np.ndarray, guess: np.ndarray, search_px: float = 4.0) -> np.ndarray:
    """Sub-pixel corners of a dark quad: fit a line to the 50% crossings along each side.

    guess: (4, 2) approximate corners, only used to know where to look.
    """
    lines = []
    for k in range(4):
        a, b = guess[k], guess[(k + 1) % 4]
        direction = (b - a) / np.linalg.norm(b - a)
        normal = np.array([-direction[1], direction[0]])
        offsets = np.linspace(-search_px, search_px, 81)
        points = []
        for t in np.linspace(0.15, 0.85, 40):
            samples = a + t * (b - a) + offsets[:, None] * normal
            profile = map_coordinates(grey, [samples[:, 1], samples[:, 0]], order=1)
            level = (profile.min() + profile.max()) / 2
            crossing = np.nonzero(np.diff(np.sign(profile - level)))[0]
            if len(crossing) != 1:
                continue
            i = crossing[0]
            frac = (level - profile[i]) / (profile[i + 1] - profile[i])
            points.append(a + t * (b - a) + (offsets[i] + frac * (offsets[1] - offsets[0])) * normal)
        points = np.array(points)
        centre = points.mean(axis=0)
        _, _, vt = np.linalg.svd(points - centre)
        lines.append((centre, vt[0]))
    corners = []
    for k in range(4):
        (p1, d1), (p2, d2) = lines[k - 1], lines[k]
        s = np.linalg.solve(np.column_stack([d1, -d2]), p2 - p1)
        corners.append(p1 + s[0] * d1)
    return np.array(corners)


@pytest.mark.parametrize("camera", [CameraSettings(), OFF_CENTRE], ids=["default-K", "off-centre-K"])
def test_rendered_marker_corners_match_projected_ground_truth(camera: CameraSettings) -> None:
    scenario = _noise_free(camera)
    cell = SimCell(scenario, np.random.default_rng(0))
    _fill_markers(cell)
    K = cell.intrinsics.K
    errors = []
    for waypoint in scenario_waypoints(scenario)[::4]:
        cell.move_to(waypoint)
        rgb, _ = cell.render_true()
        grey = rgb.astype(float).mean(axis=2)
        T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
        for marker_id in cell.board.marker_ids:
            truth = project_points(T_cam_board, cell.board.marker_corners(marker_id), K)
            errors.append(np.linalg.norm(_measured_corners(grey, truth) - truth, axis=1))
    errors = np.concatenate(errors)
    cell.close()
    assert errors.mean() < 0.5, f"mean corner error {errors.mean():.3f} px"
    assert errors.max() < 1.0, f"max corner error {errors.max():.3f} px"


def test_decoded_ids_and_orientation_match_the_board() -> None:
    """Each code decodes to its own ID where the ground truth puts it, corners in the board order
    (a mirrored or rotated texture would swap them)."""
    scenario = _noise_free()
    cell = SimCell(scenario, np.random.default_rng(0))
    for waypoint in scenario_waypoints(scenario)[::5]:
        cell.move_to(waypoint)
        rgb, _ = cell.render_true()
        T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
        found = {}
        for code in zxingcpp.read_barcodes(rgb):
            marker_id = cell.board.marker_id_from_payload(code.text)
            p = code.position
            found[marker_id] = np.array(
                [[c.x, c.y] for c in (p.top_left, p.top_right, p.bottom_right, p.bottom_left)]
            )
        assert None not in found
        assert len(found) >= 6, f"only {sorted(found)} decoded"
        for marker_id, corners in found.items():
            truth = project_points(T_cam_board, cell.board.marker_corners(marker_id), cell.intrinsics.K)
            # Decoders place the finder-less bottom-right corner a few pixels off; a
            # swapped corner would be a whole marker side (about 90 px) away.
            assert np.linalg.norm(corners - truth, axis=1).max() < 8.0
    cell.close()


def _true_depth_at(cell: SimCell, uv: np.ndarray) -> np.ndarray:
    """Depth along the optical axis of the board plane at pixel centres uv (N, 2)."""
    T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
    normal, origin = T_cam_board[:3, 2], T_cam_board[:3, 3]
    rays = np.column_stack([uv, np.ones(len(uv))]) @ np.linalg.inv(cell.intrinsics.K).T
    return (normal @ origin) / (rays @ normal)


def _marker_centre_pixels(cell: SimCell) -> np.ndarray:
    T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
    centres = np.array([cell.board.marker_center(i) for i in cell.board.marker_ids])
    return np.round(project_points(T_cam_board, centres, cell.intrinsics.K))


def test_depth_at_marker_centres_is_exact_without_noise() -> None:
    scenario = _noise_free()
    cell = SimCell(scenario, np.random.default_rng(0))
    scale = scenario.noise.depth_quantisation.depth_scale_m
    raw_errors, stored_errors = [], []
    for waypoint in scenario_waypoints(scenario):
        cell.move_to(waypoint)
        _, depth_rendered = cell.render_true()
        frame, _ = cell.capture()
        uv = _marker_centre_pixels(cell)
        truth = _true_depth_at(cell, uv)
        rows, cols = uv[:, 1].astype(int), uv[:, 0].astype(int)
        raw_errors.append(depth_rendered[rows, cols] - truth)
        stored = np.round(frame.depth_m[rows, cols] / scale) * scale
        stored_errors.append(stored - truth)
    cell.close()
    assert np.abs(np.concatenate(raw_errors)).max() < 2e-5
    # Quantisation off here, so the frame keeps the rendered depth; rounding to the
    # dataset's 1 mm steps then costs at most half a step.
    assert np.abs(np.concatenate(stored_errors)).max() <= scale / 2 + 2e-5


def test_depth_at_marker_centres_within_three_sigma_of_the_noise_model() -> None:
    scenario = Scenario()
    cell = SimCell(scenario, np.random.default_rng(11))
    scale = scenario.noise.depth_quantisation.depth_scale_m
    normalised = []
    for waypoint in scenario_waypoints(scenario):
        cell.move_to(waypoint)
        frame, _ = cell.capture()
        uv = _marker_centre_pixels(cell)
        truth = _true_depth_at(cell, uv)
        measured = frame.depth_m[uv[:, 1].astype(int), uv[:, 0].astype(int)]
        valid = measured > 0
        sigma = np.sqrt(depth_sigma(truth, scenario.noise.depth) ** 2 + scale**2 / 12)
        normalised.append(((measured - truth) / sigma)[valid])
    cell.close()
    z = np.concatenate(normalised)
    assert len(z) >= 0.95 * 8 * len(scenario_waypoints(scenario))
    assert np.mean(np.abs(z) <= 3.0) >= 0.98
    assert 0.8 < np.sqrt(np.mean(z**2)) < 1.25


def test_a_sheet_texture_is_drawn_once_per_board_definition() -> None:
    board = Scenario().board_definition()
    texture = _sheet_texture(board)
    assert _sheet_texture(board) is texture and not texture.flags.writeable
    # the texture is the sheet at the renderer's resolution, in the print's reflectances
    coverage = board_image(board, BOARD_TEXTURE_PX_PER_M)
    assert texture.shape == (*coverage.shape, 3)
    assert set(np.unique(texture[..., 0])) >= {round(255 * INK_REFLECTANCE), round(255 * PAPER_REFLECTANCE)}
    moved = replace(board, marker_centers_m={**board.marker_centers_m, 0: (0.0, 0.0)})
    assert not np.array_equal(_sheet_texture(moved), texture)
    solid = _SolidBoard(**{f: getattr(board, f) for f in BoardDefinition.__dataclass_fields__})
    assert board_to_dict(solid) == board_to_dict(board) and not np.array_equal(_sheet_texture(solid), texture)
