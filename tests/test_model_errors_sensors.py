"""The model errors of the depth and colour sensors in real MuJoCo renders of the cell (hec.sim.real_camera,
hec.sim.depth_errors, hec.sim.image_effects through SimCell.capture), and that simulating with them is
reproducible and, when they are off, leaves the ideal cell's datasets exactly as they were.

Each test switches on one effect with every sensor noise off (unless the test is about the noise) and
compares the captured frame with what the scenario's settings predict: the noise-free render
(SimCell.render_true), the board's pose and the camera's K. Board pixels come from projecting the
sheet's outline, eroded so that no pixel straddles its edge.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import maximum_filter, minimum_filter

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.camera import back_project, project
from hec.estimator.geometry.transforms import invert
from hec.estimator.geometry.waypoints import write_waypoint_file
from hec.estimator.io.dataset import load_dataset
from hec.sim.cell import SimCell
from hec.sim.depth_errors import autocorrelation_length
from hec.sim.noise import depth_sigma
from hec.sim.scenario import ModelErrors, NoiseSettings, Scenario, load_scenario, scenario_from_dict
from hec.sim.simulate import scenario_waypoints, simulate

NOISE_OFF = {name: {"enabled": False} for name in NoiseSettings.model_fields}
DEPTH_ERRORS_OFF = {
    "enabled": True,
    "correlation_px": 1.0,
    "registration_translation_sigma_m": 0.0,
    "registration_rotation_sigma_deg": 0.0,
    "flying_pixel_probability": 0.0,
    "holes_per_megapixel": 0.0,
}
IMAGE_ERRORS_OFF = {
    "enabled": True,
    "vignetting_corner_falloff": 0.0,
    "light_gradient": 0.0,
    "highlight_peak_grey": 0.0,
    "exposure_sigma": 0.0,
    "motion_speed_sigma_m_s": 0.0,
    "motion_rate_sigma_deg_s": 0.0,
}
WAYPOINTS = scenario_waypoints(Scenario())  # the default trajectory; 0 looks straight down, 1 is tilted


def _cell(seed: int = 0, noise: dict | None = None, depth: dict | None = None, image: dict | None = None):
    """A SimCell with every noise model off except `noise` and the given errors sections on."""
    errors = {}
    if depth is not None:
        errors["depth"] = {**DEPTH_ERRORS_OFF, **depth}
    if image is not None:
        errors["image"] = {**IMAGE_ERRORS_OFF, **image}
    scenario = scenario_from_dict({"noise": {**NOISE_OFF, **(noise or {})}, "errors": errors})
    return SimCell(scenario, np.random.default_rng(seed))


def _T_cam_board(cell: SimCell) -> np.ndarray:
    return invert(cell.T_base_cam()) @ cell.cell.T_base_board


def _board_mask(cell: SimCell, erode_px: int) -> np.ndarray:
    """(H, W) bool: pixels of the board sheet at least erode_px inside its projected outline."""
    w, h = cell.board.size_m
    outline = np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0], [-w / 2, h / 2, 0]])
    k = cell.camera.intrinsics
    uv = project(_T_cam_board(cell), outline, k)
    mask = np.zeros((k.height, k.width), np.uint8)
    cv2.fillPoly(mask, [np.round(uv * 16).astype(np.int32)], 1, shift=4)
    return cv2.erode(mask, np.ones((2 * erode_px + 1,) * 2, np.uint8)).astype(bool)


def _pixels(mask: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    return np.column_stack([u, v]).astype(float)


# --- depth ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("length_px", [3.0, 6.0])
def test_depth_noise_on_the_board_is_correlated_over_the_set_length(length_px: float) -> None:
    # subpixel 1.0: sigma = 9.5 mm at 0.45 m, far above quantisation (off anyway).
    cell = _cell(noise={"depth": {"enabled": True, "subpixel": 1.0}}, depth={"correlation_px": length_px})
    cell.move_to(WAYPOINTS[1])  # tilted: z and so sigma(z) vary over the board
    _, depth_true = cell.render_true()
    frame, _ = cell.capture()
    cell.close()
    mask = _board_mask(cell, 3)
    normalised = (frame.depth_m - depth_true) / depth_sigma(depth_true, cell.scenario.noise.depth)
    measured = autocorrelation_length(normalised, mask)
    assert measured == pytest.approx(length_px, rel=0.2)
    # Unit variance on the near and on the far half of the board: the noise scales as sigma(z).
    near = depth_true < np.median(depth_true[mask])
    for half in (mask & near, mask & ~near):
        assert float(normalised[half].std()) == pytest.approx(1.0, rel=0.1)


def _plane(T_cam_plane: np.ndarray) -> tuple[np.ndarray, float]:
    """The z = 0 plane of a frame as (unit normal n (3,), offset d) in the camera frame: n . p = d."""
    n = T_cam_plane[:3, 2]
    return n, float(n @ T_cam_plane[:3, 3])


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    centre = points.mean(axis=0)
    n = np.linalg.svd(points - centre, full_matrices=False)[2][2]
    n = -n if n[2] > 0 else n  # face the camera, as the board's +z does
    return n, float(n @ centre)


def test_misregistered_depth_shows_the_board_plane_moved_by_T_cam_depthmeasured() -> None:
    cell = _cell(
        seed=2, depth={"registration_translation_sigma_m": 0.003, "registration_rotation_sigma_deg": 0.3}
    )
    T_moved = cell.true.T_cam_depthmeasured  # a point at p (camera frame) appears at T_moved @ p
    cell.move_to(WAYPOINTS[1])
    frame, _ = cell.capture()
    _, depth_true = cell.render_true()
    cell.close()
    k = cell.camera.intrinsics
    uv = _pixels(_board_mask(cell, 12))  # 12 px: inside both the true and the moved outline
    n_true, d_true = _plane(_T_cam_board(cell))
    n_moved, d_moved = _plane(T_moved @ _T_cam_board(cell))
    rays = back_project(uv, np.ones(len(uv)), k)
    z_moved, z_true = d_moved / (rays @ n_moved), d_true / (rays @ n_true)
    z = frame.depth_m[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    np.testing.assert_allclose(z_true, depth_true[uv[:, 1].astype(int), uv[:, 0].astype(int)], atol=2e-5)
    assert np.abs(z_moved - z_true).max() > 1e-3  # the error moves the board by over a millimetre
    assert np.abs(z - z_moved).max() < 1e-5
    n_fit, d_fit = _fit_plane(back_project(uv, z, k))
    angle_moved = np.degrees(np.arccos(np.clip(n_fit @ n_moved, -1, 1)))
    angle_true = np.degrees(np.arccos(np.clip(n_true @ n_moved, -1, 1)))
    assert angle_true > 0.2 and angle_moved < 1e-3
    assert abs(d_fit - d_moved) < 2e-6 and abs(d_true - d_moved) > 5e-4


def test_flying_pixels_only_at_depth_edges_with_mixed_depths() -> None:
    # Looking straight down, the only depth edge is the board's outline, 3 mm above the table: a 2 mm
    # edge threshold makes it one. Holes on too: they must not disturb the flying pixels.
    settings = {"flying_pixel_probability": 0.5, "flying_pixel_width_px": 2, "flying_pixel_edge_m": 0.002}
    cell = _cell(depth={**settings, "holes_per_megapixel": 300.0})
    cell.move_to(WAYPOINTS[0])
    _, z_true = cell.render_true()
    z = cell.capture()[0].depth_m
    cell.close()
    width = settings["flying_pixel_width_px"]
    jump = np.zeros(z_true.shape, bool)
    for axis in (0, 1):
        step = np.abs(np.diff(z_true, axis=axis)) > settings["flying_pixel_edge_m"]
        lo, hi = [slice(None)] * 2, [slice(None)] * 2
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        jump[tuple(lo)] |= step
        jump[tuple(hi)] |= step
    edge = maximum_filter(jump, size=2 * width - 1)  # within width - 1 pixels of a jump pixel
    changed = (z > 0) & (np.abs(z - z_true) > 1e-6)
    assert edge.sum() > 3000
    assert not np.any(changed & ~edge)
    fraction = changed[edge].mean()
    assert fraction == pytest.approx(settings["flying_pixel_probability"], abs=0.06)
    fg = minimum_filter(z_true, size=2 * width + 1)[changed]
    bg = maximum_filter(z_true, size=2 * width + 1)[changed]
    assert np.all((z[changed] >= fg - 1e-6) & (z[changed] <= bg + 1e-6))
    # Mixed: spread over the whole step, not snapped to either side.
    a = (z[changed] - fg) / (bg - fg)
    assert 0.4 < a.mean() < 0.6 and np.mean((a > 0.1) & (a < 0.9)) > 0.7


@pytest.mark.parametrize("per_megapixel", [0.0, 500.0, 2000.0])
def test_invalid_depth_fraction_grows_with_the_holes_set(per_megapixel: float) -> None:
    radius_px = 3.0
    cell = _cell(seed=4, depth={"holes_per_megapixel": per_megapixel, "hole_radius_px": radius_px})
    cell.move_to(WAYPOINTS[0])
    assert np.all(cell.render_true()[1] > 0)  # every pixel has depth without holes
    invalid = np.mean([np.mean(cell.capture()[0].depth_m == 0) for _ in range(3)])
    cell.close()
    expected = 1.0 - np.exp(-per_megapixel * 1e-6 * 1.25 * np.pi * radius_px**2)
    if per_megapixel == 0.0:
        assert invalid == 0.0
    else:
        assert invalid == pytest.approx(expected, rel=0.2)


# --- the colour image ----------------------------------------------------------------------------


def _capture_pair(on: SimCell, off: SimCell, waypoint_index: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float grey of the same view from the cell with errors.image on and the one without."""
    grey = []
    for cell in (on, off):
        cell.move_to(WAYPOINTS[waypoint_index])
        grey.append(cell.capture()[0].rgb.astype(float).mean(axis=2))
    return grey[0], grey[1]


