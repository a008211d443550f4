"""A calibration in the forms other tools read: a ROS 2 launch file or command line for tf2_ros's
static_transform_publisher, a URDF joint, an easy_handeye2 .calib file, and hec's own YAML / JSON.

What is exported is T_parent_child: the child frame in the parent frame (tf2's frame-id ->
child-frame-id, URDF's parent -> child). With the child the camera's optical frame (a name ending in
'_optical_frame', such as RealSense's camera_color_optical_frame) it is T_flange_cam itself, the
parent being the frame the robot reported (tool0). With the child the camera's root link (such as
RealSense's camera_link, whose driver publishes camera_link -> camera_color_optical_frame), that
driver transform T_link_optical is composed out: T_parent_link = T_flange_cam @ inv(T_link_optical).
Numbers are written with repr (shortest round trip) so a reader gets the transform back to 1e-15,
and only finite ones. Frame names are refused when empty or holding white space or control
characters (no tool's frame has them, and a line break would end a comment), and escaped for the
format they go into (XML attributes, shell words, Python and YAML strings).

An eye-to-hand calibration (the camera fixed in the cell) exports T_base_cam the same way, its
parent the robot's base frame (base_link -> camera), and easy_handeye2's calibration_type is then
eye_on_base.
"""

from __future__ import annotations

import json
import shlex
import unicodedata
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np
import yaml

from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.lie import skew
from hec.estimator.geometry.transforms import (
    invert,
    make_transform,
    rpy_from_transform,
    xyz_quat_from_transform,
)
from hec.estimator.io.calibration_file import CalibrationFile

OPTICAL_SUFFIX = "_optical_frame"
# camera_link (x forward, y left, z up, ROS REP 103) -> an optical frame (x right, y down, z forward).
OPTICAL_ROTATION = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
USE = "T_base_cam = T_base_flange @ T_flange_cam (OpenCV's name: cam2gripper); p_base = T_base_cam @ p_cam"
USE_EYE_TO_HAND = "p_base = T_base_cam @ p_cam (the camera fixed in the cell; OpenCV's name: cam2base)"
# A set-up's default parent frame (the frame its camera is fixed in) and easy_handeye2's name for it.
PARENT_FRAMES = {EYE_IN_HAND: "tool0", EYE_TO_HAND: "base_link"}
EASY_HANDEYE2_TYPES = {EYE_IN_HAND: "eye_in_hand", EYE_TO_HAND: "eye_on_base"}
COVARIANCE_CONVENTION = (
    "6x6 covariance of the perturbation (dt, dtheta) of the transform: R = R_est Exp(dtheta), "
    "t = t_est + dt; "
    "dt_x, dt_y, dt_z in metres along the parent frame's axes, then dtheta_x, dtheta_y, dtheta_z in "
    "radians about the child frame's axes"
)
RPY_CONVENTION = "fixed axes x, y, z of the parent (URDF): R = Rz(yaw) Ry(pitch) Rx(roll), radians"


# The frames realsense-ros publishes as children, by suffix after its camera name (NAME, default
# 'camera'), with their parents' suffixes: every one hangs under NAME_link, which itself has no parent.
REALSENSE_ROS_PARENTS = {
    "_color_frame": "_link",
    "_color_optical_frame": "_color_frame",
    "_depth_frame": "_link",
    "_depth_optical_frame": "_depth_frame",
    "_infra1_frame": "_link",
    "_infra1_optical_frame": "_infra1_frame",
    "_infra2_frame": "_link",
    "_infra2_optical_frame": "_infra2_frame",
    "_accel_frame": "_link",
    "_accel_optical_frame": "_accel_frame",
    "_gyro_frame": "_link",
    "_gyro_optical_frame": "_gyro_frame",
}


def realsense_ros_parent(frame: str) -> str | None:
    """The parent realsense-ros (publish_tf on) gives `frame` (NAME_color_optical_frame ->
    NAME_color_frame, ...), or None for a frame it publishes no parent for (NAME_link, the root of
    the camera's tree, and any other name)."""
    for suffix, parent_suffix in REALSENSE_ROS_PARENTS.items():
        if frame.endswith(suffix) and len(frame) > len(suffix):
            return frame[: -len(suffix)] + parent_suffix
    return None


def realsense_link_optical(T_colour_depth: np.ndarray | None = None) -> np.ndarray:
    """T_link_optical (4, 4): a RealSense's camera_color_optical_frame in its camera_link (the depth
    module, where realsense-ros puts camera_link), from T_colour_depth (4, 4), the depth imager in
    the colour optical frame (the camera's extrinsics; None: colour and depth at one place, only the
    optical rotation)."""
    T_link_depth_optical = make_transform(OPTICAL_ROTATION, np.zeros(3))
    if T_colour_depth is None:
        return T_link_depth_optical
    return T_link_depth_optical @ invert(T_colour_depth)


