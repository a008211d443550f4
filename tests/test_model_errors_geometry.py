"""The model errors of a scenario (hec.sim.scenario.ModelErrors) reach the simulated cell's geometry.

With errors.arm on, MuJoCo moves the arm with the true DH table while the cell reports the
nominal model's flange pose; with errors.intrinsics, errors.lens and errors.board on, the image
is formed with the true K, the true lens and the board as printed, while the dataset reports
the nominal ones. Corners are measured in the rendered image itself (markers filled solid and
their edges located to sub-pixel precision, or the QR detector on the real texture) and compared
with OpenCV's projection of the true and of the reported cell.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.kinematics import IK_RESTARTS, forward
from hec.estimator.geometry.transforms import invert, make_transform, pose_error
from hec.estimator.geometry.waypoints import Waypoint, look_at_board
from hec.estimator.targets.board import BoardDefinition, board_image
from hec.estimator.targets.qr import QRDetector
from hec.sim.cell import SimCell
from hec.sim.model_errors import draw_true_cell
from hec.sim.scenario import NoiseSettings, Scenario, load_scenario, scenario_from_dict
from hec.sim.scene import ARM_PREFIX, BOARD_TEXTURE_PX_PER_M, CAMERA_NAME, R_CAM_MJCAM
from hec.sim.simulate import scenario_waypoints

REALISTIC = models_dir() / "scenarios" / "realistic.toml"
SEED = 7
# Views of the default trajectory rolled about the optical axis (hec.estimator.geometry.waypoints'
# ROTATION_RICH_VIEWS 9-16). With roll 0 the marker edges run along the pixel rows and
# columns and the renderer places them with a sub-pixel-phase error of up to ~0.1 px (seen on
# the ideal cell too); rolled edges sweep every phase and are located to ~0.01 px.
ROLLED_VIEWS = (9, 11, 12, 13, 14, 15, 16)
# Strong enough to matter everywhere (2-4 px), tangential terms to pin OpenCV's p1/p2 order.
LENS = (0.10, -0.20, 0.001, -0.0015, 0.0)
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def _scenario(errors: dict) -> Scenario:
    """The default scenario with these model error sections, every noise model off."""
    return scenario_from_dict({"errors": errors, "noise": NoiseSettings().all_off().model_dump()})


# --- image measurement ---------------------------------------------------------------------


class _SolidBoard(BoardDefinition):
    """The same layout with every module dark: each marker renders as a filled square."""

    def module_matrix(self, marker_id: int) -> np.ndarray:
        return np.ones((self.modules, self.modules), dtype=bool)


def _fill_markers(cell: SimCell) -> None:
    """Replace the board texture of the compiled model (before the renderer uploads it) with
    the printed layout's markers filled solid."""
    printed = cell.true.board.printed
    solid = _SolidBoard(**{f: getattr(printed, f) for f in BoardDefinition.__dataclass_fields__})
    image = board_image(solid, BOARD_TEXTURE_PX_PER_M)
    texture = cell.model.texture("board")
    size = texture.width[0] * texture.height[0] * 3
    adr = texture.adr[0]
    cell.model.tex_data[adr : adr + size] = np.repeat(image[:, :, None], 3, axis=2).ravel()


def _project(p_cam: np.ndarray, K: np.ndarray, dist: tuple[float, ...]) -> np.ndarray:
    """OpenCV's projection of camera-frame points (N, 3), metres -> (N, 2) pixels."""
    p = np.ascontiguousarray(p_cam, dtype=np.float64).reshape(-1, 1, 3)
    uv, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), K, np.asarray(dist, dtype=np.float64))
    return uv.reshape(-1, 2)


def _grey(rgb: np.ndarray) -> np.ndarray:
    """Grey levels, smoothed (sigma 1 px) so that linear interpolation between pixels follows
    the edge profile; a symmetric blur does not move a straight edge."""
    return cv2.GaussianBlur(rgb.astype(np.float64).mean(axis=2), (0, 0), 1.0)


