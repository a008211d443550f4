"""PNG files encoded in memory and written with write_atomic: a full disk is then an OSError that
names the file, and no partial image is left (cv2.imwrite would only return False)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from hec.estimator.common.files import write_atomic


def write_png(path: Path, image: np.ndarray) -> Path:
    """Write image ((H, W) or (H, W, 3) in OpenCV's BGR order, 8 or 16 bit) to path as PNG."""
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"{path}: PNG encoding failed")
    return write_atomic(path, encoded.tobytes())
