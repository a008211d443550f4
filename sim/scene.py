"""Build the MuJoCo cell: models/cell.xml, the arm, the camera on the flange and the board.

The arm's MJCF is attached at the cell's ``arm_mount`` site. The camera body
and the board are added here because their poses come from the scenario.

MuJoCo camera <-> OpenCV K (checked in tests/test_render.py):
MuJoCo's camera looks along its -z with +y up, so
``T_flange_mjcam = T_flange_cam @ diag(1, -1, -1, 1)``. Its intrinsics are set
from K with ``resolution = (W, H)``, ``focalpixel = (fx, fy)`` and
``principalpixel = ((W - 1) / 2 - cx, (H - 1) / 2 - cy)``: MuJoCo measures the
principal point as an offset from the image centre, with the sign that moves
the image content, and OpenCV's pixel origin is the centre of the first pixel.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass

import mujoco
import numpy as np

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import ROBOTS, URKinematics
from hec.estimator.geometry.lie import so3_exp
from hec.estimator.geometry.transforms import invert, make_transform, xyz_quat_from_transform
from hec.estimator.io.board_file import board_to_dict
from hec.estimator.targets.target import Target
from hec.sim.model_errors import PrintedBoard
from hec.sim.scenario import ScenarioError

CAMERA_NAME = "hec_camera"
DEPTH_SENSOR_NAME = "hec_depth_sensor"
BOARD_GEOM = "board_sheet"
ARM_PREFIX = "arm/"
MIN_TABLE_HEIGHT_M = 0.05  # a board lying face up sits on a table: its top this high at least
# The arm's link bodies in DH order: link i turns about its z with joint i, link i + 1 (the
# flange after the last) sits at its DH offset transz(d_i) transx(a_i) rotx(alpha_i).
ARM_LINKS = (
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
    "flange",
)
# Sheet mesh resolution when the board is bent (vertices along x and y).
BENT_SHEET_GRID = (41, 23)
# Rotation taking OpenCV's camera axes to MuJoCo's (x right, y up, looking along -z).
R_CAM_MJCAM = np.diag([1.0, -1.0, -1.0])
BOARD_TEXTURE_PX_PER_M = 4000.0
# Sheet textures kept (_sheet_texture), and the kept ones by board class and definition (JSON).
SHEET_TEXTURES_KEPT = 4
_SHEET_TEXTURES: dict[tuple[type, str], np.ndarray] = {}
_SHEET_TEXTURES_LOCK = threading.Lock()
# Printed reflectance of the board's paper and ink (the texture's white and black).
PAPER_REFLECTANCE = 0.85
INK_REFLECTANCE = 0.06
# Robot and camera geoms collide with the cell (contype 1), not with each other.
_ROBOT_CONTYPE = 1


@dataclass(frozen=True)
class DepthSensor:
    """A depth imager beside the colour camera: its pose T_cam_depth (4, 4) in the colour
    camera's optical frame, metres, and its own pinhole intrinsics."""

    T_cam_depth: np.ndarray
    intrinsics: CameraIntrinsics


@dataclass(frozen=True)
class EyeToHandMounts:
    """The eye-to-hand cell's frames: the camera on its stand T_base_cam (4, 4) and the board on
    the flange T_flange_board (4, 4), metres."""

    T_base_cam: np.ndarray
    T_flange_board: np.ndarray


@dataclass
class CellModel:
    """A compiled cell and the frames it was built with (all SI units). kinematics: the robot's
    nominal model (what its controller computes with); true_kinematics: what the rendered arm
    does (the same unless the scenario has arm errors; MuJoCo's joint i is at q[i] +
    true_kinematics.theta_offset[i])."""

    model: mujoco.MjModel
    kinematics: URKinematics
    T_world_base: np.ndarray
    T_base_board: np.ndarray
    T_flange_cam: np.ndarray
    intrinsics: CameraIntrinsics
    board: Target
    true_kinematics: URKinematics
    T_base_cam: np.ndarray | None = None
    T_flange_board: np.ndarray | None = None

    @property
    def eye_to_hand(self) -> bool:
        """Whether the camera stands fixed at T_base_cam and the board rides on the flange at
        T_flange_board (T_flange_cam and T_base_board then unused)."""
        return self.T_base_cam is not None

    def joint_qpos_addresses(self) -> np.ndarray:
        """Indices into qpos of the six arm joints, in DH order."""
        names = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
        return np.array([self.model.joint(ARM_PREFIX + n).qposadr[0] for n in names])

    def board_geom_id(self) -> int:
        return self.model.geom(BOARD_GEOM).id


