"""`hec detect`: detect the board in every frame of a dataset, cache the observations, and report."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.io.dataset import load_dataset
from hec.estimator.io.png import write_png
from hec.estimator.observe.corner_noise import CornerNoise, learn_corner_floor
from hec.estimator.observe.frames import Dataset, Frame
from hec.estimator.observe.grading import grade_observations
from hec.estimator.observe.observations import (
    CACHE_FILE,
    FrameObservations,
    ObservationCacheError,
    dataset_depth_noise,
    load_observations,
    observe_dataset,
    save_observations,
)
from hec.estimator.observe.overlay import draw_overlay
from hec.estimator.targets.qr import DEFAULT_PASSES, DetectorSettings

OVERLAY_DIR = "overlay"


def _frame_row(obs: FrameObservations, board_ids: list[int]) -> str:
    found = sorted(m.marker_id for m in obs.markers)
    missing = [i for i in board_ids if i not in found]
    if obs.markers:
        corner_sigma = np.median([np.sqrt(np.diag(m.corners_cov)).mean() for m in obs.markers])
        with_depth = [m for m in obs.markers if m.depth_cov is not None]
        depth_sigma = (
            f"{1000 * np.median([np.sqrt(m.depth_cov[0, 0]) for m in with_depth]):7.3f}"
            if with_depth
            else "    -  "
        )
        sigmas = f"{corner_sigma:7.4f} {depth_sigma}"
    else:
        sigmas = "   -       -   "
    note = obs.problem or "; ".join([*obs.notes, *(r.reason for r in obs.rejected)])
    return (
        f"{obs.frame:5d} {len(found):3d}/{len(board_ids):<3d} {','.join(map(str, missing)) or '-':>9} "
        f"{sigmas}  {','.join(obs.passes_run) or '-':<16} {note}"
    )


def _write_overlay(
    out: Path, obs: FrameObservations, frame: Frame | None, intrinsics: CameraIntrinsics
) -> None:
    """DATASET/overlay/NNNNNN.png for one frame (black where the image could not be read)."""
    rgb = frame.rgb if frame is not None else np.zeros((intrinsics.height, intrinsics.width, 3), np.uint8)
    write_png(out / f"{obs.frame:06d}.png", cv2.cvtColor(draw_overlay(rgb, obs), cv2.COLOR_RGB2BGR))


def detect_dataset(
    dataset: Dataset,
    settings: DetectorSettings,
    quiet: bool = False,
    on_frame: Callable[[FrameObservations, Frame | None], None] | None = None,
) -> tuple[list[FrameObservations], CornerNoise | None]:
    """Detect every frame with a progress bar (unless quiet) and learn the corner noise floor
    (settings.learn_corner_floor); nothing is written. on_frame: called after each frame. Returns
    the observations and the corner noise (None when not learned)."""
    if "depth_noise" not in dataset.metadata and any(row["depth"] for row in dataset.rows):
        print("note: dataset.json has no 'depth_noise'; using the D435 defaults", file=sys.stderr)
    with tqdm(total=len(dataset), desc="detect", unit="frame", disable=quiet, file=sys.stderr) as bar:

        def after_frame(obs: FrameObservations, frame: Frame | None) -> None:
            if on_frame is not None:
                on_frame(obs, frame)
            bar.update()

        observations = observe_dataset(dataset, settings, dataset_depth_noise(dataset), progress=after_frame)
    return learn_corner_floor(observations, dataset.board, dataset.intrinsics, settings)


def detect_and_cache(
    dataset: Dataset,
    settings: DetectorSettings,
    quiet: bool = False,
    on_frame: Callable[[FrameObservations, Frame | None], None] | None = None,
    must_cache: bool = True,
) -> tuple[list[FrameObservations], Path | None, CornerNoise | None]:
    """detect_dataset, then write DATASET/detections.json. Returns the observations, the cache path
    and the corner noise (None when not learned); without must_cache, a cache that cannot be
    written (a read-only dataset) is a note and None."""
    observations, noise = detect_dataset(dataset, settings, quiet, on_frame)
    block = None if noise is None else noise.to_dict()
    try:
        return (
            observations,
            save_observations(dataset.root, observations, settings, dataset_depth_noise(dataset), block),
            noise,
        )
    except OSError as exc:
        if must_cache:
            raise
        print(f"note: cannot write {dataset.root / CACHE_FILE} ({exc.strerror}): not cached", file=sys.stderr)
        return observations, None, noise


def cached_or_detected(dataset: Dataset, quiet: bool = False) -> tuple[list[FrameObservations], str]:
    """The observations in DATASET/detections.json if it is valid for this dataset (made with any
    detector settings), else detected now with the default settings and cached like `hec detect`.
    Returns them and where they came from, in words."""
    try:
        observations, _, _ = load_observations(dataset.root)
        return observations, f"from {dataset.root / CACHE_FILE}"
    except ObservationCacheError as exc:
        reason = "no detections cache" if not (dataset.root / CACHE_FILE).exists() else str(exc)
    print(f"note: {reason}; detecting the board in {len(dataset)} frames", file=sys.stderr)
    observations, cache, noise = detect_and_cache(dataset, DetectorSettings(), quiet, must_cache=False)
    if noise is not None:
        print(f"note: {noise.describe()}", file=sys.stderr)
    return observations, f"detected now, cached in {cache}" if cache else "detected now, not cached"


def overlay_writer(dataset: Dataset) -> Callable[[FrameObservations, Frame | None], None]:
    """A detect_and_cache on_frame that draws each frame's overlay into DATASET/overlay/."""
    overlay_dir = dataset.root / OVERLAY_DIR
    overlay_dir.mkdir(exist_ok=True)

    def write_overlay(obs: FrameObservations, frame: Frame | None) -> None:
        _write_overlay(overlay_dir, obs, frame, dataset.intrinsics)

    return write_overlay