@dataclass(frozen=True)
class Export:
    """What to write. parent, child: the frame names. T_link_optical: (4, 4) the camera driver's
    child -> optical transform to compose out when the child is not an optical frame, with
    link_source saying where it came from."""

    calibration: CalibrationFile
    parent: str = "tool0"
    child: str = "camera_color_optical_frame"
    T_link_optical: np.ndarray | None = None
    link_source: str = ""

    def __post_init__(self) -> None:
        check_frame_name(self.parent, "parent frame (--parent)")
        check_frame_name(self.child, "child frame (--child)")

    @property
    def composes_link(self) -> bool:
        return not self.child.endswith(OPTICAL_SUFFIX)

    @property
    def T_parent_child(self) -> np.ndarray:
        """(4, 4) the child frame in the parent frame, metres (module doc)."""
        T = self.calibration.T_flange_cam
        if not self.composes_link:
            return T
        if self.T_link_optical is None:
            raise ValueError(f"child frame '{self.child}' is not an optical frame: give T_link_optical")
        return T @ invert(self.T_link_optical)

    @property
    def covariance_parent_child(self) -> np.ndarray | None:
        """(6, 6) covariance of T_parent_child in the convention of the calibration's (dt along the
        parent's axes, dtheta about the child's), None when the calibration has none."""
        cov = self.calibration.covariance
        if cov is None or not self.composes_link:
            return cov
        T_optical_link = invert(self.T_link_optical)
        J = np.eye(6)
        J[:3, 3:] = -self.calibration.T_flange_cam[:3, :3] @ skew(T_optical_link[:3, 3])
        J[3:, 3:] = T_optical_link[:3, :3].T
        return J @ cov @ J.T

    def comment(self) -> list[str]:
        """The header every format carries: which transform it is and how to use it."""
        cal = self.calibration
        if cal.setup == EYE_TO_HAND:
            result = (
                f"T_base_cam, the fixed camera's optical frame in the robot base frame: {USE_EYE_TO_HAND}."
            )
        else:
            result = f"T_flange_cam, the camera optical frame in the flange: {USE}."
        lines = [
            f"hec calibration ({cal.method}, from {cal.path}): the transform {self.parent} -> {self.child},",
            f"the pose of '{self.child}' in '{self.parent}' (T_{self.parent}_{self.child}), metres.",
            f"hec's result is {result}",
        ]
        if cal.pose_frame == "tcp":
            lines.append("The robot reported its TCP, not the flange: the parent is that TCP frame.")
        if self.composes_link:
            t, q = xyz_quat_from_transform(self.T_link_optical)
            lines += [
                f"'{self.child}' is the camera's root link: T_{self.parent}_{self.child} = "
                f"{cal.hand_eye_name} @ inv(T_link_optical), T_link_optical ({self.link_source}):",
                f"  xyz {_numbers(t)} m, quaternion (w x y z) {_numbers(q)}",
            ]
        return lines


def check_frame_name(name: str, what: str) -> None:
    """ValueError naming what (e.g. "child frame (--child)") when name is empty or holds white
    space or control characters."""
    if not name:
        raise ValueError(f"{what}: the name is empty; give the frame's name as tf2 and the URDF know it")
    bad = [c for c in name if c.isspace() or unicodedata.category(c).startswith("C")]
    if bad:
        raise ValueError(
            f"{what} {name!r}: a frame name holds no white space or control characters (found {bad[0]!r}); "
            "give the frame's name as tf2 and the URDF know it"
        )


def _number(v: float) -> str:
    return repr(float(v))


def _numbers(values) -> str:
    return " ".join(_number(v) for v in values)


