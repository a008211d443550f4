"""Scenario files (TOML): robot, camera intrinsics and mount, board pose, noise, trajectory.

Every key is optional; what is left out takes the default shown in
models/scenarios/default.toml. Lengths are metres (keys end in ``_m``),
angles degrees (keys end in ``_deg``). Rotations are roll-pitch-yaw about the
fixed x, y, z axes: R = Rz(yaw) @ Ry(pitch) @ Rx(roll).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator

from hec.estimator.common.models import models_dir
from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.transforms import transform_from_xyz_rpy
from hec.estimator.io.board_file import find_board
from hec.estimator.io.tomlfile import Section, read_toml, validation_problems
from hec.estimator.targets.target import Target

Vector3 = tuple[float, float, float]


class ScenarioError(ValueError):
    """A scenario file cannot be read or has a bad key."""


class CameraSettings(Section):
    """Colour camera. Without fx/fy/cx/cy: square pixels, centred principal point, fovy_deg."""

    width: int = Field(640, gt=0)
    height: int = Field(480, gt=0)
    # D435 colour sensor: 69 x 42 degrees at 16:9; 640x480 keeps the vertical field.
    fovy_deg: float = Field(42.5, gt=0, lt=180)
    fx: float | None = Field(None, gt=0)
    fy: float | None = Field(None, gt=0)
    cx: float | None = None
    cy: float | None = None

    @model_validator(mode="after")
    def _all_or_none(self) -> CameraSettings:
        given = [v is not None for v in (self.fx, self.fy, self.cx, self.cy)]
        if any(given) and not all(given):
            raise ValueError("give all of fx, fy, cx, cy (pixels) or none of them")
        return self

    def intrinsics(self) -> CameraIntrinsics:
        if self.fx is None:
            return CameraIntrinsics.from_fovy(self.width, self.height, np.radians(self.fovy_deg))
        return CameraIntrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy)


class PoseSettings(Section):
    translation_m: Vector3 = (0.0, 0.0, 0.0)
    rotation_rpy_deg: Vector3 = (0.0, 0.0, 0.0)

    def transform(self) -> np.ndarray:
        return transform_from_xyz_rpy(np.array(self.translation_m), np.radians(self.rotation_rpy_deg))


class MountSettings(PoseSettings):
    """T_flange_cam. Default: the paper's mount, 6 mm along +Y and 40 mm along +Z
    of the flange, looking along the tool axis."""

    translation_m: Vector3 = (0.0, 0.006, 0.040)


class StandSettings(PoseSettings):
    """T_base_cam of the eye-to-hand set-up: the camera optical frame on its stand, in the base
    frame; the unknown to calibrate there. Default: 1.25 m above the floor and 0.93 m out from the
    wall, looking back toward the wall and 30 degrees down at where the arm presents the board."""

    translation_m: Vector3 = (0.15, -0.2, 0.933)
    rotation_rpy_deg: Vector3 = (150.0, 0.0, 0.0)


class BoardMountSettings(PoseSettings):
    """T_flange_board of the eye-to-hand set-up: the board frame in the flange (tool0) frame, its
    printed face out along the tool axis. Default: 30 mm out from the flange, a little off centre."""

    translation_m: Vector3 = (0.005, 0.01, 0.03)


class BoardSettings(PoseSettings):
    """The board definition and T_base_board. Default: lying in the base X-Z
    plane (face up, +Y of the base) 0.7 m below the base, 0.45 m out from the
    wall and 0.15 m to the right, so that no view puts the wrist near the base
    axis, where a UR arm cannot reach."""

    definition: str = "hec_8qr"
    translation_m: Vector3 = (0.15, -0.7, 0.45)
    rotation_rpy_deg: Vector3 = (-90.0, 0.0, 0.0)


class DepthNoise(Section):
    """Stereo depth noise, sigma(z) = z^2 * subpixel / (focal_px * baseline_m) (D435-like)."""

    enabled: bool = True
    subpixel: float = Field(0.08, ge=0)
    baseline_m: float = Field(0.050, gt=0)
    # Focal length of the D435 depth imager at 848x480 (about 87 degrees horizontal).
    focal_px: float = Field(425.0, gt=0)


class InvalidDepth(Section):
    """Zeros where the surface is seen at a grazing angle, and at random pixels."""

    enabled: bool = True
    grazing_angle_deg: float = Field(75.0, gt=0, le=90)
    dropout_fraction: float = Field(0.002, ge=0, lt=1)


class DepthQuantisation(Section):
    """Round depth to multiples of depth_scale_m, as a uint16 depth image stores it."""

    enabled: bool = True
    depth_scale_m: float = Field(0.001, gt=0)


class DepthBias(Section):
    """Systematic depth error: z_measured = scale * z + offset_m."""

    enabled: bool = False
    scale: float = Field(1.0, gt=0)
    offset_m: float = 0.0


class RGBNoise(Section):
    """Gaussian blur, then additive Gaussian noise (8-bit grey levels)."""

    enabled: bool = True
    sigma: float = Field(2.0, ge=0)
    blur_sigma_px: float = Field(0.5, ge=0)


class RobotPoseNoise(Section):
    """Noise on the reported flange pose (the true pose is kept apart).

    Reported T_base_flange: translation + N(0, translation_sigma_m^2) per base
    axis; rotation R @ Exp(N(0, rotation_sigma_deg^2) per flange axis).
    UR5 rated repeatability is +-0.1 mm.
    """

    enabled: bool = True
    translation_sigma_m: float = Field(1e-4, ge=0)
    rotation_sigma_deg: float = Field(0.01, ge=0)


class NoiseSettings(Section):
    depth: DepthNoise = DepthNoise()
    invalid_depth: InvalidDepth = InvalidDepth()
    depth_quantisation: DepthQuantisation = DepthQuantisation()
    depth_bias: DepthBias = DepthBias()
    rgb: RGBNoise = RGBNoise()
    robot_pose: RobotPoseNoise = RobotPoseNoise()

    def all_off(self) -> NoiseSettings:
        """The same settings with every model switched off."""
        sections = {name: getattr(self, name) for name in NoiseSettings.model_fields}
        return NoiseSettings(
            **{name: s.model_copy(update={"enabled": False}) for name, s in sections.items()}
        )


Coefficients = tuple[float, float, float, float, float]


class ArmErrors(Section):
    """The arm moves with true kinematics that differ from the nominal DH model it reports with:
    per-joint zero offsets, link lengths (every DH a and d) and twists (alpha), each drawn once
    from N(0, sigma^2). The reported flange pose is the nominal forward kinematics of the
    measured joints, which carry encoder noise N(0, encoder_sigma_deg^2) per frame."""

    enabled: bool = False
    joint_offset_sigma_deg: float = Field(0.08, ge=0)
    link_length_sigma_m: float = Field(3e-4, ge=0)
    twist_sigma_deg: float = Field(0.08, ge=0)
    encoder_sigma_deg: float = Field(6e-4, ge=0)


class IntrinsicsErrors(Section):
    """The camera renders with a true K that differs from the K reported in the dataset (the
    [camera] section): focal lengths scaled by 1 + N(0, focal_sigma_fraction^2) each, the
    principal point moved by N(0, principal_point_sigma_px^2) per axis, drawn once."""

    enabled: bool = False
    focal_sigma_fraction: float = Field(0.003, ge=0, lt=0.2)
    principal_point_sigma_px: float = Field(3.0, ge=0)


class LensErrors(Section):
    """The image carries Brown-Conrady distortion (OpenCV's k1, k2, p1, p2, k3) with the true
    coefficients; the dataset reports the "factory" ones."""

    enabled: bool = False
    true_coefficients: Coefficients = (0.13, -0.30, 0.0, 0.0, 0.0)
    reported_coefficients: Coefficients = (0.0, 0.0, 0.0, 0.0, 0.0)


class DepthErrors(Section):
    """Depth errors beyond white noise and bias (noise.depth, noise.depth_bias): the noise is
    spatially correlated over correlation_px (the 1/e length of its autocorrelation; 1 =
    independent pixels), the depth imager's true pose relative to the colour camera is off by
    N(0, sigma^2) per axis (depth misregistered to colour), pixels at depth edges take mixed
    depths (flying pixels) and blobs of pixels have no depth (holes)."""

    enabled: bool = False
    correlation_px: float = Field(2.5, ge=1.0, le=50.0)
    registration_translation_sigma_m: float = Field(5e-4, ge=0)
    registration_rotation_sigma_deg: float = Field(0.1, ge=0)
    flying_pixel_probability: float = Field(0.5, ge=0, le=1)
    flying_pixel_width_px: int = Field(1, ge=1, le=5)
    flying_pixel_edge_m: float = Field(0.02, gt=0)
    holes_per_megapixel: float = Field(30.0, ge=0)
    hole_radius_px: float = Field(3.0, gt=0)


class BoardErrors(Section):
    """The printed board differs from its definition: scaled by 1 + scale_error along the
    board's x and y, bent (the sheet's centre bend_m above its edges along x and y, z = bx (1 -
    u^2) + by (1 - v^2) with u, v in [-1, 1] across the sheet) and each marker moved by
    N(0, marker_placement_sigma_m^2) per axis (drawn once)."""

    enabled: bool = False
    scale_error: tuple[float, float] = (0.003, 0.001)
    bend_m: tuple[float, float] = (0.0007, 0.0)
    marker_placement_sigma_m: float = Field(5e-5, ge=0)


class ImageErrors(Section):
    """What a real camera and room add to the colour image: vignetting (corners
    vignetting_corner_falloff darker than the centre), a linear light gradient (one side
    light_gradient brighter than the other, toward light_gradient_direction_deg in the image, 0 =
    right, 90 = down), a specular highlight of a lamp at light_position_board_m (board frame) on
    the glossy print, per-view exposure gain 1 + N(0, exposure_sigma^2), and motion blur of an
    arm that has not fully settled (camera speed N(0, motion_speed_sigma_m_s^2) and rate
    N(0, motion_rate_sigma_deg_s^2) per axis during exposure_time_s)."""

    enabled: bool = False
    vignetting_corner_falloff: float = Field(0.2, ge=0, lt=1)
    light_gradient: float = Field(0.15, ge=0, lt=2)
    light_gradient_direction_deg: float = 30.0
    light_position_board_m: Vector3 = (0.1, 0.3, 1.5)
    highlight_peak_grey: float = Field(60.0, ge=0)
    highlight_radius_px: float = Field(20.0, gt=0)
    exposure_sigma: float = Field(0.03, ge=0, lt=0.5)
    motion_speed_sigma_m_s: float = Field(0.005, ge=0)
    motion_rate_sigma_deg_s: float = Field(0.5, ge=0)
    exposure_time_s: float = Field(0.015, gt=0, lt=1)


class ModelErrors(Section):
    """The ways a real cell differs from the model the estimators assume. All off by default
    (the ideal cell); models/scenarios/realistic.toml switches them on at a real cell's size."""

    arm: ArmErrors = ArmErrors()
    intrinsics: IntrinsicsErrors = IntrinsicsErrors()
    lens: LensErrors = LensErrors()
    depth: DepthErrors = DepthErrors()
    board: BoardErrors = BoardErrors()
    image: ImageErrors = ImageErrors()

    def any_enabled(self) -> bool:
        return any(getattr(self, name).enabled for name in ModelErrors.model_fields)


