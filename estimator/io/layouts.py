"""Other tools' hand-eye data layouts, read and written.

- ``folder``: a folder of images plus a pose file in any convention (hec.estimator.io.pose_file), one
  pose per image, paired by an explicit key (hec.estimator.io.pairing: the pose file's ``image``
  column, the numbers in the image names, or the nearest time); depth images (16-bit PNG or a
  numpy .npy, same names) optionally in another folder; joint angles optionally in a joint file
  (any count per image; a UR arm's six in its own order or the ROS driver's), paired as the poses.
- ``visp``: ViSP's hand-eye tutorial layout: ``image-N.png`` beside ``pose_fPe_N.yaml`` (N from 1),
  each pose ViSP's vpPoseVector YAML (``rows: 6``, ``cols: 1``, ``data``: translation in metres,
  then theta-u, a rotation vector in radians) of the end-effector in the robot's reference frame,
  T_base_flange.
- ``easy_handeye2``: easy_handeye2's ``.samples`` file (a SampleList message as YAML): per sample
  ``robot`` (for eye-in-hand T_base_effector) and ``tracking`` (T_camera_marker), each a
  translation x y z in metres and a rotation quaternion x y z w. Pose pairs, no images.

Readers return what the layout holds; errors name the file and the field. Writers exist so that a
hec dataset can be taken to those tools (and round trips tested).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_text
from hec.estimator.geometry.kinematics import URKinematics, forward, joints_in_arm_order
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.io.pairing import Pairing, natural_key, pair_images
from hec.estimator.io.pose_file import PoseConvention, columns_by_name, poses_from_values, values_from_poses
from hec.estimator.io.pose_folder import read_pose_folder
from hec.estimator.io.pose_table import IMAGE_SUFFIXES, NumberTable, read_number_table
from hec.estimator.observe.pose_pairs import PosePair

DEPTH_SUFFIXES = (".png", ".npy")
# A UR arm's joints by the names the ROS driver gives them, in the arm's order.
UR_JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
VISP_CONVENTION = PoseConvention(
    rotation="rotvec", angle_unit="rad", length_unit="m", direction="base-to-flange"
)
_TRAILING_NUMBER = re.compile(r"(\d+)\D*$")


class LayoutError(ValueError):
    """A layout's files do not fit together or one is malformed; the message names the file."""


@dataclass(frozen=True)
class JointFile:
    """A joint file (hec.estimator.io.pose_file's format, field "joints"): angles in unit ("rad" or
    "deg"); six angles of a UR arm in order ("arm" or "ros-driver", kinematics.JOINT_ORDERS)."""

    path: Path
    unit: str = "rad"
    order: str = "arm"


@dataclass(frozen=True)
class LayoutFrames:
    """Images with their robot poses. images, depths: (N,) paths (depths None where absent).
    pose_values: (N, k) the numbers as the source wrote them, in convention (the convention check
    reads them in others); T_base_flange: (N, 4, 4) as read in convention. joints: (N, n) radians in
    the arm's order, or None. pairing: which pose row each image took; notes: what the pose file's
    reading found that a person should know (repeated poses)."""

    images: list[Path]
    depths: list[Path | None]
    pose_values: np.ndarray
    convention: PoseConvention
    pairing: Pairing
    joints: np.ndarray | None = None
    notes: tuple[str, ...] = ()

    @property
    def T_base_flange(self) -> np.ndarray:
        return poses_from_values(self.pose_values, self.convention)