def _set_pose(element: mujoco.MjsBody | mujoco.MjsCamera, T: np.ndarray) -> None:
    t, q = xyz_quat_from_transform(T)
    element.pos = t
    element.quat = q


def build_cell(
    robot: str,
    T_flange_cam: np.ndarray,
    intrinsics: CameraIntrinsics,
    board: Target,
    T_base_board: np.ndarray,
    offscreen_size: tuple[int, int] = (1280, 960),
    depth_sensor: DepthSensor | None = None,
    kinematics: URKinematics | None = None,
    printed_board: PrintedBoard | None = None,
    eye_to_hand: EyeToHandMounts | None = None,
) -> CellModel:
    """Compile the cell for one scenario.

    robot: 'ur5' or 'ur5e'. T_flange_cam: (4, 4) camera mount (OpenCV optical
    frame). T_base_board: (4, 4) pose of the board frame in the base frame.
    offscreen_size: largest (width, height) rendered, at least the camera's.
    depth_sensor: an optional second camera, rigidly beside the colour camera,
    named DEPTH_SENSOR_NAME (an RGB-D camera whose depth imager is not the colour one).
    kinematics: the arm's true kinematics when they differ from the robot's nominal DH model
    (link bodies placed by its DH table; its joint offsets are applied to qpos, see
    CellModel.kinematics). printed_board: the board as printed, when not exactly as defined.
    eye_to_hand: the camera on a stand and the board on the flange instead (T_flange_cam and
    T_base_board are then not used).
    """
    if robot not in ROBOTS:
        raise ValueError(f"unknown robot {robot!r}; choose one of {sorted(ROBOTS)}")
    root = models_dir()
    spec = mujoco.MjSpec.from_file(str(root / "cell.xml"))
    arm = mujoco.MjSpec.from_file(str(root / f"{robot}.xml"))
    if kinematics is not None and kinematics != ROBOTS[robot]:
        _place_links(arm, kinematics)
    spec.attach(arm, site=spec.site("arm_mount"), prefix=ARM_PREFIX)
    views = [intrinsics] + ([depth_sensor.intrinsics] if depth_sensor is not None else [])
    spec.visual.global_.offwidth = max(offscreen_size[0], *(k.width for k in views))
    spec.visual.global_.offheight = max(offscreen_size[1], *(k.height for k in views))

    T_world_base = _site_pose(spec, "arm_mount")
    flange = spec.body(ARM_PREFIX + "flange")
    printed = printed_board or PrintedBoard(board)
    if eye_to_hand is None:
        _add_camera(flange, T_flange_cam, intrinsics)
        _add_board(spec, printed, spec.worldbody, T_world_base @ T_base_board)
    else:
        _add_stand_camera(spec, T_world_base @ eye_to_hand.T_base_cam, intrinsics)
        _add_board(spec, printed, flange, eye_to_hand.T_flange_board)
    if depth_sensor is not None:
        _add_view(
            spec.body("camera_body"), DEPTH_SENSOR_NAME, depth_sensor.T_cam_depth, depth_sensor.intrinsics
        )
    model = spec.compile()
    true_kinematics = kinematics or ROBOTS[robot]
    mounts = {} if eye_to_hand is None else vars(eye_to_hand)
    return CellModel(
        model,
        ROBOTS[robot],
        T_world_base,
        T_base_board,
        T_flange_cam,
        intrinsics,
        board,
        true_kinematics,
        **mounts,
    )


def _place_links(arm: mujoco.MjSpec, kinematics: URKinematics) -> None:
    """Put each link body of the arm's MJCF at the DH offset of the table (d, a, alpha)."""
    for i, child in enumerate(ARM_LINKS[1:]):
        body = arm.body(child)
        step = make_transform(so3_exp(np.array([kinematics.alpha[i], 0.0, 0.0])), np.zeros(3))
        step[:3, 3] = (kinematics.a[i], 0.0, kinematics.d[i])
        _set_pose(body, step)


def _site_pose(spec: mujoco.MjSpec, name: str) -> np.ndarray:
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    site = data.site(name)
    return make_transform(site.xmat.reshape(3, 3), site.xpos)


_CAMERA_GREY = [0.12, 0.12, 0.13, 1.0]


