"""The quantised Gaussian of sim.fast_normal: unit variance, Gaussian shape and tails, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from sim.fast_normal import LEVELS, normal_table, quantised_normal


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