def read_folder(
    images_dir: str | Path,
    pose_file: str | Path | None,
    convention: PoseConvention,
    depth_dir: str | Path | None = None,
    joint_file: JointFile | None = None,
    pair_by: str | None = None,
    time_tolerance_s: float = 0.02,
    image_time_unit: str = "s",
    kinematics: URKinematics | None = None,
) -> LayoutFrames:
    """An image folder, its pose file and optionally depth images and a joint file (module doc),
    paired by pair_by (hec.estimator.io.pairing). Without a pose file, the flange poses are the
    joint file's angles through kinematics (T_base_flange = forward(kinematics, q), in the matrix
    convention)."""
    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise LayoutError(f"{images_dir}: no such image folder")
    if pose_file is None and (joint_file is None or kinematics is None):
        raise LayoutError(
            "without a pose file, the flange poses come from the joints: give both joints and the arm"
        )
    if pose_file is None:
        table = read_number_table(joint_file.path, "joints")
    else:
        pose_file = Path(pose_file)
        table = read_pose_folder(pose_file) if pose_file.is_dir() else read_number_table(pose_file)
        table = columns_by_name(table, convention)
    on_disk = [p for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]
    if not on_disk:
        raise LayoutError(f"{images_dir}: no images ({', '.join(IMAGE_SUFFIXES)})")
    pairing = pair_images(on_disk, table, pair_by, time_tolerance_s, image_time_unit)
    if joint_file is None:
        joints = None
    else:
        joint_table = table if pose_file is None else read_number_table(joint_file.path, "joints")
        joints = _joints(joint_file, joint_table, pairing, len(table.values))
    if pose_file is None:
        if joints.shape[1] != 6:
            raise LayoutError(
                f"{joint_file.path}: {kinematics.name} has 6 joints, the file {joints.shape[1]} per row"
            )
        values = np.array([forward(kinematics, q).ravel() for q in joints])
        convention = PoseConvention("matrix")
    else:
        values = table.values[pairing.rows]
        poses_from_values(values, convention, str(pose_file))  # the numbers must read in the convention
    depths = _depths(pairing.images, depth_dir)
    return LayoutFrames(pairing.images, depths, values, convention, pairing, joints, tuple(table.notes))


def _joints(joint_file: JointFile, table: NumberTable, pairing: Pairing, pose_rows: int) -> np.ndarray:
    """(N, n) radians in the arm's order, row i for pairing.images[i], from the joint file's table: by
    its image names, else its rows paired as the pose file's pose_rows rows; a header that names a UR
    arm's joints as the ROS driver does decides their order."""
    if joint_file.unit not in ("rad", "deg"):
        raise LayoutError(f"{joint_file.path}: joint unit must be rad or deg, got {joint_file.unit!r}")
    images = pairing.images
    if table.names is not None:
        rows = dict(zip(table.names, table.values, strict=True))
        missing = [p.name for p in images if p.name not in rows]
        if missing:
            raise LayoutError(f"{joint_file.path}: no joints for image {', '.join(missing[:5])}")
        values = np.array([rows[p.name] for p in images])
    elif len(table.values) != pose_rows:
        raise LayoutError(
            f"{joint_file.path} has {len(table.values)} rows of joints but the pose file {pose_rows} "
            "(and no 'image' column to match them by name)"
        )
    else:
        values = table.values[pairing.rows]
    values = np.radians(values) if joint_file.unit == "deg" else values
    named = _named_joint_order(table.columns)
    if named is not None:
        return values[:, named]
    if joint_file.order != "arm":
        if values.shape[1] != 6:
            raise LayoutError(
                f"{joint_file.path}: joint order {joint_file.order!r} is a UR arm's, for six joints; "
                f"the file has {values.shape[1]}"
            )
        values = joints_in_arm_order(values, joint_file.order)
    return values


def _named_joint_order(columns: list[str] | None) -> list[int] | None:
    """The columns of a UR arm's six joints in the arm's order, when the header names them as the ROS
    driver does (shoulder_pan_joint, ..., wrist_3_joint, with any prefix); else None."""
    if columns is None or len(columns) != 6:
        return None
    lowered = [c.lower() for c in columns]
    found = [[i for i, c in enumerate(lowered) if name in c] for name in UR_JOINT_NAMES]
    return [f[0] for f in found] if all(len(f) == 1 for f in found) else None


