"""The far-off sweep: error_scale multiplies every systematic error of the cell (and nothing
else), its cells with one error source at several scales give no error budget, and its page
counts how often seed-ekf warned when it was off."""

from __future__ import annotations

import numpy as np
import pytest

from hec.estimator.common.models import models_dir
from hec.sim.scenario import load_scenario
from hec.sweep.budget import has_budget
from hec.sweep.config import SweepConfigError, cell_scenario, load_config, scenario_defaults
from hec.sweep.page import warning_rows
from hec.sweep.summary import CellSummary

REALISTIC = models_dir() / "scenarios" / "realistic.toml"


def _cell(factor: float, sources: str = "all"):
    base = load_scenario(REALISTIC)
    params = {**scenario_defaults(base), "error_sources": sources, "error_scale": factor}
    return base, cell_scenario(base.to_dict(), str(REALISTIC.parent), params)


def test_error_scale_multiplies_every_systematic_error_and_nothing_else() -> None:
    base, scenario = _cell(3.0)
    e, b = scenario.errors, base.errors
    assert e.arm.joint_offset_sigma_deg == pytest.approx(3 * b.arm.joint_offset_sigma_deg)
    assert e.arm.link_length_sigma_m == pytest.approx(3 * b.arm.link_length_sigma_m)
    assert e.arm.twist_sigma_deg == pytest.approx(3 * b.arm.twist_sigma_deg)
    assert e.arm.encoder_sigma_deg == b.arm.encoder_sigma_deg  # per-frame noise, not an error
    assert e.intrinsics.focal_sigma_fraction == pytest.approx(3 * b.intrinsics.focal_sigma_fraction)
    assert e.intrinsics.principal_point_sigma_px == pytest.approx(3 * b.intrinsics.principal_point_sigma_px)
    np.testing.assert_allclose(e.lens.true_coefficients, 3 * np.asarray(b.lens.true_coefficients))
    assert e.lens.reported_coefficients == b.lens.reported_coefficients
    assert e.depth.registration_rotation_sigma_deg == pytest.approx(
        3 * b.depth.registration_rotation_sigma_deg
    )
    assert e.depth.correlation_px == b.depth.correlation_px
    np.testing.assert_allclose(e.board.scale_error, 3 * np.asarray(b.board.scale_error))
    np.testing.assert_allclose(e.board.bend_m, 3 * np.asarray(b.board.bend_m))
    assert e.image == b.image
    bias = scenario.noise.depth_bias
    assert bias.scale == pytest.approx(1 + 3 * (base.noise.depth_bias.scale - 1))
    assert bias.offset_m == pytest.approx(3 * base.noise.depth_bias.offset_m)
    # Scale 1 is the preset itself; the switches stay the cell's.
    assert _cell(1.0)[1].errors == base.errors
    _, arm_only = _cell(2.0, "arm")
    assert arm_only.errors.arm.enabled and not arm_only.errors.lens.enabled


def test_the_far_off_sweep_has_its_cells_and_rejects_a_negative_scale(tmp_path) -> None:
    config = load_config(models_dir() / "sweeps" / "far_off.toml")
    cells = [(c.parameters["error_sources"], c.parameters["error_scale"]) for c in config.cells]
    assert cells == [
        ("none", 1.0),
        ("all", 1.0),
        ("all", 2.0),
        ("all", 3.0),
        ("arm", 2.0),
        ("depth", 2.0),
        ("depth", 1.0),
    ]
    assert config.paired and config.trials >= 30 and {"ekf", "seed-ekf", "opencv-park"} <= set(config.methods)
    path = tmp_path / "bad.toml"
    path.write_text('fidelity = "render"\n[fixed]\nerror_scale = -1.0\n')
    with pytest.raises(SweepConfigError, match="error_scale"):
        load_config(path)


def _summary(cell: str, source: str) -> CellSummary:
    return CellSummary(cell, "ekf", "render", {"error_sources": source}, 1, 1, None, None, 0, 6.0, 0.1)


def test_several_cells_of_one_source_are_no_error_budget() -> None:
    assert has_budget([_summary("c00", "none"), _summary("c01", "arm")])
    assert not has_budget([_summary("c00", "none"), _summary("c01", "all"), _summary("c02", "all")])


def test_the_page_counts_seed_ekf_trials_off_beyond_their_uncertainty_and_their_warnings() -> None:
    def row(cell: str, nees: float, warnings: float, status: str = "ok") -> dict:
        return {"cell": cell, "method": "seed-ekf", "status": status, "nees": nees, "warnings": warnings}

    rows = [row("c00", 5.0, 0.0), row("c00", 30.0, 1.0), row("c00", 40.0, 0.0), row("c01", 3.0, 0.0)]
    rows += [row("c01", 90.0, 2.0, "failed"), {**row("c01", 50.0, 0.0), "method": "ekf"}]
    assert warning_rows(rows, "seed-ekf", 20.0) == [["c00", "3", "2", "1"], ["c01", "1", "0", "0"]]
