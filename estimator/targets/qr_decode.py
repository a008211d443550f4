"""QR decoding back-ends behind one function: payload and four rough corners per symbol.

Back-ends: ``zxing`` (zxing-cpp, the default and the fastest), ``pyzbar``
(the paper's choice) and ``opencv`` (cv2.QRCodeDetector, slow, optional).
Each can run on the image upscaled by an integer factor, which helps small
codes. Corners come back in the library's own order (zxing: the symbol's
top-left, top-right, bottom-right, bottom-left; pyzbar: any start and either
winding); hec.estimator.targets.qr_fit puts them in the marker's order. Pixel
coordinates follow hec.estimator.geometry.camera (origin at the centre of the top-left
pixel). zxing also reports the symbol's version, error-correction level and mask
(the others do not: those fields stay None).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import zxingcpp
from pyzbar import pyzbar

BACKENDS = ("zxing", "pyzbar", "opencv")


@dataclass(frozen=True)
class DecodedSymbol:
    """One decoded QR symbol: its text, (4, 2) corners in pixels (library order), who found it,
    and the version, error-correction level and mask it was printed with (None: not reported)."""

    payload: str
    corners_px: np.ndarray
    backend: str
    scale: int
    version: int | None = None
    error_correction: str | None = None
    mask: int | None = None

    @property
    def center_px(self) -> np.ndarray:
        return self.corners_px.mean(axis=0)

    @property
    def side_px(self) -> float:
        """Mean length of the four sides, pixels."""
        return float(np.linalg.norm(self.corners_px - np.roll(self.corners_px, 1, axis=0), axis=1).mean())


# What a back-end returns per symbol: payload, (4, 2) corners, and the symbol fields it read.
_Found = tuple[str, np.ndarray, dict]


def _zxing(gray: np.ndarray) -> list[_Found]:
    found = []
    for code in zxingcpp.read_barcodes(
        gray, formats=zxingcpp.BarcodeFormat.QRCode, try_rotate=False, try_invert=False, try_downscale=False
    ):
        if not code.valid:
            continue
        p = code.position
        corners = [p.top_left, p.top_right, p.bottom_right, p.bottom_left]
        extra = getattr(code, "extra", None) or {}  # older zxing-cpp releases have no extra
        read = {
            "version": int(extra["Version"]) if str(extra.get("Version", "")).isdigit() else None,
            "error_correction": extra.get("ECLevel")
            if extra.get("ECLevel") in ("L", "M", "Q", "H")
            else None,
            "mask": extra.get("DataMask") if isinstance(extra.get("DataMask"), int) else None,
        }
        found.append((code.text, np.array([[c.x, c.y] for c in corners], dtype=np.float64), read))
    return found


def _pyzbar(gray: np.ndarray) -> list[_Found]:
    found = []
    for code in pyzbar.decode(gray, symbols=[pyzbar.ZBarSymbol.QRCODE]):
        if len(code.polygon) != 4:
            continue
        try:
            text = code.data.decode("utf-8")
        except UnicodeDecodeError:
            text = code.data.decode("latin-1")
        found.append((text, np.array([[p.x, p.y] for p in code.polygon], dtype=np.float64), {}))
    return found


_OPENCV_DETECTOR: cv2.QRCodeDetector | None = None


def _opencv(gray: np.ndarray) -> list[_Found]:
    global _OPENCV_DETECTOR
    if _OPENCV_DETECTOR is None:
        _OPENCV_DETECTOR = cv2.QRCodeDetector()
    ok, texts, points, _ = _OPENCV_DETECTOR.detectAndDecodeMulti(gray)
    if not ok or points is None:
        return []
    return [(t, p.reshape(4, 2).astype(np.float64), {}) for t, p in zip(texts, points, strict=True) if t]


_DECODERS = {"zxing": _zxing, "pyzbar": _pyzbar, "opencv": _opencv}


def decode_qr(gray: np.ndarray, backend: str, scale: int = 1) -> list[DecodedSymbol]:
    """Decode every QR symbol in a grey image.

    gray: (H, W) uint8. backend: one of BACKENDS. scale: integer upscaling (linear
    interpolation) applied before decoding; corners are mapped back to the input's pixels.
    Returns the symbols in the order the library reports them.
    """
    if backend not in _DECODERS:
        raise ValueError(f"unknown QR back-end {backend!r}; choose from {', '.join(BACKENDS)}")
    if scale < 1:
        raise ValueError(f"scale must be an integer >= 1, got {scale}")
    image = gray if scale == 1 else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    symbols = []
    for text, corners, read in _DECODERS[backend](np.ascontiguousarray(image)):
        # Pixel centres: input pixel i spans upscaled pixels [i*scale, (i+1)*scale).
        corners_px = (corners + 0.5) / scale - 0.5
        symbols.append(DecodedSymbol(text, corners_px, backend, scale, **read))
    return symbols