def _depths(images: list[Path], depth_dir: str | Path | None) -> list[Path | None]:
    """The depth image of each image (same stem, .png or .npy) in depth_dir, or None without
    depth_dir."""
    if depth_dir is None:
        return [None] * len(images)
    depth_dir = Path(depth_dir)
    if not depth_dir.is_dir():
        raise LayoutError(f"{depth_dir}: no such depth folder")
    depths, missing = [], []
    for image in images:
        found = [depth_dir / f"{image.stem}{suffix}" for suffix in DEPTH_SUFFIXES]
        found = [d for d in found if d.is_file()]
        if len(found) > 1:
            raise LayoutError(
                f"{depth_dir}: two depth files for {image.name}: {found[0].name} and {found[1].name}"
            )
        depths.append(found[0] if found else None)
        if not found:
            missing.append(image.stem)
    if missing:
        raise LayoutError(
            f"{depth_dir}: no depth image ({' or '.join(DEPTH_SUFFIXES)}) for {', '.join(missing[:5])}"
        )
    return depths


def write_folder(
    out_dir: str | Path,
    rgb_pngs: list[bytes],
    T_base_flange: np.ndarray,
    convention: PoseConvention,
    joints: np.ndarray | None = None,
) -> Path:
    """images/NNNNNN.png and poses.csv (with an image column) in a convention: the folder layout;
    with joints (N, n) radians, also joints.csv (image, q1..qn)."""
    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    lines = ["image," + ",".join(f"v{k}" for k in range(convention.values_per_pose))]
    for i, (png, values) in enumerate(
        zip(rgb_pngs, values_from_poses(T_base_flange, convention), strict=True)
    ):
        name = f"{i:06d}.png"
        write_atomic(out_dir / "images" / name, png)
        lines.append(name + "," + ",".join(repr(float(v)) for v in values))
    write_atomic(out_dir / "poses.csv", "\n".join(lines) + "\n")
    if joints is not None:
        rows = ["image," + ",".join(f"q{k + 1}" for k in range(joints.shape[1]))]
        rows += [f"{i:06d}.png," + ",".join(repr(float(v)) for v in q) for i, q in enumerate(joints)]
        write_atomic(out_dir / "joints.csv", "\n".join(rows) + "\n")
    return out_dir


def read_visp(folder: str | Path) -> LayoutFrames:
    """ViSP's hand-eye layout (module doc): each pose file N (``pose_fPe_N.yaml``, or any YAML file
    whose name holds "pose" and ends in its number) with the image whose name ends in the same
    number (``image-N.png``, or any image file)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise LayoutError(f"{folder}: no such folder")
    poses = _numbered(folder, (".yaml", ".yml"), "pose")
    if not poses:
        raise LayoutError(f"{folder}: no pose_fPe_N.yaml files (ViSP's hand-eye layout)")
    images = _numbered(folder, IMAGE_SUFFIXES, "image")
    missing = [poses[n].name for n in poses if n not in images]
    if missing:
        raise LayoutError(f"{folder}: no image numbered as pose {', '.join(missing[:5])}")
    unposed = [images[n].name for n in images if n not in poses]
    if unposed:
        raise LayoutError(f"{folder}: images without a pose file: {', '.join(unposed[:5])}")
    numbers = sorted(poses)
    values = np.array([_visp_pose(poses[n]) for n in numbers])
    pairing = Pairing(
        "number", [images[n] for n in numbers], list(range(len(numbers))), [poses[n].name for n in numbers]
    )
    return LayoutFrames(pairing.images, [None] * len(numbers), values, VISP_CONVENTION, pairing)


def _numbered(folder: Path, suffixes: tuple[str, ...], what: str) -> dict[int, Path]:
    """The files of folder with one of suffixes by the number their name ends in; a number taken
    twice is refused, naming both files."""
    found: dict[int, Path] = {}
    for path in sorted(folder.iterdir(), key=lambda p: natural_key(p.name)):
        match = _TRAILING_NUMBER.search(path.stem)
        if path.suffix.lower() not in suffixes or not path.is_file() or match is None:
            continue
        if what == "pose" and "pose" not in path.stem.lower():
            continue
        number = int(match.group(1))
        if number in found:
            raise LayoutError(
                f"{folder}: {found[number].name} and {path.name} are both {what} {number}; "
                "keep one (or rename the other)"
            )
        found[number] = path
    return found


def _visp_pose(path: Path) -> list[float]:
    try:
        data = yaml.safe_load(read_text(path, LayoutError))
    except yaml.YAMLError as exc:
        raise LayoutError(f"{path}: not YAML ({exc})") from None
    if not isinstance(data, dict) or data.get("rows") != 6 or data.get("cols") != 1:
        raise LayoutError(f"{path}: expected a vpPoseVector: 'rows: 6', 'cols: 1' and 'data'")
    entries = data.get("data")
    try:
        values = [float(np.ravel(e)[0]) for e in entries]
    except (TypeError, ValueError, IndexError):
        values = []
    if len(values) != 6:
        raise LayoutError(
            f"{path}: field 'data' should hold 6 numbers (tx ty tz tux tuy tuz), got {entries!r}"
        )
    return values


def write_visp(out_dir: str | Path, rgb_pngs: list[bytes], T_base_flange: np.ndarray) -> Path:
    """image-N.png and pose_fPe_N.yaml (N from 1): ViSP's hand-eye layout."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for n, (png, values) in enumerate(
        zip(rgb_pngs, values_from_poses(T_base_flange, VISP_CONVENTION), strict=True), start=1
    ):
        write_atomic(out_dir / f"image-{n}.png", png)
        rows = "".join(f"  - [{float(v)!r}]\n" for v in values)
        write_atomic(out_dir / f"pose_fPe_{n}.yaml", f"rows: 6\ncols: 1\ndata:\n{rows}")
    return out_dir


