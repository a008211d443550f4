"""Debug picture of one frame's detections: what was found, in which order, and what was not.

Drawn at twice the image size so labels stay legible: accepted markers in
green with their ID, corners numbered 0-3 (0 = the symbol's top-left, drawn
larger), the centre, and the depth there with its 1-sigma; rejected
candidates in red with the reason; frame problems and notes across the top.
"""

from __future__ import annotations

import textwrap

import cv2
import numpy as np

from hec.estimator.observe.observations import FrameObservations

SCALE = 2
_GREEN = (40, 200, 40)
_RED = (230, 40, 40)
_YELLOW = (250, 220, 0)
_WHITE = (255, 255, 255)
_CORNER_COLOURS = [(255, 60, 60), (255, 170, 0), (60, 160, 255), (200, 80, 255)]
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _pt(uv: np.ndarray) -> tuple[int, int]:
    """Pixel (centre-of-pixel convention) to a drawing point at SCALE."""
    return int(round((uv[0] + 0.5) * SCALE - 0.5)), int(round((uv[1] + 0.5) * SCALE - 0.5))


def _text(
    img: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int], size: float = 0.5
) -> None:
    cv2.putText(img, text, org, _FONT, size, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, _FONT, size, colour, 1, cv2.LINE_AA)


def draw_overlay(rgb: np.ndarray, observations: FrameObservations) -> np.ndarray:
    """(2H, 2W, 3) uint8 RGB picture of the detections drawn over the (H, W, 3) RGB frame."""
    base = np.asarray(rgb)
    if base.ndim == 2:
        base = np.repeat(base[:, :, None], 3, axis=2)
    img = cv2.resize(base, None, fx=SCALE, fy=SCALE, interpolation=cv2.INTER_NEAREST)
    img = np.ascontiguousarray(img)
    for rejection in observations.rejected:
        if rejection.corners_px is None:
            continue
        polygon = np.array([_pt(c) for c in rejection.corners_px], dtype=np.int32)
        cv2.polylines(img, [polygon], True, _RED, 2, cv2.LINE_AA)
        lines = textwrap.wrap(rejection.reason, 40)
        x, y = polygon[:, 0].min(), polygon[:, 1].max() + 16
        for k, line in enumerate(lines[:3]):
            _text(img, line, (int(x), int(y + 16 * k)), _RED, 0.45)
    for marker in observations.markers:
        polygon = np.array([_pt(c) for c in marker.corners_px], dtype=np.int32)
        cv2.polylines(img, [polygon], True, _GREEN, 1, cv2.LINE_AA)
        for k, corner in enumerate(marker.corners_px):
            cv2.circle(img, _pt(corner), 7 if k == 0 else 4, _CORNER_COLOURS[k], 2, cv2.LINE_AA)
            _text(img, str(k), (_pt(corner)[0] + 6, _pt(corner)[1] - 6), _CORNER_COLOURS[k], 0.5)
        c = _pt(marker.center_px)
        cv2.drawMarker(img, c, _YELLOW, cv2.MARKER_CROSS, 14, 2)
        _text(img, f"ID {marker.marker_id}", (c[0] + 8, c[1] - 8), _WHITE, 0.6)
        if marker.depth_m is not None:
            sigma_mm = 1000.0 * np.sqrt(marker.depth_cov[0, 0])
            label = f"z {1000.0 * marker.depth_m[0]:.1f}+-{sigma_mm:.2f} mm"
        else:
            label = f"no depth: {marker.depth_note}"[:48]
        _text(img, label, (c[0] + 8, c[1] + 16), _YELLOW, 0.45)
    header = [f"frame {observations.frame}: {len(observations.markers)} markers"]
    if observations.problem:
        header.append(f"SKIPPED: {observations.problem}")
    header += [f"note: {n}" for n in observations.notes]
    y = 22
    for line in header:
        for part in textwrap.wrap(line, 90):
            _text(img, part, (8, y), _RED if line.startswith(("SKIPPED", "note")) else _WHITE, 0.6)
            y += 22
    return img
