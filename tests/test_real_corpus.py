"""Real eye-in-hand sets (tests/data/real/<set>/, each with its SOURCE.md and LICENSE) imported with
`hec import folder` and calibrated with `hec calibrate`: the figures measured when each set was added
must come back, and hec's default method must predict held-out frames about as well as the best OpenCV
method on the same corners.

Everything here is deterministic (the same images, the same detector, no random draws): repeated runs
of import and calibrate gave bit-identical translations and leave-one-frame-out figures, so the
tolerance only has to absorb floating-point differences between machines and library builds.
TOLERANCE_MM is 0.01 mm, under a twentieth of the smallest 1-sigma hec reports on these sets (0.22 mm),
so any change that means something (a corner found or lost, another outlier gate, another noise level)
fails and has to be looked at and the figures re-recorded.

The leave-one-frame-out comparison uses the millimetres in the base frame (the pick error at the
board's distance, `leave_one_frame_out.rms_mm`). hec's ekf must be within LOO_FACTOR of the best
OpenCV method's (the OpenCV method with the smallest figure when the set was added). On two sets hec
is better (ical_charuco_eye_to_hand 0.20x, ur_xtion_chessboard 0.95x); on franka_d435_charuco, whose
arm poses disagree with its images by about 5.5 px, hec loses: 4.13 mm against OpenCV Tsai's 3.89
(1.06x). LOO_FACTOR 1.1 lets that stand and catches anything worse.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from tests.hec_cli import run_hec

REAL = Path(__file__).parent / "data" / "real"
TOLERANCE_MM = 0.01
LOO_FACTOR = 1.1


@dataclass(frozen=True)
class Figures:
    """What one method gave on a set: T_flange_cam's translation (mm), the observations it used and
    its leave-one-frame-out prediction error in the base frame (mm)."""

    translation_mm: tuple[float, float, float]
    observations_used: int
    loo_mm: float


@dataclass(frozen=True)
class RealSet:
    name: str
    import_options: tuple[str, ...]
    frames_used: int
    ekf: Figures
    opencv_method: str
    opencv: Figures


SETS = [
    # A fixed camera and the board on a KUKA arm, read as eye-in-hand by inverting the poses: hec's
    # T_flange_cam is then T_base_cam (SOURCE.md). Frame 2 has no board marker hec finds.
    RealSet(
        "ical_charuco_eye_to_hand",
        ("--pose-direction", "flange-to-base", "--intrinsics", "camera.yaml"),
        15,
        Figures((-19.3142, 1265.8261, 289.1748), 206, 1.5354),
        "opencv-shah",
        Figures((-27.9248, 1264.1640, 283.5146), 207, 7.7856),
    ),
    RealSet(
        "ur_xtion_chessboard",
        ("--rotation", "rotvec", "--intrinsics", "camera.yml"),
        18,
        Figures((-88.9793, 24.3354, 14.5226), 764, 0.5602),
        "opencv-shah",
        Figures((-88.8487, 24.4344, 14.2422), 775, 0.5874),
    ),
    RealSet(
        "franka_d435_charuco",
        ("--rotation", "matrix", "--intrinsics", "camera.yaml"),
        12,
        Figures((48.7147, 10.0168, -39.2965), 264, 4.1284),
        "opencv-tsai",
        Figures((48.7873, 8.4941, -38.8509), 264, 3.8919),
    ),
]


def _import(real_set: RealSet, out: Path) -> str:
    """`hec import folder` of the set into out; returns what it printed."""
    folder = REAL / real_set.name
    options = [o if not o.endswith((".yaml", ".yml")) else str(folder / o) for o in real_set.import_options]
    code, stdout, stderr = run_hec(
        ["import", "folder", str(folder / "images"), "--poses", str(folder / "poses.csv"), *options,
         "--board", str(folder / "board.json"), "--out", str(out), "--quiet"]
    )  # fmt: skip
    assert code == 0, stderr
    return stdout + stderr


def _calibrate(dataset: Path, method: str) -> dict:
    out = dataset.parent / f"{method}.json"
    code, _, stderr = run_hec(["calibrate", str(dataset), "--method", method, "--json", str(out), "--quiet"])
    assert code == 0, stderr
    return json.loads(out.read_text())


def _check(result: dict, expected: Figures, frames_used: int) -> None:
    method = result["method"]
    assert result["frames_used"] == frames_used, method
    assert result["observations_used"] == expected.observations_used, method
    np.testing.assert_allclose(
        result["translation_mm"], expected.translation_mm, atol=TOLERANCE_MM, err_msg=method
    )
    assert result["leave_one_frame_out"]["rms_mm"] == pytest.approx(expected.loo_mm, abs=TOLERANCE_MM), method


@pytest.mark.parametrize("real_set", SETS, ids=lambda s: s.name)
def test_a_real_set_imports_and_calibrates_to_the_recorded_figures(real_set: RealSet, tmp_path: Path) -> None:
    printed = _import(real_set, tmp_path / "ds")
    assert "the robot poses fit the stated convention" in printed
    assert "none of the common mistakes fits better" in printed

    ekf = _calibrate(tmp_path / "ds", "ekf")
    opencv = _calibrate(tmp_path / "ds", real_set.opencv_method)
    _check(ekf, real_set.ekf, real_set.frames_used)
    _check(opencv, real_set.opencv, real_set.frames_used)

    ratio = ekf["leave_one_frame_out"]["rms_mm"] / opencv["leave_one_frame_out"]["rms_mm"]
    assert ratio <= LOO_FACTOR, (
        f"{real_set.name}: ekf predicts held-out frames to {ratio:.2f}x {real_set.opencv_method}'s error"
    )


def test_every_real_set_has_its_source_and_licence_and_stays_small() -> None:
    folders = sorted(p for p in REAL.iterdir() if p.is_dir())
    assert [p.name for p in folders] == sorted(s.name for s in SETS)
    for folder in folders:
        source = (folder / "SOURCE.md").read_text()
        assert "Licence" in source and "Source" in source and "What was changed" in source, folder.name
        assert (folder / "LICENSE").read_text().strip(), folder.name
        size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
        assert size < 5_000_000, f"{folder.name}: {size / 1e6:.1f} MB"
        images = list((folder / "images").iterdir())
        assert len(images) >= 10, folder.name


def _table(real_set: RealSet, result: dict) -> str:
    """The markdown table of one set's `hec calibrate --method all --json` output."""
    left_out = "; ".join(result["frames_left_out"])
    lines = [
        f"### {real_set.name}",
        "",
        f"{result['frames_used']} frames used" + (f"; left out: {left_out}" if left_out else "") + ".",
        "",
        "| method | x mm | y mm | z mm | 1-sigma mm | residual px | LOO px | LOO mm | used/rejected |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for m in result["results"]:
        if "error" in m:
            lines.append(f"| {m['method']} | failed: {m['error'].split(' (')[0]} | | | | | | | |")
            continue
        t, loo, sigma = m["translation_mm"], m["leave_one_frame_out"], m["sigma_translation_mm"]
        rss = f"{np.linalg.norm(sigma):.3f}" if sigma else "-"
        loo_cells = f"{loo['rms_px']:.3f} | {loo['rms_mm']:.3f}" if loo else "not run | not run"
        lines.append(
            f"| {m['method']} | {t[0]:.3f} | {t[1]:.3f} | {t[2]:.3f} | {rss} | {m['residual_rms_px']:.3f} | "
            f"{loo_cells} | {m['observations_used']}/{m['observations_rejected']} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    # python -m tests.test_real_corpus: import every set and print `hec calibrate --method all` as the
    # tables of tests/data/real/README.md.
    import tempfile

    with tempfile.TemporaryDirectory() as temporary:
        for real_set in SETS:
            dataset = Path(temporary) / real_set.name
            _import(real_set, dataset)
            print(_table(real_set, _calibrate(dataset, "all")))
