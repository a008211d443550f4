"""One printed QR symbol, exactly: its payload, version, error-correction level and mask.

Two generators given the same payload, version and error-correction level draw the
same finder, timing and format modules, but each picks its own mask (the qrcode
package scores all 8; other generators fix one), so a symbol is only regenerated
exactly when its mask is known. ``SymbolSpec`` names all four; a mask of None means
the qrcode package's automatic choice. ``read_format`` reads the level and mask
from the 15 format-information modules of a sampled symbol, which every QR symbol
carries twice beside its finder patterns.

Module matrices are (n, n) bool, True = dark, row 0 at the symbol's top, n = 17 + 4 version.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np
import qrcode
from qrcode.util import BCH_type_info

ERROR_CORRECTION = {
    "L": qrcode.constants.ERROR_CORRECT_L,
    "M": qrcode.constants.ERROR_CORRECT_M,
    "Q": qrcode.constants.ERROR_CORRECT_Q,
    "H": qrcode.constants.ERROR_CORRECT_H,
}
MASKS = range(8)
# A format reading this many bits (of 30, both copies) from the nearest valid one is not trusted.
MAX_FORMAT_BIT_ERRORS = 6


@dataclass(frozen=True)
class SymbolSpec:
    """What regenerates one printed QR symbol: payload, version (1-40), error correction
    (L, M, Q or H) and mask (0-7, None: the qrcode package's automatic choice)."""

    payload: str
    version: int
    error_correction: str
    mask: int | None = None

    @property
    def modules(self) -> int:
        """Modules along one side (21 for version 1)."""
        return 17 + 4 * self.version

    def pinned(self) -> SymbolSpec:
        """The same symbol with its mask stated (the automatic choice made explicit)."""
        return self if self.mask is not None else replace(self, mask=_automatic_mask(*self._key()))

    def matrix(self) -> np.ndarray:
        """(n, n) bool module matrix, read-only; raises ValueError if the payload does not fit."""
        pinned = self.pinned()
        return _matrix(*pinned._key(), pinned.mask)

    def mask_independent(self) -> np.ndarray:
        """(n, n) bool, True where the module is the same under every mask (finder, timing and
        alignment patterns, version information, the dark module and the few data modules all
        masks leave alike): the part of the symbol any generator draws alike."""
        return _mask_independent(*self._key())

    def describe(self) -> str:
        """'version 1-M, mask 3' (the mask as the automatic choice resolves it)."""
        return f"version {self.version}-{self.error_correction}, mask {self.pinned().mask}"

    def differences(self, printed: SymbolSpec) -> str:
        """'mask 3 printed, 5 expected' for every field where ``printed`` differs from this one."""
        expected = self.pinned()
        parts = [
            f"{name} {getattr(printed, key)} printed, {getattr(expected, key)} expected"
            for key, name in (
                ("version", "version"),
                ("error_correction", "error correction"),
                ("mask", "mask"),
            )
            if getattr(printed, key) is not None and getattr(printed, key) != getattr(expected, key)
        ]
        return ", ".join(parts)

    def _key(self) -> tuple[str, int, str]:
        return self.payload, self.version, self.error_correction


def _make(payload: str, version: int, error_correction: str, mask: int | None) -> qrcode.QRCode:
    qr = qrcode.QRCode(
        version=version, error_correction=ERROR_CORRECTION[error_correction], border=0, mask_pattern=mask
    )
    qr.add_data(payload)
    try:
        qr.make(fit=False)
    except qrcode.exceptions.DataOverflowError:
        raise ValueError(
            f"payload {payload!r} does not fit a version {version} symbol at error correction "
            f"{error_correction}"
        ) from None
    return qr


@functools.lru_cache(maxsize=1024)
def _automatic_mask(payload: str, version: int, error_correction: str) -> int:
    return int(_make(payload, version, error_correction, None).best_mask_pattern())


@functools.lru_cache(maxsize=2048)
def _matrix(payload: str, version: int, error_correction: str, mask: int) -> np.ndarray:
    """Cached: encoding costs milliseconds."""
    modules = np.array(_make(payload, version, error_correction, mask).get_matrix(), dtype=bool)
    modules.flags.writeable = False
    return modules


@functools.lru_cache(maxsize=256)
def _mask_independent(payload: str, version: int, error_correction: str) -> np.ndarray:
    stack = np.stack([_matrix(payload, version, error_correction, m) for m in MASKS])
    same = np.all(stack == stack[0], axis=0)
    same.flags.writeable = False
    return same


def _format_positions(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(15, 2) (row, col) of format bit i, bit 0 first, for the copy beside the top-left finder's
    column and the one along its row (split between the top-left and top-right finders)."""
    vertical = [(i if i < 6 else i + 1 if i < 8 else n - 15 + i, 8) for i in range(15)]
    horizontal = [(8, n - i - 1 if i < 8 else 15 - i if i == 8 else 15 - i - 1) for i in range(15)]
    return np.array(vertical), np.array(horizontal)


def _format_bits(error_correction: str, mask: int) -> np.ndarray:
    code = BCH_type_info((ERROR_CORRECTION[error_correction] << 3) | mask)
    return np.array([(code >> i) & 1 for i in range(15)], dtype=bool)


def read_format(dark: np.ndarray) -> tuple[str, int, int] | None:
    """The error-correction level and mask a sampled symbol's format modules carry, and how
    many of their 30 bits differ from that format word.

    dark: (n, n) bool module states as read from the image. Both copies are compared with
    all 32 valid format words; the nearest wins unless more than MAX_FORMAT_BIT_ERRORS of
    the 30 bits differ (then None: the format cannot be read).
    """
    vertical, horizontal = _format_positions(dark.shape[0])
    read = np.concatenate([dark[vertical[:, 0], vertical[:, 1]], dark[horizontal[:, 0], horizontal[:, 1]]])
    best, best_errors = None, MAX_FORMAT_BIT_ERRORS + 1
    for level in ERROR_CORRECTION:
        for mask in MASKS:
            errors = int(np.count_nonzero(read != np.tile(_format_bits(level, mask), 2)))
            if errors < best_errors:
                best, best_errors = (level, mask, errors), errors
    return best
