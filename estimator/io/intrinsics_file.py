"""Camera intrinsics from the files other tools write.

- OpenCV's ``cv2.FileStorage`` YAML or JSON (what ``calibrateCamera`` samples save):
  ``camera_matrix`` (or ``K``), ``distortion_coefficients`` (or ``dist_coeffs``, ``D``),
  ``image_width`` and ``image_height``;
- ROS ``camera_info`` YAML, either as ``camera_calibration_parsers`` writes it
  (``image_width``, ``image_height``, ``camera_matrix: {rows, cols, data}``,
  ``distortion_model``, ``distortion_coefficients: {data}``) or as the message dumps
  (``width``, ``height``, ``k`` or ``K``, ``d`` or ``D``, ``distortion_model``).

- ViSP's ``camera.xml`` (``vpXmlParserCamera``): ``image_width``, ``image_height`` and a
  ``model`` of type ``perspectiveProjWithDistortion`` (``px py u0 v0 kud``; kud is OpenCV's k1)
  or ``perspectiveProjWithoutDistortion`` (``px py u0 v0``), the first preferred;
- a numpy ``.npz`` as OpenCV users save ``calibrateCamera``'s output: the matrix as ``K``,
  ``mtx``, ``camera_matrix`` or ``cameraMatrix``, the distortion as ``dist``, ``D``,
  ``dist_coeffs``, ``distortion_coefficients`` or ``distCoeffs``, and the size as ``width`` and
  ``height`` or ``image_size`` (width, height);
- Kalibr's camchain YAML: ``cam0`` with ``camera_model: pinhole``, ``intrinsics: [fu, fv, pu,
  pv]``, ``distortion_model: radtan`` (or none), ``distortion_coeffs: [k1, k2, r1, r2]`` and
  ``resolution: [width, height]``.

Distortion must be OpenCV's model (``plumb_bob``/``rational_polynomial`` coefficients in
OpenCV's order: k1 k2 p1 p2 k3 ...); hec's camera model takes up to five coefficients. A file
without the image size takes image_size when the caller knows it (an import: its images').
"""

from __future__ import annotations

from pathlib import Path
from xml.etree import ElementTree

import cv2
import numpy as np
import yaml

from hec.estimator.common.files import write_atomic
from hec.estimator.geometry.camera import CameraIntrinsics


class IntrinsicsFileError(ValueError):
    """An intrinsics file that cannot be read; the message names the file and the field."""


def read_intrinsics(path: str | Path, image_size: tuple[int, int] | None = None) -> CameraIntrinsics:
    """The camera of an intrinsics file in any of the formats of the module doc; image_size (width,
    height) is used where the file gives none."""
    path = Path(path)
    if not path.is_file():
        raise IntrinsicsFileError(f"{path}: intrinsics file not found")
    if path.suffix.lower() == ".npz":
        return _from_npz(path, image_size)
    text = path.read_text(errors="replace")
    if text.lstrip().startswith("%YAML") or "opencv-matrix" in text:
        return _from_opencv(path)
    if text.lstrip().startswith("<"):
        return _from_visp_xml(path, text)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        why = " ".join(str(exc).split())
        raise IntrinsicsFileError(f"{path}: neither OpenCV FileStorage nor YAML/JSON ({why})") from None
    if not isinstance(data, dict):
        raise IntrinsicsFileError(f"{path}: expected a mapping of intrinsics fields")
    if isinstance(data.get("cam0"), dict):
        return _from_kalibr(data["cam0"], path)
    return _from_mapping(data, path, image_size)


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


def _from_npz(path: Path, image_size: tuple[int, int] | None) -> CameraIntrinsics:
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {key: npz[key].tolist() for key in npz.files}
    except (ValueError, OSError) as exc:
        raise IntrinsicsFileError(f"{path}: not a numpy .npz file ({exc})") from None
    if "image_size" in data and "width" not in data:
        size = np.ravel(data["image_size"]).tolist()
        if len(size) == 2:
            data["width"], data["height"] = size
    for key, value in list(data.items()):
        if key in ("mtx", "cameraMatrix"):
            data.setdefault("K", value)
        if key in ("dist", "distCoeffs"):
            data.setdefault("D", np.ravel(value).tolist())
    return _from_mapping(data, path, image_size)


def _from_visp_xml(path: Path, text: str) -> CameraIntrinsics:
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError as exc:
        raise IntrinsicsFileError(f"{path}: not valid XML ({exc})") from None
    camera = root.find(".//camera")
    if camera is None:
        raise IntrinsicsFileError(f"{path}: no <camera> element (ViSP's camera.xml)")
    models = {m.findtext("type", "").strip(): m for m in camera.findall("model")}
    model = models.get("perspectiveProjWithDistortion", models.get("perspectiveProjWithoutDistortion"))
    if model is None:
        raise IntrinsicsFileError(
            f"{path}: no <model> of type perspectiveProjWithDistortion or perspectiveProjWithoutDistortion"
        )

    def number(element: ElementTree.Element, tag: str) -> float:
        value = element.findtext(tag)
        try:
            return float(value)
        except (TypeError, ValueError):
            raise IntrinsicsFileError(f"{path}: field '{tag}' should be a number, got {value!r}") from None

    px, py, u0, v0 = (number(model, tag) for tag in ("px", "py", "u0", "v0"))
    kud = number(model, "kud") if model.find("kud") is not None else 0.0
    K = np.array([[px, 0.0, u0], [0.0, py, v0], [0.0, 0.0, 1.0]])
    return _intrinsics(path, K, [kud], number(camera, "image_width"), number(camera, "image_height"))


def _from_kalibr(cam: dict, path: Path) -> CameraIntrinsics:
    if cam.get("camera_model", "pinhole") != "pinhole":
        raise IntrinsicsFileError(
            f"{path}: field 'cam0.camera_model' is {cam.get('camera_model')!r}; hec's camera is a pinhole"
        )
    model = cam.get("distortion_model", "radtan")
    if model not in ("radtan", "none"):
        raise IntrinsicsFileError(
            f"{path}: field 'cam0.distortion_model' is {model!r}; only radtan (OpenCV's k1 k2 p1 p2) "
            "is supported"
        )
    values = cam.get("intrinsics")
    if not isinstance(values, list) or len(values) != 4:
        raise IntrinsicsFileError(
            f"{path}: field 'cam0.intrinsics' should be [fu, fv, pu, pv], got {values!r}"
        )
    resolution = cam.get("resolution")
    if not isinstance(resolution, list) or len(resolution) != 2:
        raise IntrinsicsFileError(
            f"{path}: field 'cam0.resolution' should be [width, height], got {resolution!r}"
        )
    fu, fv, pu, pv = values
    K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]], dtype=np.float64)
    dist = list(cam.get("distortion_coeffs", [])) if model == "radtan" else []
    return _intrinsics(path, K, dist, resolution[0], resolution[1])


def _from_mapping(data: dict, path: Path, image_size: tuple[int, int] | None = None) -> CameraIntrinsics:
    model = data.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial", "opencv", ""):
        raise IntrinsicsFileError(
            f"{path}: field 'distortion_model' is {model!r}; only OpenCV's plumb_bob is supported"
        )
    K = _field(data, ("camera_matrix", "K", "k"), path)
    dist = _field(data, ("distortion_coefficients", "D", "d", "dist_coeffs"), path, required=False)
    width = data.get("image_width", data.get("width"))
    height = data.get("image_height", data.get("height"))
    if width is None and height is None and image_size is not None:
        width, height = image_size
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