def run_detect(
    dataset_path: Path, overlay: bool = False, passes: tuple[str, ...] = DEFAULT_PASSES, quiet: bool = False
) -> list[FrameObservations]:
    """Detect every frame, write DATASET/detections.json (and overlays), print the per-frame table.
    A dataset of imported pose pairs has no images: ValueError, its pairs are its observations."""
    dataset = load_dataset(dataset_path)
    if dataset.metadata.get("pose_pairs_file"):
        raise ValueError(
            f"{dataset.root} holds imported pose pairs ({dataset.metadata['pose_pairs_file']}) and no "
            "images: there is nothing to detect; `hec calibrate` uses the pairs as they are"
        )
    settings = DetectorSettings(passes=passes)
    overlay_dir = dataset.root / OVERLAY_DIR
    start = time.perf_counter()
    observations, cache, noise = detect_and_cache(
        dataset, settings, quiet, overlay_writer(dataset) if overlay else None
    )
    elapsed = time.perf_counter() - start
    board_ids = dataset.board.marker_ids
    print("frame found   missing corner_sd depth_sd  passes           notes")
    print("                       [px]      [mm]")
    for obs in observations:
        print(_frame_row(obs, board_ids))
    markers = sum(len(o.markers) for o in observations)
    skipped = sum(o.problem is not None for o in observations)
    print(
        f"{len(observations)} frames ({skipped} skipped), {markers} markers, "
        f"{sum(len(o.rejected) for o in observations)} rejected; "
        f"{1000 * elapsed / max(len(observations), 1):.1f} ms per frame with image loading"
        + (" and overlays" if overlay else "")
    )
    if noise is not None:
        print(noise.describe())
    print(f"observations: {cache}")
    if overlay:
        print(f"overlays: {overlay_dir}/")
    if dataset.ground_truth is not None:
        s = grade_observations(
            observations, dataset.ground_truth, dataset.board, dataset.intrinsics
        ).summary()
        print(
            f"vs ground truth: {s['detected_visible']}/{s['visible_markers']} fully visible markers detected"
            f" ({s['wrong_id']} with a wrong ID); corner RMS {s['corner_rms_px']:.4f} px"
            f" (decoders {s['raw_corner_rms_px']:.3f} px); marker-centre 3D RMS {s['center_rms_mm']:.4f} mm;"
            f" normalised errors (1 = honest): corners {nees_text(s['corner_nees'])},"
            f" centre 3D {nees_text(s['center_point_nees'])}, all 3D points {nees_text(s['point_nees'])}"
            + nees_note(s["corner_nees"], max(s["center_point_nees"], s["point_nees"]))
        )
    return observations


# A normalised error above this says the errors are larger than the covariance the detector gives.
NEES_EXPLAINED = 3.0


def nees_text(value: float) -> str:
    """A normalised error: two decimals, or three significant digits when large."""
    return f"{value:.2f}" if value < 100 else f"{value:.3g}"


def nees_note(corner_nees: float, point_nees: float) -> str:
    """Why normalised errors above NEES_EXPLAINED are what they are ('' when none is)."""
    notes = []
    if corner_nees > NEES_EXPLAINED:
        notes.append(
            "the corners miss by more than their covariance says (a lens or print error the detector's "
            "noise model leaves out)"
        )
    if point_nees > NEES_EXPLAINED:
        notes.append(
            "the 3D points miss by more than their covariance says (a depth bias, scale or offset, that "
            "the per-pixel depth noise leaves out)"
        )
    if not notes:
        return ""
    return (
        " (above 3: " + "; ".join(notes) + "; hec calibrate learns the noise and self-calibrates such errors)"
    )
