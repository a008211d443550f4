"""How to open the RealSense and what goes wrong with it, without librealsense itself: cell files and
sessions read these on machines that have no camera library (the extra hec[realsense])."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

MAX_BURST = 255  # the per-pixel sample count is kept as uint8
FILTERS = ("spatial", "temporal", "hole_filling")


class CameraError(RuntimeError):
    """The camera cannot be opened or stopped delivering; the message says what to check."""


@dataclass(frozen=True)
class RealSenseSettings:
    """How to open the camera and capture.

    serial: the device's serial number, or None for the first one found.
    colour_size, depth_size: (width, height) in pixels; fps: frames per second.
    burst: frames averaged per capture; warmup_frames: frames dropped after start
    while auto-exposure settles. timeout_s: longest wait for one frame.
    filters: librealsense post-processing filters applied to depth before alignment,
    any of FILTERS, in that order. depth_units_m: the depth step to set on the camera
    (None: leave it; a D435 defaults to 1 mm, 0.1 mm limits its range to 6.5 m).
    recording: play back this .db3/.bag file instead
    of a live camera. record_to: also record the raw streams to this .db3 file.
    """

    serial: str | None = None
    colour_size: tuple[int, int] = (1280, 720)
    depth_size: tuple[int, int] = (848, 480)
    fps: int = 30
    burst: int = 10
    warmup_frames: int = 30
    timeout_s: float = 5.0
    filters: tuple[str, ...] = ()
    depth_units_m: float | None = 1e-4
    recording: Path | None = None
    record_to: Path | None = None

    def __post_init__(self) -> None:
        unknown = [f for f in self.filters if f not in FILTERS]
        if unknown:
            raise ValueError(f"unknown depth filters {unknown}; choose from {list(FILTERS)}")
        if not 1 <= self.burst <= MAX_BURST:
            raise ValueError(f"burst must be 1..{MAX_BURST} frames, got {self.burst}")
        if self.warmup_frames < 0 or self.timeout_s <= 0 or self.fps <= 0:
            raise ValueError("warmup_frames must be >= 0, timeout_s and fps > 0")
        if self.depth_units_m is not None and not 0 < self.depth_units_m <= 0.01:
            raise ValueError(f"depth_units_m must be in (0, 0.01] metres, got {self.depth_units_m}")
        if self.recording is not None and self.record_to is not None:
            raise ValueError("play back a recording or record, not both")
        if self.recording is not None and Path(self.recording).suffix not in (".db3", ".bag"):
            raise ValueError(f"{self.recording}: a recording is a .db3 (or legacy .bag) file")
        if self.record_to is not None and Path(self.record_to).suffix != ".db3":
            raise ValueError(f"{self.record_to}: librealsense records to .db3 files")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["recording"] = str(self.recording) if self.recording else None
        d["record_to"] = str(self.record_to) if self.record_to else None
        return d