def _expected_gain(cell: SimCell, falloff: float, gradient: float, direction_deg: float) -> np.ndarray:
    """(H, W) vignetting (cos^4 profile, falloff at the farthest corner) times the linear ramp."""
    k = cell.camera.intrinsics
    u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
    cos4 = (1.0 / (1.0 + ((u - k.cx) / k.fx) ** 2 + ((v - k.cy) / k.fy) ** 2)) ** 2
    corners = (u[[0, 0, -1, -1], [0, -1, 0, -1]], v[[0, 0, -1, -1], [0, -1, 0, -1]])
    corner_cos4 = cos4[corners[1].astype(int), corners[0].astype(int)].min()
    vignetting = 1.0 - falloff * (1.0 - cos4) / (1.0 - corner_cos4)
    c, s = np.cos(np.radians(direction_deg)), np.sin(np.radians(direction_deg))
    along = c * (u - (k.width - 1) / 2) + s * (v - (k.height - 1) / 2)
    ramp = 1.0 + gradient * along / (abs(c) * (k.width - 1) + abs(s) * (k.height - 1))
    return vignetting * ramp


def test_vignetting_and_light_gradient_change_the_board_brightness_as_set() -> None:
    settings = {
        "vignetting_corner_falloff": 0.3,
        "light_gradient": 0.2,
        "light_gradient_direction_deg": 120.0,
    }
    on, off = _cell(seed=5, image=settings), _cell(seed=5)
    lit, plain = _capture_pair(on, off, 2)  # a near view: the board spans much of the image
    on.close()
    off.close()
    gain = _expected_gain(on, *settings.values())
    board = _board_mask(on, 2) & (plain > 100)  # the paper, away from quantisation
    ratio = lit[board] / plain[board]
    # Rounded to grey levels, each channel: within half a level (and the channel mean likewise).
    assert np.abs(lit - plain * gain)[board].max() <= 0.51
    # As set: the brightness over the board follows the gain, whose range here is large.
    assert gain[board].max() - gain[board].min() > 0.2
    assert np.corrcoef(ratio, gain[board])[0, 1] > 0.99