def _add_housing(parent: mujoco.MjsBody, T_parent_cam: np.ndarray, collision: dict) -> mujoco.MjsBody:
    """The camera body at T_parent_cam with a D435-sized housing (90 x 25 x 25 mm, its front face
    1.5 mm behind the optical centre); collision: its contype and conaffinity."""
    body = parent.add_body(name="camera_body")
    _set_pose(body, T_parent_cam)
    body.add_geom(
        name="camera_housing",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.045, 0.0125, 0.0125],
        pos=[0.0, 0.0, -0.014],
        rgba=_CAMERA_GREY,
        **collision,
    )
    return body


def _add_stand_camera(spec: mujoco.MjSpec, T_world_cam: np.ndarray, k: CameraIntrinsics) -> None:
    """The camera fixed in the cell (eye-to-hand) at T_world_cam, on a post down to the floor
    (world z up); the arm collides with both."""
    _add_view(
        _add_housing(spec.worldbody, T_world_cam, {"contype": 0, "conaffinity": 1}), CAMERA_NAME, np.eye(4), k
    )
    x, y, z = T_world_cam[:3, 3]
    height = z - 0.03
    if height > 0.0:
        spec.worldbody.add_geom(
            name="camera_stand",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[0.015, height / 2],
            pos=[x, y, height / 2],
            rgba=_CAMERA_GREY,
            contype=0,
            conaffinity=1,
        )


def _add_camera(flange: mujoco.MjsBody, T_flange_cam: np.ndarray, k: CameraIntrinsics) -> None:
    """A D435-sized housing behind the optical centre, and the camera itself."""
    body = _add_housing(flange, T_flange_cam, {"contype": _ROBOT_CONTYPE, "conaffinity": 0})
    grey = _CAMERA_GREY
    # Bracket from the housing back to the flange plane (visual only).
    depth = float(T_flange_cam[2, 3]) - 0.0265
    if depth > 1e-3:
        T_cam_flange = invert(T_flange_cam)
        body.add_geom(
            name="camera_bracket",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[0.02, depth / 2],
            pos=T_cam_flange[:3, 3] + T_cam_flange[:3, 2] * depth / 2,
            quat=xyz_quat_from_transform(T_cam_flange)[1],
            rgba=grey,
            contype=0,
            conaffinity=0,
        )
    _add_view(body, CAMERA_NAME, np.eye(4), k)


def _add_view(body: mujoco.MjsBody, name: str, T_body_cam: np.ndarray, k: CameraIntrinsics) -> None:
    """A MuJoCo camera at T_body_cam (OpenCV optical frame) with the pinhole intrinsics k."""
    camera = body.add_camera(name=name)
    _set_pose(camera, T_body_cam @ make_transform(R_CAM_MJCAM, np.zeros(3)))
    camera.resolution = [k.width, k.height]
    camera.focal_pixel = [k.fx, k.fy]
    camera.principal_pixel = [(k.width - 1) / 2 - k.cx, (k.height - 1) / 2 - k.cy]
    camera.sensor_size = [k.width * 3e-6, k.height * 3e-6]


def _sheet_texture(board: Target) -> np.ndarray:
    """(H, W, 3) uint8 texture of the printed sheet at BOARD_TEXTURE_PX_PER_M, read-only. Drawing it
    takes ~0.14 s (a sweep trial builds a scene per trial), so the last few boards' are kept, keyed
    by the board's class and definition (its file's content, board_to_dict): a board printed with
    misplaced markers is another."""
    key = (type(board), json.dumps(board_to_dict(board), sort_keys=True))
    with _SHEET_TEXTURES_LOCK:  # Dask may run trials on threads
        if key not in _SHEET_TEXTURES:
            # Printed reflectance: paper about 0.85, ink about 0.06, so lit white and black stay
            # inside 8 bits and the camera's noise is not clipped away.
            coverage = board.image(BOARD_TEXTURE_PX_PER_M).astype(np.float64) / 255.0
            image = np.round(255.0 * (INK_REFLECTANCE + (PAPER_REFLECTANCE - INK_REFLECTANCE) * coverage))
            rgb = np.repeat(image.astype(np.uint8)[:, :, None], 3, axis=2)
            rgb.flags.writeable = False
            if len(_SHEET_TEXTURES) >= SHEET_TEXTURES_KEPT:
                del _SHEET_TEXTURES[next(iter(_SHEET_TEXTURES))]  # the oldest
            _SHEET_TEXTURES[key] = rgb
        return _SHEET_TEXTURES[key]


