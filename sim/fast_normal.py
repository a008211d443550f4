"""Image-sized Gaussian noise fields, drawn ~8x faster than ``Generator.standard_normal``.

Each value is a 16-bit uniform integer from the ``numpy.random.Generator`` passed in (a quarter of one
of its bit generator's raw 64-bit outputs), looked up in a fixed table of the standard normal's inverse
CDF at the 65536 cell midpoints, (k + 0.5) / 65536. The result is a quantised Gaussian truncated at
+-4.32 sigma (a true Gaussian exceeds that with probability 1.5e-5), rescaled to exactly unit variance.
Fine for sensor noise that is rounded to grey levels or depth steps afterwards; not for draws where the
far tails matter.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import ndtri

LEVELS = 65536


@lru_cache(maxsize=8)
def normal_table(scale: float = 1.0) -> np.ndarray:
    """(LEVELS,) float32, increasing: scale times the unit-variance quantised standard normal."""
    t = ndtri((np.arange(LEVELS) + 0.5) / LEVELS)
    table = (scale / np.sqrt(np.mean(t * t))) * t
    table = table.astype(np.float32)
    table.flags.writeable = False
    return table


def uniform_levels(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """A uint16 array of the given shape: independent uniform indices into normal_table, four
    from each of the bit generator's raw 64-bit outputs (twice as fast as Generator.integers)."""
    count = int(np.prod(shape))
    raw = rng.bit_generator.random_raw(-(-count // 4))
    return raw.view(np.uint16)[:count].reshape(shape)


def quantised_normal(rng: np.random.Generator, shape: tuple[int, ...], scale: float = 1.0) -> np.ndarray:
    """A float32 array of the given shape: independent N(0, scale^2) draws, quantised (see module)."""
    return np.take(normal_table(float(scale)), uniform_levels(rng, shape))