class TrajectorySettings(Section):
    """Where the arm goes.

    kind 'rotation-rich' (default): views of the board centre tilted 15-35
    degrees about two board axes and rolled about the optical axis, alternating
    between 0.9 and 1.25 times distance_m (hec.estimator.geometry.waypoints).
    kind 'paper': the paper's fixed-orientation translations of 30-40 mm in x, y, z.
    kind 'file': waypoints read from ``file`` (CSV, see the README).
    """

    kind: Literal["rotation-rich", "paper", "file"] = "rotation-rich"
    file: str | None = None
    distance_m: float = Field(0.45, gt=0.1, lt=2.0)
    margin_px: float = Field(12.0, ge=0)
    max_view_angle_deg: float = Field(60.0, gt=0, lt=90)

    @model_validator(mode="after")
    def _file_given(self) -> TrajectorySettings:
        if (self.kind == "file") != (self.file is not None):
            raise ValueError("'file' is needed exactly when kind = 'file'")
        return self


# The keys only the eye-to-hand set-up reads (Scenario.to_dict leaves them out of an eye-in-hand one).
EYE_TO_HAND_KEYS = ("setup", "stand", "board_mount")


class Scenario(Section):
    """setup: "eye-in-hand" (the camera on the flange at mount, the board fixed at board's pose) or
    "eye-to-hand" (the camera fixed at stand, the board on the flange at board_mount; board's
    definition is still the board's, its pose there is not used)."""

    robot: Literal["ur5", "ur5e"] = "ur5"
    seed: int = Field(0, ge=0)
    setup: Literal["eye-in-hand", "eye-to-hand"] = EYE_IN_HAND
    camera: CameraSettings = CameraSettings()
    mount: MountSettings = MountSettings()
    board: BoardSettings = BoardSettings()
    stand: StandSettings = StandSettings()
    board_mount: BoardMountSettings = BoardMountSettings()
    noise: NoiseSettings = NoiseSettings()
    trajectory: TrajectorySettings = TrajectorySettings()
    errors: ModelErrors = ModelErrors()
    # Folder that relative paths in the file (board definition, waypoints) are read from.
    base_dir: str = Field(".", exclude=True)

    def board_definition(self) -> Target:
        """A board name in models/boards/, or a JSON path relative to the scenario."""
        return find_board(self.board.definition, Path(self.base_dir))

    def waypoint_file(self) -> Path | None:
        return None if self.trajectory.file is None else Path(self.base_dir) / self.trajectory.file

    def to_dict(self) -> dict:
        """The settings as plain JSON values. Without model errors (the ideal cell) the 'errors'
        table is left out, so datasets of the ideal cell read as they did before it existed; so are the
        eye-to-hand keys (EYE_TO_HAND_KEYS) of an eye-in-hand scenario."""
        data = self.model_dump(mode="json")
        if self.errors == ModelErrors():
            del data["errors"]
        if self.setup == EYE_IN_HAND:
            for key in EYE_TO_HAND_KEYS:
                del data[key]
        return data

    @property
    def eye_to_hand(self) -> bool:
        return self.setup == EYE_TO_HAND