def _measured_corners(
    grey: np.ndarray, p_cam: np.ndarray, K: np.ndarray, dist: tuple[float, ...], search_px: float = 8.0
) -> np.ndarray:
    """Sub-pixel corners (4, 2) of a dark quad whose corners are near the projection of p_cam
    (4, 3): the 50% crossings across each side (searched along the side's predicted image,
    curved by the lens) are undistorted with OpenCV (K, dist), where the sides are straight
    lines; the lines' intersections are distorted back with cv2.projectPoints. The prediction
    only says where to look: the corners come from the image."""
    lines = []
    offsets = np.linspace(-search_px, search_px, 81)
    for k in range(4):
        a, b = p_cam[k], p_cam[(k + 1) % 4]
        along = a + np.linspace(0.15, 0.85, 40)[:, None] * (b - a)
        uv = _project(along, K, dist)
        tangent = _project(along + 1e-3 * (b - a), K, dist) - uv
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        normals = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        crossings = []
        for p, normal in zip(uv, normals, strict=True):
            samples = p + offsets[:, None] * normal
            profile = map_coordinates(grey, [samples[:, 1], samples[:, 0]], order=1)
            level = (profile.min() + profile.max()) / 2
            crossing = np.nonzero(np.diff(np.sign(profile - level)))[0]
            if len(crossing) != 1:
                continue
            i = crossing[0]
            frac = (level - profile[i]) / (profile[i + 1] - profile[i])
            crossings.append(p + (offsets[i] + frac * (offsets[1] - offsets[0])) * normal)
        assert len(crossings) >= 20, f"side {k}: edge found at only {len(crossings)} of 40 places"
        src = np.array(crossings).reshape(-1, 1, 2)
        xy = cv2.undistortPointsIter(src, K, np.asarray(dist, float), None, None, _UNDISTORT).reshape(-1, 2)
        centre = xy.mean(axis=0)
        _, _, vt = np.linalg.svd(xy - centre)
        lines.append((centre, vt[0]))
    corners_xy = []
    for k in range(4):
        (p1, d1), (p2, d2) = lines[k - 1], lines[k]
        s = np.linalg.solve(np.column_stack([d1, -d2]), p2 - p1)
        corners_xy.append(p1 + s[0] * d1)
    return _project(np.column_stack([corners_xy, np.ones(4)]), K, dist)


