"""Benchmark of the corner noise floor learned from the data (hec.estimator.observe.corner_noise).

Renders the default (ideal) and the realistic cell (models/scenarios/realistic.toml: lens and
intrinsics undeclared, blur, lighting, a bent print with shifted markers) on the rotation-rich
trajectory for several seeds, detects every frame, and prints per dataset: the corners' RMS
error per coordinate against the true corners; the noise the markers' agreement measures
with one homography per frame through the declared lens alone, with the lens fitted too, and
with the lens and the print fitted (what the learned floor uses); the floor the covariances
then use; and the normalised errors (e^T C^-1 e / 2 per point, 1 = honest) of the corners
and the centres with the constant floor and with the learned one.

    .venv/bin/python -m hec.bench.corner_noise [--seeds 0 1 2 3]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import hec.sim as sim  # noqa: F401  (selects the GL backend before mujoco loads)
from hec.estimator.common.models import models_dir
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.corner_noise import fit_board_views, learn_corner_floor, measured_noise
from hec.estimator.observe.frames import Dataset
from hec.estimator.observe.grading import grade_observations
from hec.estimator.observe.observations import FrameObservations, observe_dataset
from hec.estimator.targets.qr import DetectorSettings
from hec.sim.scenario import load_scenario
from hec.sim.simulate import simulate

CELLS = {"default": None, "realistic": models_dir() / "scenarios" / "realistic.toml"}
# The agreement models compared, as in HEADER: (fit the lens, fit the print).
MODELS = ((False, False), (True, False), (True, True))


def _render(cell: str, seed: int, out: Path) -> Dataset:
    scenario = load_scenario(CELLS[cell])
    return load_dataset(simulate(scenario, out / f"{cell}-{seed}", seed, progress=False).out_dir)


def _grade(dataset: Dataset, observations: list[FrameObservations]) -> dict:
    return grade_observations(observations, dataset.ground_truth, dataset.board, dataset.intrinsics).summary()


def _row(cell: str, seed: int, dataset: Dataset) -> str:
    """One line of figures for one rendered dataset."""
    settings = DetectorSettings()
    constant = observe_dataset(dataset, settings)
    learned, noise = learn_corner_floor(constant, dataset.board, dataset.intrinsics, settings)
    measured = []
    for lens, printed in MODELS:
        fit = fit_board_views(constant, dataset.board, dataset.intrinsics, settings, lens, printed)
        measured.append(measured_noise(fit.residuals, fit.dof_factor))
    before, after = _grade(dataset, constant), _grade(dataset, learned)
    return (
        f"{cell:<10} {seed:4d} {before['corner_rms_px'] / np.sqrt(2.0):9.4f} "
        + " ".join(f"{m:11.4f}" for m in measured)
        + f" {noise.floor_px:9.4f} {noise.center_floor_px:9.4f}"
        f" {before['corner_nees']:9.2f} {after['corner_nees']:9.2f}"
        f" {before['center_px_nees']:9.2f} {after['center_px_nees']:9.2f}"
    )


HEADER = (
    "                     true   measured by the markers' agreement [px]       floor [px]"
    "         corner NEES         centre NEES\n"
    "cell       seed  rms [px]  homography       +lens +lens+print    corner    centre"
    "  constant   learned  constant   learned"
)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = parser.parse_args(argv)
    print(HEADER)
    with tempfile.TemporaryDirectory() as tmp:
        for cell in CELLS:
            for seed in args.seeds:
                print(_row(cell, seed, _render(cell, seed, Path(tmp))), flush=True)


if __name__ == "__main__":
    main()