def test_exposure_is_a_uniform_gain_that_differs_between_views() -> None:
    on, off = _cell(seed=6, image={"exposure_sigma": 0.1}), _cell(seed=6)
    gains = []
    for i in (0, 1, 2):
        lit, plain = _capture_pair(on, off, i)
        paper = (plain > 100) & (lit < 254)
        g = float(np.sum(lit[paper] * plain[paper]) / np.sum(plain[paper] ** 2))
        assert np.abs(lit - g * plain)[paper].max() <= 0.51 + 255 * 0.002  # one gain for the whole image
        gains.append(g)
    on.close()
    off.close()
    assert np.all(np.abs(np.array(gains) - 1.0) < 0.4)
    assert np.min(np.abs(np.diff(sorted(gains)))) > 0.005, gains


def test_highlight_is_centred_on_the_lamp_mirror_point() -> None:
    # Place the lamp so that its mirror image on the board lies at p_board, off the board centre.
    probe = _cell()
    probe.move_to(WAYPOINTS[1])
    camera_board = invert(_T_cam_board(probe))[:3, 3]
    probe.close()
    p_board, lamp_z = np.array([0.06, 0.04, 0.0]), 1.5
    # Mirror reflection: p lies on the line from the camera to the lamp's image below the plane,
    # p = (c L_z + L c_z) / (c_z + L_z), solved for the lamp's x, y.
    lamp_xy = (p_board[:2] * (camera_board[2] + lamp_z) - camera_board[:2] * lamp_z) / camera_board[2]
    peak, radius = 40.0, 15.0  # 40: the paper (~206) stays below 255
    settings = {"light_position_board_m": [*lamp_xy, lamp_z], "highlight_peak_grey": peak}
    on, off = _cell(seed=7, image={**settings, "highlight_radius_px": radius}), _cell(seed=7)
    lit, plain = _capture_pair(on, off, 1)
    on.close()
    off.close()
    expected_uv = project(_T_cam_board(on), p_board[None], on.camera.intrinsics)[0]
    glare = lit - plain
    use = (glare > 8) & (lit < 255)
    v, u = np.nonzero(use)
    # log glare = log peak - a ((u - u0)^2 + (v - v0)^2): linear in (u, v, u^2 + v^2, 1), weighted.
    A = np.column_stack([u, v, u * u + v * v, np.ones(u.size)]).astype(float)
    w = glare[use]
    coef = np.linalg.lstsq(A * w[:, None], np.log(glare[use]) * w, rcond=None)[0]
    a = -coef[2]
    centre = np.array([coef[0], coef[1]]) / (2 * a)
    assert np.linalg.norm(centre - expected_uv) < 0.1, (centre, expected_uv)
    assert np.sqrt(np.log(2) / a) == pytest.approx(radius, rel=0.02)
    assert np.exp(coef[3] + a * centre @ centre) == pytest.approx(peak, rel=0.02)
    assert _board_mask(on, 40)[int(round(centre[1])), int(round(centre[0]))]


