"""The detector of each target kind (the board files of every kind: hec.estimator.io.board_file)."""

from __future__ import annotations

from collections.abc import Callable

from hec.estimator.targets.aprilgrid import AprilGridDetector
from hec.estimator.targets.charuco import CharucoDetector
from hec.estimator.targets.chessboard import ChessboardDetector
from hec.estimator.targets.qr import DetectorSettings, QRDetector
from hec.estimator.targets.target import Target, TargetDetector

# kind -> the detector of such a board
DETECTORS: dict[str, Callable[[Target, DetectorSettings], TargetDetector]] = {
    "qr": QRDetector,
    "aprilgrid": AprilGridDetector,
    "chessboard": ChessboardDetector,
    "charuco": CharucoDetector,
}


def detector_for(board: Target, settings: DetectorSettings | None = None) -> TargetDetector:
    """The detector of the board's kind. settings: the QR passes and floors (the other kinds
    take what applies to them)."""
    return DETECTORS[board.kind](board, settings or DetectorSettings())