def read_easy_handeye_samples(path: str | Path) -> list[PosePair]:
    """The pose pairs of an easy_handeye2 .samples file (module doc), frames numbered from 0."""
    path = Path(path)
    if not path.is_file():
        raise LayoutError(f"{path}: samples file not found")
    try:
        data = yaml.safe_load(read_text(path, LayoutError))
    except yaml.YAMLError as exc:
        raise LayoutError(f"{path}: not YAML ({exc})") from None
    samples = data.get("samples") if isinstance(data, dict) else None
    if not isinstance(samples, list) or not samples:
        raise LayoutError(f"{path}: field 'samples' should be a non-empty list of {{robot, tracking}}")
    pairs = []
    for i, sample in enumerate(samples):
        where = f"{path}: samples[{i}]"
        if not isinstance(sample, dict):
            raise LayoutError(f"{where}: expected {{robot, tracking}}")
        pairs.append(
            PosePair(
                i,
                _ros_transform(sample.get("robot"), f"{where}.robot"),
                _ros_transform(sample.get("tracking"), f"{where}.tracking"),
            )
        )
    return pairs


def _ros_transform(value: object, where: str) -> np.ndarray:
    """(4, 4) of a geometry_msgs/Transform as YAML: translation {x, y, z}, rotation {x, y, z, w}."""
    try:
        t = [float(value["translation"][k]) for k in "xyz"]
        q = [float(value["rotation"][k]) for k in "xyzw"]
    except (TypeError, KeyError, ValueError):
        raise LayoutError(
            f"{where}: expected translation {{x, y, z}} and rotation {{x, y, z, w}}, got {value!r}"
        ) from None
    if not np.all(np.isfinite(t + q)):
        raise LayoutError(f"{where}: translation and rotation must be finite numbers, got {value!r}")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-3:
        raise LayoutError(f"{where}: rotation quaternion has norm {norm:.4g}, not 1")
    return make_transform(Rotation.from_quat(q).as_matrix(), np.array(t))


def write_easy_handeye_samples(path: str | Path, pairs: list[PosePair]) -> Path:
    """An easy_handeye2 .samples file of pose pairs (robot T_base_flange, tracking T_cam_board)."""

    def transform(T: np.ndarray) -> dict:
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        return {
            "translation": dict(zip("xyz", map(float, T[:3, 3]), strict=True)),
            "rotation": {"x": float(x), "y": float(y), "z": float(z), "w": float(w)},
        }

    samples = [{"robot": transform(p.T_base_flange), "tracking": transform(p.T_cam_board)} for p in pairs]
    return write_atomic(Path(path), yaml.safe_dump({"samples": samples}, sort_keys=False))