# --- reproducibility -----------------------------------------------------------------------------

# Every [errors.*] section off, every magnitude other than its default.
ERRORS_OFF_TOML = """
[errors.arm]
enabled = false
joint_offset_sigma_deg = 0.5
link_length_sigma_m = 0.002
twist_sigma_deg = 0.5
encoder_sigma_deg = 0.01
[errors.intrinsics]
enabled = false
focal_sigma_fraction = 0.01
principal_point_sigma_px = 5.0
[errors.lens]
enabled = false
true_coefficients = [0.2, -0.4, 0.001, -0.001, 0.05]
reported_coefficients = [0.01, -0.02, 0.0, 0.0, 0.0]
[errors.depth]
enabled = false
correlation_px = 4.0
registration_translation_sigma_m = 0.002
registration_rotation_sigma_deg = 0.3
flying_pixel_probability = 0.9
flying_pixel_width_px = 2
flying_pixel_edge_m = 0.01
holes_per_megapixel = 100.0
hole_radius_px = 5.0
[errors.board]
enabled = false
scale_error = [0.01, 0.005]
bend_m = [0.002, 0.001]
marker_placement_sigma_m = 0.0002
[errors.image]
enabled = false
vignetting_corner_falloff = 0.4
light_gradient = 0.3
light_gradient_direction_deg = 120.0
light_position_board_m = [0.2, -0.1, 1.0]
highlight_peak_grey = 90.0
highlight_radius_px = 30.0
exposure_sigma = 0.1
motion_speed_sigma_m_s = 0.02
motion_rate_sigma_deg_s = 2.0
exposure_time_s = 0.03
"""
FILE_TRAJECTORY = '\n[trajectory]\nkind = "file"\nfile = "waypoints.csv"\n'