def _xyz_xyzw(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t, (w, x, y, z) = xyz_quat_from_transform(T)
    return t, np.array([x, y, z, w])


def _publisher_arguments(e: Export) -> list[str]:
    t, q = _xyz_xyzw(e.T_parent_child)
    values = [("--x", t[0]), ("--y", t[1]), ("--z", t[2]), ("--qx", q[0]), ("--qy", q[1]), ("--qz", q[2])]
    args = [part for name, v in [*values, ("--qw", q[3])] for part in (name, _number(v))]
    return args + ["--frame-id", e.parent, "--child-frame-id", e.child]


def ros2_args(e: Export) -> str:
    """The `ros2 run tf2_ros static_transform_publisher` command line, after '#' comment lines."""
    lines = [f"# {line}" for line in e.comment()]
    words = ["ros2", "run", "tf2_ros", "static_transform_publisher", *_publisher_arguments(e)]
    return "\n".join([*lines, shlex.join(words)]) + "\n"


def ros2_launch(e: Export) -> str:
    """A ROS 2 Python launch file running static_transform_publisher with named arguments."""
    args = ",\n".join(f"                    {json.dumps(a)}" for a in _publisher_arguments(e))
    name = json.dumps(f"hec_{e.parent}_to_{e.child}".replace("/", "_"))
    header = "\n".join(f"# {line}" for line in e.comment())
    return f"""{header}
# Run: ros2 launch THIS_FILE.launch.py
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription(
        [
            Node(
                package="tf2_ros",
                executable="static_transform_publisher",
                name={name},
                arguments=[
{args},
                ],
            )
        ]
    )
"""


def _xml_comment(lines: list[str]) -> str:
    return "\n".join(f"  <!-- {line.replace('--', '- -')} -->" for line in lines)


def urdf(e: Export) -> str:
    """A fixed URDF <joint> parent -> child (xyz metres, rpy radians, RPY_CONVENTION) in a <robot>."""
    T = e.T_parent_child
    xyz, rpy = _numbers(T[:3, 3]), _numbers(rpy_from_transform(T))
    joint = f"{e.parent}_to_{e.child}_joint".replace("/", "_")
    notes = [*e.comment(), f"origin: xyz in metres, rpy in radians about the {RPY_CONVENTION}."]
    return f'''<?xml version="1.0"?>
<robot name="hec_camera_mount">
{_xml_comment(notes)}
  <joint name={quoteattr(joint)} type="fixed">
    <parent link={quoteattr(e.parent)}/>
    <child link={quoteattr(e.child)}/>
    <origin xyz="{xyz}" rpy="{rpy}"/>
  </joint>
</robot>
'''


def _yaml_text(e: Export, data: dict, flow: bool | None = None) -> str:
    """The header as comments, then data (flow: YAML's default_flow_style)."""
    header = "\n".join(f"# {line}" for line in e.comment())
    return header + "\n" + yaml.safe_dump(data, sort_keys=False, default_flow_style=flow, width=1000)


def easy_handeye2(e: Export) -> str:
    """easy_handeye2's .calib YAML (parameters, then transform: translation x y z, rotation x y z w):
    eye_in_hand, the transform effector -> camera; eye_on_base (eye-to-hand), robot base -> camera."""
    t, q = _xyz_xyzw(e.T_parent_child)
    setup = e.calibration.setup
    base, effector = (e.parent, "tool0") if setup == EYE_TO_HAND else ("base_link", e.parent)
    data = {
        "parameters": {
            "name": "hec",
            "calibration_type": EASY_HANDEYE2_TYPES[setup],
            "robot_base_frame": base,
            "robot_effector_frame": effector,
            "tracking_base_frame": e.child,
            "tracking_marker_frame": "hec_board",
            "freehand_robot_movement": True,
        },
        "transform": {
            "translation": dict(zip("xyz", map(float, t), strict=True)),
            "rotation": dict(zip("xyzw", map(float, q), strict=True)),
        },
    }
    return _yaml_text(e, data, flow=False)


def _passed_on(data: dict) -> dict:
    """The calibration file's uncertainty and quality figures, as they are, where present."""
    keys = ("sigma_translation_mm", "sigma_rotation_deg", "pick_error", "residual_rms_px")
    keys += ("residual_depth_rms_mm", "frame_residuals", "leave_one_frame_out")
    return {k: data[k] for k in keys if data.get(k) is not None}


def transform_record(e: Export) -> dict:
    """hec's own description of the exported transform (the yaml and json formats)."""
    T = e.T_parent_child
    t, q = _xyz_xyzw(T)
    cal = e.calibration
    covariance = e.covariance_parent_child
    record = {
        "format": "hec-transform",
        "version": 1,
        "transform": f"T_{e.parent}_{e.child}: the pose of '{e.child}' in '{e.parent}'",
        "use": USE_EYE_TO_HAND if cal.setup == EYE_TO_HAND else USE,
        "parent_frame": e.parent,
        "child_frame": e.child,
        "method": cal.method,
        "calibration_file": str(cal.path),
        "units": "metres and radians (keys ending _mm, _deg, _px: millimetres, degrees, pixels)",
        "matrix": T.tolist(),
        "translation_m": t.tolist(),
        "quaternion_xyzw": q.tolist(),
        "rpy_rad": rpy_from_transform(T).tolist(),
        "rpy_convention": RPY_CONVENTION,
        "covariance": None if covariance is None else covariance.tolist(),
        "covariance_convention": COVARIANCE_CONVENTION
        if covariance is not None
        else "none: the calibration has none",
    }
    if e.composes_link:
        record["T_link_optical"] = e.T_link_optical.tolist()
        record["T_link_optical_source"] = e.link_source
    return record | _passed_on(cal.data)


def hec_yaml(e: Export) -> str:
    return _yaml_text(e, transform_record(e))


def hec_json(e: Export) -> str:
    """JSON has no comments: the header's lines go under 'comment'."""
    return json.dumps({"comment": e.comment(), **transform_record(e)}, indent=1) + "\n"


WRITERS = {  # the formats, in the order the command line lists them
    "ros2-launch": ros2_launch,
    "ros2-args": ros2_args,
    "urdf": urdf,
    "easy_handeye2": easy_handeye2,
    "yaml": hec_yaml,
    "json": hec_json,
}


FORMATS = tuple(WRITERS)


def export_text(e: Export, fmt: str) -> str:
    """The calibration in format fmt (one of FORMATS)."""
    if fmt not in WRITERS:
        raise ValueError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if not np.all(np.isfinite(e.T_parent_child)):
        raise ValueError(
            f"{e.calibration.path}: T_{e.parent}_{e.child} holds numbers that are not finite; nothing written"
        )
    return WRITERS[fmt](e)
