"""Landmark observations: what the estimators see of each marker in each frame, with covariances.

Per frame and marker: the corner pixels and the centre (from hec.estimator.targets.qr),
the depth at the centre and the corners (from the plane under the marker,
hec.estimator.observe.depth), and those five points back-projected into the camera frame
(OpenCV optical frame, metres). Covariances combine the pixel covariance of
the fit and the depth noise model sigma(z):
p = z(u, v) * ray(u, v), so dp/d(u, v) = z dray/d(u, v) + ray (dz/du, dz/dv)
and cov(p) = dp/d(uv) cov(uv) dp/d(uv)^T + var(z) ray ray^T.

A frame that cannot be used keeps its row with ``problem`` set; a marker
without depth keeps its pixels with ``depth_note`` saying why. Observations
are cached beside a dataset in ``detections.json`` (format hec-detections v1)
so estimators can be rerun without detecting again, with the corner noise floor learned
from the dataset (hec.estimator.observe.corner_noise) when their covariances use it.
"""

from __future__ import annotations

import csv
import hashlib
import json
from collections import Counter
from collections.abc import Callable
from dataclasses import Field, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.geometry.camera import CameraIntrinsics, pixel_rays
from hec.estimator.observe.depth import DepthFitError, DepthNoiseModel, fit_marker_depth
from hec.estimator.observe.frames import Dataset, DatasetError, Frame
from hec.estimator.targets.detection import BLURRED_SHARPNESS, MarkerDetection, Rejection
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.target import TargetDetector

CACHE_FILE = "detections.json"
CACHE_FORMAT = "hec-detections"
CACHE_VERSION = 1
FINGERPRINT_FILES = ("dataset.json", "board.json", "frames.csv")  # what a cache was made from


class ObservationCacheError(ValueError):
    """A detections cache is missing, malformed or stale."""


@dataclass(frozen=True)
class MarkerObservation(MarkerDetection):
    """One marker in one frame: its detection (hec.estimator.targets.qr.MarkerDetection) plus depth.

    Points are (centre, corner 0..P-1), P the board's points per marker (4 for a QR code, 1 for
    a chessboard corner, whose centre is the point itself). depth_m (1 + P,), depth_cov
    (1 + P, 1 + P): depth along the optical axis at those points (correlated: one plane);
    depth_slope (1 + P, 2): the plane's dz/d(u, v) there, metres per pixel. points_cam (1 + P, 3),
    points_cov (1 + P, 3, 3): the points in the camera frame, metres, each with its own
    covariance. Depth fields are None when the marker has no usable depth; depth_note
    then says why. depth_pixels: inlier, valid and total pixel counts under the marker.
    """

    depth_m: np.ndarray | None = None
    depth_cov: np.ndarray | None = None
    depth_slope: np.ndarray | None = None
    points_cam: np.ndarray | None = None
    points_cov: np.ndarray | None = None
    depth_note: str | None = None
    depth_pixels: dict = field(default_factory=dict)


@dataclass
class FrameObservations:
    """Everything observed in one frame. problem: why the frame gave nothing, else None.
    notes: frame-level remarks that did not stop it (for example unusable depth)."""

    frame: int
    time_s: float
    T_base_flange: np.ndarray
    markers: list[MarkerObservation] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)
    problem: str | None = None
    notes: list[str] = field(default_factory=list)
    passes_run: list[str] = field(default_factory=list)

    def marker(self, marker_id: int) -> MarkerObservation | None:
        return next((m for m in self.markers if m.marker_id == marker_id), None)


def depth_problem(depth_m: np.ndarray | None, intrinsics: CameraIntrinsics) -> str | None:
    """Why a frame's depth image cannot be used at all, or None."""
    if depth_m is None:
        return "no depth image"
    if depth_m.shape != (intrinsics.height, intrinsics.width):
        return (
            f"depth image is {depth_m.shape[1]}x{depth_m.shape[0]} but colour is "
            f"{intrinsics.width}x{intrinsics.height}: depth must be aligned to the colour image"
        )
    if not np.any(np.isfinite(depth_m) & (depth_m > 0)):
        return "depth image has no valid pixel (all zero)"
    return None