def _tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def datasets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Four waypoints of the default trajectory, seed 3: realistic twice, the errors-off file, default."""
    tmp = tmp_path_factory.mktemp("model_errors")
    write_waypoint_file(tmp / "waypoints.csv", WAYPOINTS[:4])
    realistic = (models_dir() / "scenarios" / "realistic.toml").read_text()
    files = {"realistic": realistic, "errors-off": ERRORS_OFF_TOML, "default": ""}
    out = {}
    for name, text in files.items():
        (tmp / f"{name}.toml").write_text(text + FILE_TRAJECTORY)
    for name in ("realistic", "realistic-again", "errors-off", "default"):
        scenario = load_scenario(tmp / f"{name.removesuffix('-again')}.toml")
        out[name] = simulate(scenario, tmp / name, seed=3, progress=False).out_dir
    return out


def test_realistic_simulation_is_reproducible_byte_for_byte(datasets: dict[str, Path]) -> None:
    a, b = _tree_bytes(datasets["realistic"]), _tree_bytes(datasets["realistic-again"])
    assert {"dataset.json", "frames.csv", "ground_truth.json", "rgb/000003.png", "depth/000003.png"} <= set(a)
    assert a.keys() == b.keys()
    for name in a:
        assert a[name] == b[name], f"{name} differs between two realistic runs with the same seed"
    assert load_dataset(datasets["realistic"]).ground_truth.model_errors is not None


def test_errors_off_leave_the_default_datasets_unchanged(datasets: dict[str, Path]) -> None:
    errors_off, default = _tree_bytes(datasets["errors-off"]), _tree_bytes(datasets["default"])
    assert errors_off.keys() == default.keys()
    assert sum(name.endswith(".png") for name in default) == 8
    for name in default:
        if name != "dataset.json":
            assert errors_off[name] == default[name], f"{name} differs with every model error off"
    meta_off, meta_default = json.loads(errors_off["dataset.json"]), json.loads(default["dataset.json"])
    table = meta_off["simulation"]["scenario"].pop("errors")
    assert meta_off == meta_default and "errors" not in meta_default["simulation"]["scenario"]
    # The recorded table is the file's: every section off, every magnitude other than the default.
    recorded = ModelErrors(**table)
    for section in ModelErrors.model_fields:
        values, defaults = getattr(recorded, section), getattr(ModelErrors(), section)
        assert not values.enabled
        for key in type(values).model_fields:
            if key != "enabled":
                assert getattr(values, key) != getattr(defaults, key), f"errors.{section}.{key}"
