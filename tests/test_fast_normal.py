"""The quantised Gaussian of hec.sim.fast_normal: unit variance, Gaussian shape and tails, determinism,
and the SplitMix64 levels under it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr
from scipy.stats import chisquare

from hec.sim.fast_normal import LEVELS, normal_table, quantised_normal, splitmix64, uniform_levels


def test_table_is_symmetric_increasing_with_unit_variance() -> None:
    t = normal_table().astype(np.float64)
    assert t.shape == (LEVELS,) and normal_table().dtype == np.float32
    assert np.all(np.diff(t) > 0.0)
    assert np.allclose(t, -t[::-1], atol=1e-6)
    assert np.mean(t * t) == pytest.approx(1.0, abs=1e-6)
    assert 4.3 < t[-1] < 4.35  # truncated at the last cell midpoint


def test_scale_multiplies_the_table() -> None:
    assert np.allclose(normal_table(2.5), 2.5 * normal_table(), rtol=1e-6)


def test_draws_are_standard_normal_with_gaussian_tails() -> None:
    x = quantised_normal(np.random.default_rng(3), (1000, 1000)).astype(np.float64)
    assert abs(x.mean()) < 0.005
    assert x.std() == pytest.approx(1.0, abs=0.003)
    assert np.mean(x**4) == pytest.approx(3.0, abs=0.05)  # kurtosis of a Gaussian
    for k in (1.0, 2.0, 3.0, 4.0):
        expected = 2.0 * ndtr(-k)
        assert np.mean(np.abs(x) > k) == pytest.approx(expected, rel=0.1, abs=2e-5)


def test_same_generator_state_same_draws_and_shape_dtype() -> None:
    a = quantised_normal(np.random.default_rng(7), (4, 5, 3), 2.0)
    b = quantised_normal(np.random.default_rng(7), (4, 5, 3), 2.0)
    assert a.shape == (4, 5, 3) and a.dtype == np.float32
    assert np.array_equal(a, b)
    assert not np.array_equal(a, quantised_normal(np.random.default_rng(8), (4, 5, 3), 2.0))


def test_splitmix64_gives_the_published_outputs() -> None:
    # The reference sequence of SplitMix64 from state 1234567 (as Vigna's splitmix64.c produces it).
    expected = [6457827717110365317, 3203168211198807973, 9817491932198370423]
    assert splitmix64(np.uint64(1234567), 3).tolist() == expected


def test_levels_are_uniform_and_independent_and_cost_one_draw() -> None:
    rng = np.random.default_rng(5)
    levels = uniform_levels(rng, (1 << 22,)).astype(np.int64)
    for byte in (levels >> 8, levels & 0xFF):  # both halves of every level uniform over 256 values
        assert chisquare(np.bincount(byte, minlength=256)).pvalue > 1e-4
    z = (levels - levels.mean()) / levels.std()
    bound = 5.0 / np.sqrt(z.size)
    for lag in (1, 2, 3, 4, 640):  # neighbours within one 64-bit output (1-3), across outputs, rows
        assert abs(np.mean(z[:-lag] * z[lag:])) < bound
    after_one_draw = np.random.default_rng(5)
    after_one_draw.bit_generator.random_raw()
    assert rng.bit_generator.state == after_one_draw.bit_generator.state