def observe_frame(
    index: int, frame: Frame, detector: TargetDetector, depth_noise: DepthNoiseModel
) -> FrameObservations:
    """Detect the markers of one frame and turn them into observations."""
    obs = FrameObservations(index, frame.time_s, np.asarray(frame.T_base_flange, dtype=np.float64))
    rgb = np.asarray(frame.rgb)
    if rgb.ndim >= 2 and rgb.shape[:2] != (frame.intrinsics.height, frame.intrinsics.width):
        obs.problem = (
            f"colour image is {rgb.shape[1]}x{rgb.shape[0]} but the intrinsics say "
            f"{frame.intrinsics.width}x{frame.intrinsics.height}"
        )
        return obs
    detections = detector.detect(rgb)
    obs.rejected = detections.rejected
    obs.passes_run = detections.passes_run
    obs.notes.extend(detections.notes)
    if detections.problem is not None:
        obs.problem = detections.problem
        return obs
    if not detections.markers:
        blurred = detections.sharpness < BLURRED_SHARPNESS
        sharpness = f"sharpness {detections.sharpness:.0f}" + (": the image looks blurred" if blurred else "")
        obs.problem = (
            f"{_all_rejected(detections.rejected)} ({sharpness})"
            if detections.rejected
            else f"no board marker found ({sharpness})"
        )
        return obs
    no_depth = depth_problem(frame.depth_m, frame.intrinsics)
    if no_depth is not None:
        obs.notes.append(f"{no_depth}; markers kept without depth")
    for det in detections.markers:
        depth = (
            {"depth_note": no_depth}
            if no_depth
            else _depth(det, frame.depth_m, frame.intrinsics, depth_noise)
        )
        obs.markers.append(MarkerObservation(**{f.name: getattr(det, f.name) for f in fields(det)}, **depth))
    return obs


def camera_points(
    marker: MarkerDetection,
    z: np.ndarray,
    z_cov: np.ndarray,
    slope: np.ndarray,
    intrinsics: CameraIntrinsics,
) -> tuple[np.ndarray, np.ndarray]:
    """The centre and points of a marker in the camera frame, each with its covariance.

    z: (1 + P,) depth at (centre, point 0..P-1), metres; z_cov: (1 + P, 1 + P); slope: (1 + P, 2)
    dz/d(u, v) of the surface there. Returns points (1 + P, 3) and their covariances (1 + P, 3, 3).
    """
    uv = np.vstack([marker.center_px, marker.corners_px])
    return back_projected_points(uv, _pixel_covariances(marker), z, np.diag(z_cov), slope, intrinsics)


def _pixel_covariances(marker: MarkerDetection) -> np.ndarray:
    """(1 + P, 2, 2) covariances of the marker's centre and points 0..P-1, pixels^2."""
    P = len(marker.corners_px)
    uv_cov = np.zeros((1 + P, 2, 2))
    uv_cov[0] = marker.center_cov
    for k in range(P):
        uv_cov[k + 1] = marker.corners_cov[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]
    return uv_cov