def _add_board(
    spec: mujoco.MjSpec, printed: PrintedBoard, parent: mujoco.MjsBody, T_parent_board: np.ndarray
) -> None:
    """The printed sheet as a textured mesh at z = 0 of the board frame (a quad, or a grid when
    it is scaled or bent), on a backing plate, at T_parent_board in parent: the world (the board
    fixed in the cell; lying face up it gets a table) or the flange (eye-to-hand; its plate then
    collides with the cell as the camera on the flange does)."""
    board = printed.printed
    rgb = _sheet_texture(board)
    spec.add_texture(
        name="board",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        width=rgb.shape[1],
        height=rgb.shape[0],
        nchannel=3,
    ).data = rgb.tobytes()
    spec.add_material(name="board", textures=["", "board"], specular=0.0, shininess=0.0)
    w, h = board.size_m
    mesh = spec.add_mesh(name="board_sheet")
    if printed.is_exact:
        # Corners: top-left, bottom-left, bottom-right, top-right (board frame, x right, y up).
        mesh.uservert = [-w / 2, h / 2, 0, -w / 2, -h / 2, 0, w / 2, -h / 2, 0, w / 2, h / 2, 0]
        # Texture row 0 (the sheet's top edge) sits at v = 0.
        mesh.usertexcoord = [0, 0, 0, 1, 1, 1, 1, 0]
        mesh.userface = [1, 2, 3, 1, 3, 0]
    else:
        mesh.uservert, mesh.usertexcoord, mesh.userface = _sheet_grid(printed)
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
    body = parent.add_body(name="board")
    _set_pose(body, T_parent_board)
    on_flange = parent is not spec.worldbody
    body.add_geom(
        name=BOARD_GEOM,
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname="board_sheet",
        material="board",
        contype=0,
        conaffinity=0,
    )
    # Backing plate 2 mm thick, 1 mm below the sheet's lowest point: no face is coplanar with
    # the print.
    lowest = min(0.0, printed.bend_m[0]) + min(0.0, printed.bend_m[1])
    sx, sy = printed.scale
    body.add_geom(
        name="board_plate",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[w * sx / 2, h * sy / 2, 0.001],
        pos=[0.0, 0.0, lowest - 0.002],
        rgba=[0.9, 0.9, 0.88, 1.0],
        contype=_ROBOT_CONTYPE if on_flange else 0,
        conaffinity=0 if on_flange else 1,
    )
    if not on_flange and T_parent_board[2, 2] > np.cos(np.radians(5.0)):
        _add_table(spec, T_parent_board[:3, 3] - [0.0, 0.0, 0.003])


def _sheet_grid(printed: PrintedBoard) -> tuple[list[float], list[float], list[int]]:
    """Vertices, texture coordinates and faces of the printed sheet as a BENT_SHEET_GRID mesh,
    each vertex where PrintedBoard.to_board_frame puts the printed point."""
    w, h = printed.printed.size_m
    nx, ny = BENT_SHEET_GRID
    x, y = np.meshgrid(np.linspace(-w / 2, w / 2, nx), np.linspace(h / 2, -h / 2, ny))
    flat = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    vertices = printed.to_board_frame(flat)
    texcoords = np.column_stack([(flat[:, 0] + w / 2) / w, (h / 2 - flat[:, 1]) / h])
    faces = []
    for r in range(ny - 1):  # row r is above row r + 1
        for c in range(nx - 1):
            tl, tr = r * nx + c, r * nx + c + 1
            bl, br = tl + nx, tr + nx
            faces += [bl, br, tr, bl, tr, tl]  # counter-clockwise seen from +z, as the quad's
    return vertices.ravel().tolist(), texcoords.ravel().tolist(), faces


def _add_table(spec: mujoco.MjSpec, top_centre_world: np.ndarray) -> None:
    """A table whose top face is at top_centre_world (under a board lying face up)."""
    x, y, z = top_centre_world
    if z < MIN_TABLE_HEIGHT_M:
        raise ScenarioError(
            f"key 'board.translation_m': it puts the board {z:.3f} m above the floor, too low for the table "
            f"under it (at least {MIN_TABLE_HEIGHT_M:g} m; the base frame's y points up)"
        )
    table = {"contype": 0, "conaffinity": 1, "material": "table"}
    spec.worldbody.add_geom(
        name="table_top",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.5, 0.32, 0.02],
        pos=[x, y, z - 0.02],
        **table,
    )
    spec.worldbody.add_geom(
        name="table_leg",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.04, 0.04, (z - 0.04) / 2],
        pos=[x, y, (z - 0.04) / 2],
        **table,
    )
