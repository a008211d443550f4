"""Camera intrinsics from the files other tools write.

- OpenCV's ``cv2.FileStorage`` YAML or JSON (what ``calibrateCamera`` samples save):
  ``camera_matrix`` (or ``K``), ``distortion_coefficients`` (or ``dist_coeffs``, ``D``),
  ``image_width`` and ``image_height``;
- ROS ``camera_info`` YAML, either as ``camera_calibration_parsers`` writes it
  (``image_width``, ``image_height``, ``camera_matrix: {rows, cols, data}``,
  ``distortion_model``, ``distortion_coefficients: {data}``) or as the message dumps
  (``width``, ``height``, ``k`` or ``K``, ``d`` or ``D``, ``distortion_model``).

Distortion must be OpenCV's model (``plumb_bob``/``rational_polynomial`` coefficients in
OpenCV's order: k1 k2 p1 p2 k3 ...); hec's camera model takes up to five coefficients.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

from hec.estimator.common.files import write_atomic
from hec.estimator.geometry.camera import CameraIntrinsics


class IntrinsicsFileError(ValueError):
    """An intrinsics file that cannot be read; the message names the file and the field."""


def read_intrinsics(path: str | Path) -> CameraIntrinsics:
    """The camera of an OpenCV or ROS intrinsics file (module doc)."""
    path = Path(path)
    if not path.is_file():
        raise IntrinsicsFileError(f"{path}: intrinsics file not found")
    text = path.read_text(errors="replace")
    if text.lstrip().startswith("%YAML") or "opencv-matrix" in text:
        return _from_opencv(path)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise IntrinsicsFileError(f"{path}: neither OpenCV FileStorage nor YAML/JSON ({exc})") from None
    if not isinstance(data, dict):
        raise IntrinsicsFileError(f"{path}: expected a mapping of intrinsics fields")
    return _from_mapping(data, path)


def _from_opencv(path: Path) -> CameraIntrinsics:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        K = _first_matrix(storage, ("camera_matrix", "K", "cameraMatrix"))
        dist = _first_matrix(storage, ("distortion_coefficients", "dist_coeffs", "D", "distCoeffs"))
        width, height = (storage.getNode(k).real() for k in ("image_width", "image_height"))
    finally:
        storage.release()
    if K is None:
        raise IntrinsicsFileError(f"{path}: missing field 'camera_matrix' (3x3)")
    return _intrinsics(path, K, [] if dist is None else dist.ravel().tolist(), width, height)


def _first_matrix(storage: cv2.FileStorage, names: tuple[str, ...]) -> np.ndarray | None:
    for name in names:
        node = storage.getNode(name)
        if not node.empty():
            return node.mat()
    return None


def _from_mapping(data: dict, path: Path) -> CameraIntrinsics:
    model = data.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial", "opencv", ""):
        raise IntrinsicsFileError(
            f"{path}: field 'distortion_model' is {model!r}; only OpenCV's plumb_bob is supported"
        )
    K = _field(data, ("camera_matrix", "K", "k"), path)
    dist = _field(data, ("distortion_coefficients", "D", "d", "dist_coeffs"), path, required=False)
    width = data.get("image_width", data.get("width"))
    height = data.get("image_height", data.get("height"))
    return _intrinsics(path, np.asarray(K, dtype=np.float64), list(dist or []), width, height)


def _field(data: dict, names: tuple[str, ...], path: Path, required: bool = True) -> list | None:
    """The values of the first of names present (a list, or a {rows, cols, data} mapping)."""
    for name in names:
        if name in data:
            value = data[name]
            return value["data"] if isinstance(value, dict) and "data" in value else value
    if required:
        raise IntrinsicsFileError(f"{path}: missing field '{names[0]}'")
    return None


def _intrinsics(path: Path, K: np.ndarray, dist: list, width: object, height: object) -> CameraIntrinsics:
    try:
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    except ValueError:
        raise IntrinsicsFileError(f"{path}: field 'camera_matrix' should have 9 numbers") from None
    if not (isinstance(width, int | float) and isinstance(height, int | float) and width > 0 and height > 0):
        raise IntrinsicsFileError(
            f"{path}: fields 'image_width' and 'image_height' should be positive, got {width!r}, {height!r}"
        )
    coefficients = [float(c) for c in dist]
    if any(c != 0.0 for c in coefficients[5:]):
        raise IntrinsicsFileError(
            f"{path}: field 'distortion_coefficients' has {len(coefficients)} non-zero terms; hec's camera "
            "model takes five (k1 k2 p1 p2 k3)"
        )
    try:
        return CameraIntrinsics(
            int(width),
            int(height),
            float(K[0, 0]),
            float(K[1, 1]),
            float(K[0, 2]),
            float(K[1, 2]),
            tuple((coefficients + [0.0] * 5)[:5]),
        )
    except ValueError as exc:
        raise IntrinsicsFileError(f"{path}: {exc}") from None


def write_opencv_intrinsics(path: str | Path, intrinsics: CameraIntrinsics) -> Path:
    """Write intrinsics as OpenCV's FileStorage YAML (the layout read_intrinsics reads first),
    through a temporary name."""
    storage = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    storage.write("image_width", intrinsics.width)
    storage.write("image_height", intrinsics.height)
    storage.write("camera_matrix", intrinsics.K)
    storage.write("distortion_coefficients", np.array(intrinsics.dist, dtype=np.float64).reshape(1, -1))
    return write_atomic(Path(path), storage.releaseAndGetString())