def resolve_scenario_path(path: str | Path) -> Path:
    """The scenario file: ``path`` itself, or for a bare name of models/scenarios/ ("realistic") that one."""
    path = Path(path)
    named = models_dir() / "scenarios" / f"{path}.toml"
    if not path.exists() and path.suffix == "" and named.is_file():
        return named
    return path


def load_scenario(path: str | Path | None) -> Scenario:
    """Read and validate a scenario file; a name of models/scenarios/ without .toml ("realistic")
    reads that one; None gives the default scenario. A file with the key based_on (a scenario name
    or file, relative to it) holds only what it changes in that one (tables merged key by key)."""
    if path is None:
        return Scenario()
    path = resolve_scenario_path(path)
    return scenario_from_dict(_scenario_data(path, ()), source=str(path), base_dir=path.parent)


def _scenario_data(path: Path, seen: tuple[Path, ...]) -> dict:
    """A scenario file's keys, merged over those of the scenario it is based_on (seen: the files
    that led here, for a circle)."""
    data = read_toml(path, ScenarioError, "scenario")
    if "base_dir" in data:
        raise ScenarioError(f"{path}: key 'base_dir': unknown key")
    based_on = data.pop("based_on", None)
    if based_on is None:
        return data
    base = Path(based_on) if Path(based_on).is_absolute() else path.parent / based_on
    base = base if base.exists() else resolve_scenario_path(based_on)
    if not base.is_file() or base.resolve() in seen:
        problem = "goes round in a circle" if base.is_file() else "names no scenario file"
        raise ScenarioError(f"{path}: key 'based_on': {based_on!r} {problem}")
    return _merged(_scenario_data(base, (*seen, path.resolve())), data)


def _merged(base: dict, changes: dict) -> dict:
    """base with changes applied: tables merged key by key, everything else replaced."""
    out = dict(base)
    for key, value in changes.items():
        both = isinstance(value, dict) and isinstance(base.get(key), dict)
        out[key] = _merged(base[key], value) if both else value
    return out


def scenario_from_dict(data: dict, source: str = "scenario", base_dir: Path = Path(".")) -> Scenario:
    try:
        return Scenario(**data, base_dir=str(base_dir))
    except ValidationError as exc:
        raise ScenarioError(validation_problems(exc, source)) from None