def back_projected_points(
    uv: np.ndarray,
    uv_cov: np.ndarray,
    z: np.ndarray,
    z_var: np.ndarray,
    slope: np.ndarray,
    intrinsics: CameraIntrinsics,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (..., 3) and their covariances (..., 3, 3) of pixels uv (..., 2) with
    covariances uv_cov (..., 2, 2), depths z (...,) of variances z_var (...,), metres, independent
    of the pixels, on a surface of slope dz/d(u, v) (..., 2) there."""
    rays, d_ray_d_uv = pixel_rays(uv, intrinsics)
    rays, d_ray_d_uv = rays.reshape(*z.shape, 3), d_ray_d_uv.reshape(*z.shape, 3, 2)
    d_p_d_uv = z[..., None, None] * d_ray_d_uv + rays[..., :, None] * slope[..., None, :]
    points_cov = d_p_d_uv @ uv_cov @ np.swapaxes(d_p_d_uv, -1, -2) + z_var[..., None, None] * (
        rays[..., :, None] * rays[..., None, :]
    )
    return rays * z[..., None], points_cov


def with_pixel_floor(
    marker: MarkerObservation, corner_var: float, center_var: float, intrinsics: CameraIntrinsics
) -> MarkerObservation:
    """The marker with corner_var added to the variance of each corner coordinate and center_var
    to the centre's (pixels^2), and its 3D points' covariances grown to match (with the depth
    plane's slope; caches written before it was kept: the slope through its corners' depths)."""
    grown = replace(
        marker,
        corners_cov=marker.corners_cov + corner_var * np.eye(marker.corners_cov.shape[0]),
        center_cov=marker.center_cov + center_var * np.eye(2),
    )
    if marker.points_cam is None:
        return grown
    uv = np.vstack([marker.center_px, marker.corners_px])
    slope = marker.depth_slope if marker.depth_slope is not None else _plane_slope(uv, marker.depth_m)
    _, points_cov = camera_points(grown, marker.depth_m, marker.depth_cov, slope, intrinsics)
    return replace(grown, points_cov=points_cov)


def _plane_slope(uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(n, 2) dz/d(u, v) at the pixels uv (n, 2), n >= 3 apart, of depths z (n,) on one plane, metres per
    pixel: 1/z is linear in (u, v) there (hec.estimator.observe.depth.MarkerDepth)."""
    A = np.column_stack([np.ones(len(uv)), uv - uv.mean(axis=0)])
    coeffs = np.linalg.lstsq(A, 1.0 / z, rcond=None)[0]
    return -(z * z)[:, None] * coeffs[1:][None, :]


def _depth(
    marker: MarkerDetection, depth_m: np.ndarray, intrinsics: CameraIntrinsics, noise: DepthNoiseModel
) -> dict:
    """The depth fields of MarkerObservation for one detected marker."""
    try:
        region = marker.corners_px if marker.depth_region_px is None else marker.depth_region_px
        plane = fit_marker_depth(depth_m, region, noise)
    except DepthFitError as exc:
        return {"depth_note": str(exc)}
    uv = np.vstack([marker.center_px, marker.corners_px])
    z, z_cov = plane.depth_at(uv)
    slope = plane.slope_at(uv)
    points, points_cov = camera_points(marker, z, z_cov, slope, intrinsics)
    return {
        "depth_m": z,
        "depth_cov": z_cov,
        "depth_slope": slope,
        "points_cam": points,
        "points_cov": points_cov,
        "depth_pixels": {"inliers": plane.inliers, "valid": plane.valid, "pixels": plane.pixels},
    }


def _all_rejected(rejected: list[Rejection]) -> str:
    """'the board was seen, but all N of its points found were rejected: ...' with the two most
    common reasons (each Rejection's reason without its 'marker 3: ' or 'corner 7: ' prefix)."""
    reasons = Counter(r.reason.split(": ", 1)[-1] for r in rejected)
    said = "; ".join(f"{n} {reason}" for reason, n in reasons.most_common(2))
    more = f"; {len(reasons) - 2} other reasons" if len(reasons) > 2 else ""
    return f"the board was seen, but all {len(rejected)} of its points found were rejected: {said}{more}"


def dataset_depth_noise(dataset: Dataset) -> DepthNoiseModel:
    """The dataset's depth noise model (dataset.json 'depth_noise', else D435 defaults),
    with the depth step of its depth images."""
    spec = dataset.metadata.get("depth_noise")
    try:
        model = DepthNoiseModel.from_dict(spec) if isinstance(spec, dict) else DepthNoiseModel()
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(
            f"{dataset.root / 'dataset.json'}: field 'depth_noise' is malformed ({exc})"
        ) from None
    return replace(model, depth_step_m=dataset.depth_scale_m)


def observe_dataset(
    dataset: Dataset,
    settings: DetectorSettings | None = None,
    depth_noise: DepthNoiseModel | None = None,
    progress: Callable[[FrameObservations, Frame | None], None] | None = None,
) -> list[FrameObservations]:
    """Observations of every frame; a frame whose files cannot be read is kept with its problem.
    progress, if given, is called after each frame with its observations and the frame
    (None when it could not be read)."""
    detector = detector_for(dataset.board, settings)
    noise = depth_noise or dataset_depth_noise(dataset)
    observations = []
    for i, row in enumerate(dataset.rows):
        try:
            frame = dataset.frame(i)
        except DatasetError as exc:
            frame = None
            obs = FrameObservations(i, row["time_s"], row["T_base_flange"], problem=str(exc))
        else:
            obs = observe_frame(i, frame, detector, noise)
        observations.append(obs)
        if progress is not None:
            progress(obs, frame)
    return observations


def dataset_fingerprint(root: Path, frame_count: int) -> str:
    """sha256 over dataset.json, board.json, frames.csv and the number of frames a cache holds: a
    cache made for other frames, another board, or fewer frames than the dataset has is stale."""
    digest = hashlib.sha256()
    for name in FINGERPRINT_FILES:
        digest.update((root / name).read_bytes())
    digest.update(f"frames observed: {frame_count}".encode())
    return digest.hexdigest()


def _frames_in(root: Path) -> int:
    """The number of frames of the dataset at root (rows of its frames.csv)."""
    with open(root / "frames.csv", newline="") as f:
        return sum(1 for _ in csv.DictReader(f))


def _array(a: np.ndarray | None) -> list | None:
    return None if a is None else np.asarray(a, dtype=np.float64).tolist()


def _is_array_field(f: Field) -> bool:
    return "ndarray" in str(f.type)


def _marker_to_dict(m: MarkerObservation) -> dict:
    return {
        f.name: _array(getattr(m, f.name)) if _is_array_field(f) else getattr(m, f.name) for f in fields(m)
    }


def _rejection_to_dict(r: Rejection) -> dict:
    return {
        "reason": r.reason,
        "marker_id": r.marker_id,
        "payload": r.payload,
        "corners_px": _array(r.corners_px),
    }


def save_observations(
    root: Path,
    observations: list[FrameObservations],
    settings: DetectorSettings,
    depth_noise: DepthNoiseModel,
    corner_noise: dict | None = None,
) -> Path:
    """Write DATASET/detections.json (temporary file, then rename). Returns its path.
    corner_noise: the corner noise measured on the dataset and the floors its covariances use
    (hec.estimator.observe.corner_noise.CornerNoise.to_dict), if they were learned."""
    data = {
        "format": CACHE_FORMAT,
        "version": CACHE_VERSION,
        "dataset_fingerprint": dataset_fingerprint(root, len(observations)),
        "detector": settings.to_dict(),
        "depth_noise": depth_noise.to_dict(),
        "corner_noise": corner_noise,
        "points": "centre, then the marker's points: corners 0..3 (top-left, top-right, bottom-right, "
        "bottom-left) of a QR code or tag, the point itself for a chessboard corner",
        "units": "pixels; metres in the camera frame (x right, y down, z forward)",
        "frames": [
            {
                "frame": o.frame,
                "time_s": o.time_s,
                "T_base_flange": _array(o.T_base_flange),
                "problem": o.problem,
                "notes": o.notes,
                "passes_run": o.passes_run,
                "markers": [_marker_to_dict(m) for m in o.markers],
                "rejected": [_rejection_to_dict(r) for r in o.rejected],
            }
            for o in observations
        ],
    }
    return write_atomic(root / CACHE_FILE, json.dumps(data))


def _opt(value: list | None) -> np.ndarray | None:
    return None if value is None else np.array(value, dtype=np.float64)


def _finite(name: str, value: list | None) -> np.ndarray | None:
    """A marker's array field; ValueError when it holds NaN or infinity (a damaged cache)."""
    array = _opt(value)
    if array is not None and not np.all(np.isfinite(array)):
        raise ValueError(f"marker field '{name}' is not finite")
    return array


def load_observations(
    root: Path, settings: DetectorSettings | None = None
) -> tuple[list[FrameObservations], DetectorSettings, DepthNoiseModel]:
    """Read DATASET/detections.json. Raises ObservationCacheError if it is missing, malformed,
    made for other frames, or (when settings are given) made with other detector settings."""
    path = Path(root) / CACHE_FILE
    data = read_json_object(path, ObservationCacheError, "no detections cache (run `hec detect` first)")
    if data.get("format") != CACHE_FORMAT or data.get("version") != CACHE_VERSION:
        raise ObservationCacheError(f"{path}: expected format {CACHE_FORMAT!r} version {CACHE_VERSION}")
    try:
        frame_count = _frames_in(Path(root))
        fingerprint = dataset_fingerprint(Path(root), frame_count)
    except OSError as exc:
        raise ObservationCacheError(f"{path}: cannot check it against the dataset ({exc})") from None
    if data.get("dataset_fingerprint") != fingerprint:
        raise ObservationCacheError(
            f"{path}: stale, the dataset or its board changed since detection, or it holds fewer than the "
            f"dataset's {frame_count} frames; run `hec detect` again"
        )
    try:
        cached_settings = DetectorSettings.from_dict(data["detector"])
        depth_noise = DepthNoiseModel.from_dict(data["depth_noise"])
        frames = [_frame_from_dict(f) for f in data["frames"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise ObservationCacheError(f"{path}: malformed ({type(exc).__name__}: {exc})") from None
    if settings is not None and settings != cached_settings:
        raise ObservationCacheError(f"{path}: made with other detector settings; run `hec detect` again")
    return frames, cached_settings, depth_noise


def _field(marker: dict, f: Field) -> object:
    """A cached marker's field; a field that defaults to None may be absent (caches written
    before it existed)."""
    return marker.get(f.name) if f.default is None else marker[f.name]


def _frame_from_dict(f: dict) -> FrameObservations:
    markers = [
        MarkerObservation(
            **{
                f.name: _finite(f.name, _field(m, f)) if _is_array_field(f) else _field(m, f)
                for f in fields(MarkerObservation)
            }
        )
        for m in f["markers"]
    ]
    rejected = [
        Rejection(r["reason"], r["marker_id"], r["payload"], _opt(r["corners_px"])) for r in f["rejected"]
    ]
    return FrameObservations(
        frame=int(f["frame"]),
        time_s=float(f["time_s"]),
        T_base_flange=np.array(f["T_base_flange"]),
        markers=markers,
        rejected=rejected,
        problem=f["problem"],
        notes=list(f["notes"]),
        passes_run=list(f["passes_run"]),
    )