def _corner_errors(cell: SimCell, views: list[Waypoint]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over the views (every one must be accepted), the measured corners of every marker
    fully in the image against the projection with the true camera and with the reported one.
    Returns the errors (N,) px for the true and the reported camera, and the corners' (N, 2)
    normalised image coordinates (true camera)."""
    true_k, reported = cell.true.intrinsics, cell.intrinsics
    to_true, to_reported, normalised = [], [], []
    for waypoint in views:
        cell.move_to(waypoint)
        frame, _ = cell.capture()
        grey = _grey(frame.rgb)
        T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
        for corners in cell.true.board.true_corners():
            p_cam = corners @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            truth = _project(p_cam, true_k.K, true_k.dist)
            inside = (truth >= 8.0) & (truth <= [true_k.width - 9.0, true_k.height - 9.0])
            if not inside.all():
                continue
            measured = _measured_corners(grey, p_cam, true_k.K, true_k.dist)
            to_true.append(np.linalg.norm(measured - truth, axis=1))
            to_reported.append(np.linalg.norm(measured - _project(p_cam, reported.K, reported.dist), axis=1))
            normalised.append((truth - true_k.K[:2, 2]) / [true_k.fx, true_k.fy])
    return np.concatenate(to_true), np.concatenate(to_reported), np.concatenate(normalised)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


# --- 1. the arm ------------------------------------------------------------------------------


def _joint_sets(n: int, seed: int) -> list[np.ndarray]:
    """The IK restarts and n random joint sets inside UR's limits (radians)."""
    rng = np.random.default_rng(seed)
    return list(IK_RESTARTS) + [rng.uniform(-np.pi, np.pi, 6) for _ in range(n)]


def test_mujoco_arm_and_camera_follow_the_true_kinematics() -> None:
    """The rendered flange (and the camera on it) is where the TRUE DH table and joint offsets
    put it, to 1e-9, not where the nominal model does."""
    cell = SimCell(_scenario({"arm": {"enabled": True}}), np.random.default_rng(SEED))
    true, nominal = cell.cell.true_kinematics, cell.cell.kinematics
    assert all(true.theta_offset) and true.d != nominal.d and true.alpha != nominal.alpha
    T_base_world = invert(cell.cell.T_world_base)
    nominal_gaps = []
    for q in _joint_sets(6, seed=1):
        cell.set_joints(q)
        body = cell.data.body(ARM_PREFIX + "flange")
        T_base_flange = T_base_world @ make_transform(body.xmat.reshape(3, 3), body.xpos)
        np.testing.assert_allclose(T_base_flange, forward(true, q), rtol=0, atol=1e-9)
        camera = cell.data.cam(CAMERA_NAME)
        T_world_cam = make_transform(camera.xmat.reshape(3, 3) @ R_CAM_MJCAM, camera.xpos)
        np.testing.assert_allclose(T_base_world @ T_world_cam, cell.T_base_cam(), rtol=0, atol=1e-9)
        nominal_gaps.append(pose_error(T_base_flange, forward(nominal, q))[0])
    cell.close()
    assert min(nominal_gaps) > 1e-4, "the rendered arm moves with the nominal model"


def test_reported_flange_pose_is_the_nominal_model_of_the_true_joints() -> None:
    """Without encoder and robot pose noise the reported pose is exactly forward(nominal, q)
    and the true one exactly forward(true, q), the same for the same seed and joints, and
    their difference depends on the configuration."""
    scenario = _scenario({"arm": {"enabled": True, "encoder_sigma_deg": 0.0}})
    assert not scenario.noise.robot_pose.enabled
    joint_sets = _joint_sets(2, seed=2)[-3:]
    runs = []
    for _ in range(2):
        cell = SimCell(scenario, np.random.default_rng(SEED))
        nominal, true = cell.cell.kinematics, cell.cell.true_kinematics
        poses = []
        for q in joint_sets:
            cell.set_joints(q)
            reported, actual = cell.flange_pose(), cell.true_flange_pose()
            assert np.array_equal(reported, forward(nominal, q))
            assert np.array_equal(actual, forward(true, q))
            poses.append((reported, actual))
        frame, truth = cell.capture()  # the dataset's path reports the same
        assert np.array_equal(frame.T_base_flange, forward(nominal, joint_sets[-1]))
        assert np.array_equal(frame.joints, joint_sets[-1])
        assert np.array_equal(truth.T_base_flange, forward(true, joint_sets[-1]))
        cell.close()
        runs.append(np.array(poses))
    assert np.array_equal(runs[0], runs[1]), "same seed and joints, different poses"
    # The error is not one fixed offset: between configurations its translation changes by
    # more than 0.1 mm (in the base frame and in the flange frame) and its rotation by more
    # than 0.01 degrees.
    in_flange = [invert(actual) @ reported for reported, actual in runs[0]]
    in_base = [reported[:3, 3] - actual[:3, 3] for reported, actual in runs[0]]
    for i in range(len(joint_sets) - 1):
        dt, dr = pose_error(in_flange[i], in_flange[i + 1])
        moved = np.linalg.norm(in_base[i] - in_base[i + 1])
        print(f"error changes by {1e3 * moved:.2f} mm (base), {1e3 * dt:.2f} mm, {np.degrees(dr):.3f} deg")
        assert moved > 1e-4 and dt > 1e-4 and np.degrees(dr) > 0.01, (moved, dt, np.degrees(dr))


def test_nominal_model_error_over_the_default_views_has_a_real_arms_size() -> None:
    """realistic.toml's arm errors give the nominal model a 0.3-10 mm RMS pose error over the
    default trajectory's joints (this cell's draw and 20 others)."""
    arm = load_scenario(REALISTIC).errors.arm
    scenario = _scenario({"arm": arm.model_dump()})
    cell = SimCell(scenario, np.random.default_rng(SEED))
    joints = []
    for waypoint in scenario_waypoints(Scenario()):
        cell.move_to(waypoint)
        joints.append(cell.joints.copy())
    cell.close()
    assert len(joints) == 17
    nominal = cell.cell.kinematics
    draws = [cell.cell.true_kinematics] + [
        draw_true_cell(scenario, cell.board, np.random.default_rng(seed)).kinematics for seed in range(20)
    ]
    per_draw = []
    for true in draws:
        e = np.array([pose_error(forward(nominal, q), forward(true, q)) for q in joints])
        per_draw.append((1e3 * e[:, 0], np.degrees(e[:, 1])))
    dt_mm = np.concatenate([d[0] for d in per_draw])
    dr_deg = np.concatenate([d[1] for d in per_draw])
    own_t, own_r = per_draw[0]
    print(
        f"this cell: {_rms(own_t):.2f} mm RMS ({own_t.max():.2f} max), {_rms(own_r):.3f} deg RMS "
        f"({own_r.max():.3f} max); 21 draws: {_rms(dt_mm):.2f} mm RMS ({dt_mm.max():.2f} max), "
        f"{_rms(dr_deg):.3f} deg RMS ({dr_deg.max():.3f} max); per-draw RMS "
        f"{min(_rms(d[0]) for d in per_draw):.2f}-{max(_rms(d[0]) for d in per_draw):.2f} mm"
    )
    assert 0.3 < _rms(own_t) < 10.0
    assert 0.3 < _rms(dt_mm) < 10.0
    assert 0.02 < _rms(dr_deg) < 2.0


# --- 2.-3. the camera ------------------------------------------------------------------------


def test_image_is_formed_with_the_true_intrinsics() -> None:
    """With realistic.toml's intrinsics errors, rendered corners sit where the TRUE K projects
    them (< 0.1 px), not the reported K. (Seed 8 draws focal lengths 0.5 % and 0.4 % short and
    the principal point 4.2 px off, so each of fx, fy, cx, cy is tested.)"""
    intrinsics = load_scenario(REALISTIC).errors.intrinsics
    cell = SimCell(_scenario({"intrinsics": intrinsics.model_dump()}), np.random.default_rng(8))
    true_k, reported = cell.true.intrinsics, cell.intrinsics
    shift = np.hypot(true_k.cx - reported.cx, true_k.cy - reported.cy)
    assert shift > 2.0 and abs(true_k.cx - reported.cx) > 0.5 and abs(true_k.cy - reported.cy) > 0.5
    assert abs(true_k.fx / reported.fx - 1) > 0.002 and abs(true_k.fy / reported.fy - 1) > 0.002
    _fill_markers(cell)
    waypoints = scenario_waypoints(cell.scenario)
    to_true, to_reported, _ = _corner_errors(cell, [waypoints[i] for i in ROLLED_VIEWS])
    cell.close()
    print(
        f"principal point moved {shift:.2f} px, focal x{true_k.fx / reported.fx:.4f} "
        f"y{true_k.fy / reported.fy:.4f}: {len(to_true)} corners, true K {_rms(to_true):.3f} px RMS "
        f"({to_true.max():.3f} max), reported K {_rms(to_reported):.3f} px RMS ({to_reported.max():.3f} max)"
    )
    assert len(to_true) == 8 * 4 * len(ROLLED_VIEWS)
    assert _rms(to_true) < 0.05 and to_true.max() < 0.1
    assert _rms(to_reported) > 0.5


def _corner_views(cell: SimCell, distance_m: float = 0.5, roll_deg: float = 6.0) -> list[Waypoint]:
    """Views of the board from distance_m, rolled (the roll sign that brings a marker corner
    closest to the image corner), each turned about the optical centre so that the markers
    fill one image corner after another (20 px from its edges, pinhole), and one centred view.
    (Moving the camera sideways instead takes the wrist out of the UR5's reach.)"""
    k = cell.intrinsics
    corners = cell.board.all_corners().reshape(-1, 3)
    views = []
    for i, (su, sv, roll) in enumerate([(-1, -1, -1), (1, -1, 1), (1, 1, -1), (-1, 1, 1), (0, 0, 1)]):
        T_board_cam = look_at_board(0.0, 0.0, roll * roll_deg, distance_m)
        side = np.array([su, sv])
        for _ in range(4):  # the turn changes the perspective a little: iterate
            uv = _project((corners - T_board_cam[:3, 3]) @ T_board_cam[:3, :3], k.K, k.dist)
            lo, hi = uv.min(axis=0), uv.max(axis=0)
            far = [k.width - 21.0, k.height - 21.0]
            shift_px = np.where(side < 0, 20.0 - lo, np.where(side > 0, far - hi, 0.0))
            # Aim the optical axis at the pixel K[:2, 2] - shift: the image moves by +shift.
            z = np.linalg.solve(k.K, [*(k.K[:2, 2] - shift_px), 1.0])
            z /= np.linalg.norm(z)
            x = np.array([1.0, 0.0, 0.0]) - z[0] * z
            x /= np.linalg.norm(x)
            T_board_cam = T_board_cam @ make_transform(np.column_stack([x, np.cross(z, x), z]), np.zeros(3))
        T_base_flange = cell.cell.T_base_board @ T_board_cam @ invert(cell.cell.T_flange_cam)
        views.append(Waypoint(i, f"corner {su:+d} {sv:+d}", T_base_flange=T_base_flange))
    return views


def test_image_is_formed_through_the_true_lens_to_the_image_corners() -> None:
    """With distortion, rendered corners over the whole image, up to its corners, sit where
    cv2.projectPoints(true K, true coefficients) puts them (< 0.15 px)."""
    scenario = _scenario({"lens": {"enabled": True, "true_coefficients": list(LENS)}})
    cell = SimCell(scenario, np.random.default_rng(SEED))
    assert cell.true.intrinsics.dist == LENS and not any(cell.intrinsics.dist)
    _fill_markers(cell)
    to_true, to_pinhole, xy = _corner_errors(cell, _corner_views(cell))
    cell.close()
    k = cell.true.intrinsics
    radius = np.linalg.norm(xy, axis=1)
    image_corner = np.hypot(k.cx / k.fx, k.cy / k.fy)
    print(
        f"{len(to_true)} corners up to r = {radius.max():.3f} (image corner {image_corner:.3f}): true lens "
        f"{_rms(to_true):.3f} px RMS ({to_true.max():.3f} max), pinhole {_rms(to_pinhole):.3f} px RMS "
        f"({to_pinhole.max():.3f} max)"
    )
    # Corners near all four image corners (beyond 85% of the corner radius in each quadrant).
    for su in (-1, 1):
        for sv in (-1, 1):
            quadrant = (np.sign(xy[:, 0]) == su) & (np.sign(xy[:, 1]) == sv)
            assert radius[quadrant].max() > 0.85 * image_corner, (su, sv, radius[quadrant].max())
    assert _rms(to_true) < 0.05 and to_true.max() < 0.15
    assert to_pinhole.max() > 1.5


# --- 4. the board ----------------------------------------------------------------------------

BOARD_ERRORS = {"enabled": True, "scale_error": [0.01, 0.005], "bend_m": [0.002, 0.0]}


def test_printed_board_corners_follow_the_documented_print() -> None:
    """PrintedBoard.true_corners is the definition with each marker moved (by about
    marker_placement_sigma_m, its size kept), scaled about the centre and bent as BoardErrors
    documents: z = bx (1 - u^2) + by (1 - v^2), u = 2 x / width across the scaled sheet."""
    sigma = 2e-4
    cell = SimCell(
        _scenario({"board": {**BOARD_ERRORS, "marker_placement_sigma_m": sigma}}),
        np.random.default_rng(SEED),
    )
    cell.close()
    nominal, printed = cell.board, cell.true.board
    moved = np.array(
        [
            np.subtract(printed.printed.marker_centers_m[i], nominal.marker_centers_m[i])
            for i in nominal.marker_ids
        ]
    )
    assert (
        np.all(moved != 0.0) and np.all(np.abs(moved) < 5 * sigma) and 0.3 * sigma < _rms(moved) < 3 * sigma
    )
    xy = (nominal.all_corners()[:, :, :2] + moved[:, None, :]) * [1.01, 1.005]
    u = 2 * xy[..., 0] / (nominal.size_m[0] * 1.01)
    expected = np.concatenate([xy, (0.002 * (1 - u**2))[..., None]], axis=2)
    np.testing.assert_allclose(printed.true_corners(), expected, rtol=0, atol=1e-12)


def test_detected_corners_fit_the_printed_board_not_the_nominal_one() -> None:
    """On the rendered print (scaled, bent, markers moved) the detector's corners fit the TRUE
    board at the true pose to < 0.1 px RMS; the nominal board misses them by several times
    that, at the true pose and even at its own best-fitting pose."""
    scenario = _scenario({"board": {**BOARD_ERRORS, "marker_placement_sigma_m": 2e-4}})
    cell = SimCell(scenario, np.random.default_rng(SEED))
    k = cell.true.intrinsics
    detector = QRDetector(cell.board)
    ids = cell.board.marker_ids
    true_corners, nominal_corners = cell.true.board.true_corners(), cell.board.all_corners()
    residuals = {"true": [], "nominal": [], "true, best pose": [], "nominal, best pose": []}
    views = scenario_waypoints(scenario)
    for i in (0, 5) + ROLLED_VIEWS[::2]:
        cell.move_to(views[i])
        frame, _ = cell.capture()
        markers = detector.detect(frame.rgb).markers
        assert sorted(m.marker_id for m in markers) == ids, f"view {i}: not every marker detected"
        measured = np.concatenate([m.corners_px for m in markers])
        order = [ids.index(m.marker_id) for m in markers]
        T_cam_board = invert(cell.T_base_cam()) @ cell.cell.T_base_board
        for name, board in (("true", true_corners), ("nominal", nominal_corners)):
            p_board = board[order].reshape(-1, 3)
            p_cam = p_board @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            residuals[name].append(np.linalg.norm(_project(p_cam, k.K, k.dist) - measured, axis=1))
            _, rvec, tvec = cv2.solvePnP(p_board, measured, k.K, np.asarray(k.dist))
            fitted, _ = cv2.projectPoints(p_board, rvec, tvec, k.K, np.asarray(k.dist))
            residuals[f"{name}, best pose"].append(np.linalg.norm(fitted.reshape(-1, 2) - measured, axis=1))
    cell.close()
    rms = {name: _rms(np.concatenate(r)) for name, r in residuals.items()}
    print(", ".join(f"{name} {value:.3f} px RMS" for name, value in rms.items()))
    assert rms["true"] < 0.1 and np.concatenate(residuals["true"]).max() < 0.3
    assert rms["nominal"] > 1.0 and rms["nominal"] > 10 * rms["true"]
    assert rms["nominal, best pose"] > 4 * rms["true, best pose"]
