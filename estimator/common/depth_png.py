"""Depth images as 16-bit PNG values: steps of the dataset's depth scale, 0 = no depth."""

from __future__ import annotations

import numpy as np

UINT16_MAX = 65535


def encode_depth(depth_m: np.ndarray, depth_scale_m: float) -> np.ndarray:
    """Depth in metres (any shape) -> uint16 steps of depth_scale_m, round(depth / scale), as
    stored in a 16-bit PNG. 0, negative, non-finite and out-of-range (> 65535 steps) depths -> 0."""
    if not depth_scale_m > 0.0:
        raise ValueError(f"depth_scale_m must be positive, got {depth_scale_m}")
    d = np.asarray(depth_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        steps = np.rint(d / depth_scale_m)
        ok = np.isfinite(steps) & (steps > 0) & (steps <= UINT16_MAX)
    return np.where(ok, steps, 0).astype(np.uint16)


def decode_depth(depth_u16: np.ndarray, depth_scale_m: float) -> np.ndarray:
    """uint16 depth steps (any shape) -> float32 metres, value * depth_scale_m; 0 stays 0 (invalid)."""
    if not depth_scale_m > 0.0:
        raise ValueError(f"depth_scale_m must be positive, got {depth_scale_m}")
    return (np.asarray(depth_u16).astype(np.float64) * depth_scale_m).astype(np.float32)
