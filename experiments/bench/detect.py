"""Benchmark of the measurement layer on rendered trajectories.

Reports, per decoding pass alone and for the detector's combined passes: the
share of fully visible markers decoded with the right ID; raw and refined
corner error against ground truth; normalised errors; detection-plus-refinement
time per 640x480 frame; and the error floors on noise-free renders that
hec.estimator.targets.qr_fit's DEFAULT_*_FLOOR_PX hold.

    .venv/bin/python -m hec.bench.detect [--seed N]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import hec.sim as sim  # noqa: F401  (selects the GL backend before mujoco loads)
from hec.estimator.geometry.camera import project_points
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.grading import grade_observations, true_T_cam_board
from hec.estimator.observe.observations import dataset_depth_noise, observe_frame
from hec.estimator.targets.detection import to_gray
from hec.estimator.targets.kinds import detector_for
from hec.estimator.targets.qr import DetectorSettings
from hec.estimator.targets.qr_decode import decode_qr
from hec.sim.scenario import load_scenario, scenario_from_dict
from hec.sim.simulate import simulate

SINGLE_PASSES = ("zxing@1", "zxing@2", "pyzbar@1", "pyzbar@2", "opencv@1", "opencv@2")


def _render(kind: str, seed: int, out: Path, noise_free_rgb: bool = False) -> Dataset:
    overrides: dict = {"trajectory": {"kind": kind}}
    if noise_free_rgb:
        overrides["noise"] = {"rgb": {"enabled": False}}
    scenario = scenario_from_dict(overrides, source=f"bench {kind}") if overrides else load_scenario(None)
    return load_dataset(
        simulate(scenario, out / f"{kind}-{seed}-{noise_free_rgb}", seed, progress=False).out_dir
    )


def _true_corners(dataset: Dataset, i: int) -> dict[int, np.ndarray]:
    T_cam_board = true_T_cam_board(dataset.ground_truth, i)
    return {
        m: project_points(T_cam_board, dataset.board.marker_corners(m), dataset.intrinsics.K)
        for m in dataset.board.marker_ids
    }


def _decode_rate(dataset: Dataset, spec: str, grays: list[np.ndarray]) -> tuple[float, float]:
    """Share of markers decoded with the right ID at the right place by one pass, and ms per frame."""
    backend, _, scale = spec.partition("@")
    found = total = 0
    seconds = []
    for i, gray in enumerate(grays):
        truth = _true_corners(dataset, i)
        start = time.perf_counter()
        symbols = decode_qr(gray, backend, int(scale))
        seconds.append(time.perf_counter() - start)
        right = set()
        for s in symbols:
            marker_id = dataset.board.marker_id_from_payload(s.payload)
            if marker_id is not None and np.linalg.norm(s.center_px - truth[marker_id].mean(axis=0)) < 5.0:
                right.add(marker_id)
        found += len(right)
        total += len(truth)
    return found / total, 1000.0 * float(np.median(seconds))


def _combined(dataset: Dataset) -> dict:
    detector = detector_for(dataset.board)
    noise = dataset_depth_noise(dataset)
    detect_ms, observe_ms, observations = [], [], []
    for i in range(len(dataset)):
        frame = dataset.frame(i)
        start = time.perf_counter()
        detector.detect(frame.rgb)
        detect_ms.append(1000.0 * (time.perf_counter() - start))
        start = time.perf_counter()
        observations.append(observe_frame(i, frame, detector, noise))
        observe_ms.append(1000.0 * (time.perf_counter() - start))
    summary = grade_observations(
        observations, dataset.ground_truth, dataset.board, dataset.intrinsics
    ).summary()
    summary["detect_ms_median"] = float(np.median(detect_ms))
    summary["detect_ms_p90"] = float(np.percentile(detect_ms, 90))
    summary["observe_ms_median"] = float(np.median(observe_ms))
    return summary


def _floors(dataset: Dataset) -> tuple[float, float]:
    """RMS per coordinate of refined corners and centres on noise-free renders (image noise ~0)."""
    detector = detector_for(dataset.board)
    noise = dataset_depth_noise(dataset)
    observations = [observe_frame(i, dataset.frame(i), detector, noise) for i in range(len(dataset))]
    errors = grade_observations(observations, dataset.ground_truth, dataset.board, dataset.intrinsics)
    return (
        float(np.sqrt(np.mean(np.square(errors.corner_errors_px)))),
        float(np.sqrt(np.mean(np.square(errors.center_errors_px)))),
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for kind in ("rotation-rich", "paper"):
            dataset = _render(kind, args.seed, Path(tmp))
            grays = [to_gray(dataset.frame(i).rgb) for i in range(len(dataset))]
            print(f"\n== {kind} trajectory, default noise, seed {args.seed}: {len(dataset)} frames ==")
            print("decoding pass alone   markers decoded (right ID and place)   ms/frame")
            for spec in SINGLE_PASSES:
                rate, ms = _decode_rate(dataset, spec, grays)
                print(f"  {spec:<10} {100 * rate:27.1f} % {ms:24.1f}")
            s = _combined(dataset)
            print(
                f"detector ({','.join(DetectorSettings().passes)}, stops when all in view are found):\n"
                f"  fully visible markers detected {s['detected_visible']}/{s['visible_markers']}"
                f" ({100 * s['detection_rate']:.1f} %), wrong IDs {s['wrong_id']}\n"
                f"  corner RMS: decoders {s['raw_corner_rms_px']:.3f} px"
                f" -> refined {s['corner_rms_px']:.4f} px\n"
                f"  normalised errors (1 = honest): corners {s['corner_nees']:.2f},"
                f" centre px {s['center_px_nees']:.2f},"
                f" centre 3D {s['center_point_nees']:.2f}, all 3D points {s['point_nees']:.2f};"
                f" centre 3D RMS {s['center_rms_mm']:.4f} mm\n"
                f"  time per frame: detection + refinement median {s['detect_ms_median']:.1f} ms"
                f" (p90 {s['detect_ms_p90']:.1f}); with depth and covariances {s['observe_ms_median']:.1f} ms"
            )
        corner_floor, center_floor = _floors(_render("rotation-rich", 0, Path(tmp), noise_free_rgb=True))
        print(
            f"\nerror floors on noise-free renders (seed 0): corner {corner_floor:.4f} px,"
            f" centre {center_floor:.4f} px per coordinate"
        )


if __name__ == "__main__":
    main()
