"""A RealSense camera (D435/D435i, or a recording of one) as a colour + aligned depth source.

Everything goes through librealsense: the pipeline opens the device, ``rs.align``
moves depth into the colour image, the colour intrinsics and distortion come from
the stream profile and the depth scale from the depth sensor.

A capture averages the depth of a burst of frames per pixel over its valid samples
*before* alignment, puts the mean into a librealsense depth frame and aligns that
once; the valid-sample count per colour pixel comes from aligning each frame.
``rs.align`` writes the nearest of the depth pixels that land on a colour pixel
(adjacent depth pixels share colour pixels) and keeps the depth imager's axis:
aligning each noisy frame and averaging measured -0.4..-0.8 mm on a D435-like
stream at 0.45 m. So the aligned mean is only the starting point: the depth is
re-sampled where each colour pixel's point projects into the depth image and put
on the colour axis (hec.hardware.depth_burst.DepthResampler). Finer depth units (0.1 mm
by default, where the camera lets us set them) keep the mean's precision. The
images it returns feed the same detector and estimators as the simulator's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyrealsense2 as rs

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.hardware.camera_settings import CameraError, RealSenseSettings
from hec.hardware.depth_burst import DepthAverage, DepthResampler

# Timestamp domains on the host's clock (a D435 reports global_time by default).
_HOST_CLOCK_DOMAINS = (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time)
# Frame sets dropped before a burst when timestamps cannot tell old frames from new.
_STALE_FRAMESETS = 3
_CHECK_CONNECTION = "check the USB 3 cable and that `rs-enumerate-devices` lists the camera"


@dataclass
class RGBDCapture:
    """rgb: (H, W, 3) uint8, the burst's last colour image. depth_m: (H, W) float32 metres
    along the colour camera's optical axis, aligned to rgb, mean of the valid samples,
    0 = none. depth_samples: (H, W) uint8 valid samples per pixel. time_s: capture time
    of the last frame, seconds on the camera's clock (the host's for a D435)."""

    rgb: np.ndarray
    depth_m: np.ndarray
    depth_samples: np.ndarray
    time_s: float


def intrinsics_from_profile(profile: rs.video_stream_profile) -> CameraIntrinsics:
    """OpenCV intrinsics of a librealsense video stream.

    librealsense and OpenCV both put pixel (0, 0) at the centre of the top-left pixel,
    so ppx, ppy are cx, cy. Brown-Conrady coefficients are OpenCV's (k1, k2, p1, p2, k3);
    the other models are accepted only when all their coefficients are zero.
    """
    k = profile.get_intrinsics()
    coeffs = tuple(float(c) for c in k.coeffs)
    if k.model != rs.distortion.brown_conrady and any(coeffs):
        raise CameraError(
            f"the {profile.stream_name()} stream reports distortion model {k.model} with coefficients "
            f"{coeffs}; hec models only Brown-Conrady (OpenCV) distortion. Calibrate the colour "
            "intrinsics with OpenCV and use a dataset written with them."
        )
    dist = coeffs if k.model == rs.distortion.brown_conrady else (0.0,) * 5
    return CameraIntrinsics(k.width, k.height, float(k.fx), float(k.fy), float(k.ppx), float(k.ppy), dist)


def transform_from_extrinsics(extrinsics: rs.extrinsics) -> np.ndarray:
    """librealsense extrinsics 'from -> to' (rotation stored column-major) as T_to_from (4, 4)."""
    T = np.eye(4)
    T[:3, :3] = np.array(extrinsics.rotation, dtype=np.float64).reshape(3, 3).T
    T[:3, 3] = extrinsics.translation
    return T


class RealSenseCamera:
    """An open RealSense pipeline; use as a context manager.

    context: the librealsense context to find the device in (a fresh one by default;
    tests pass one that holds a software device).
    """

    def __init__(self, settings: RealSenseSettings, context: rs.context | None = None) -> None:
        self.settings = settings
        self._context = context if context is not None else rs.context()
        self._pipeline = rs.pipeline(self._context)
        config = rs.config()
        if settings.recording is not None:
            self.device_description = self._configure_playback(config)
        else:
            self.device_description = self._configure_live(config)
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as exc:
            raise CameraError(f"could not start the camera streams ({exc}); {_CHECK_CONNECTION}") from None
        self._started = True
        try:
            self._device = profile.get_device()
            if settings.recording is not None:
                self._device.as_playback().set_real_time(False)
            colour = profile.get_stream(rs.stream.color).as_video_stream_profile()
            depth = profile.get_stream(rs.stream.depth).as_video_stream_profile()
            self.intrinsics = intrinsics_from_profile(colour)
            if settings.recording is None and settings.depth_units_m is not None:
                self._set_depth_units(settings.depth_units_m)
            self.depth_scale_m = self._sensor_depth_scale()
            self.T_colour_depth = transform_from_extrinsics(depth.get_extrinsics_to(colour))
            self._resampler = DepthResampler(
                self.intrinsics, intrinsics_from_profile(depth), self.T_colour_depth
            )
            self._align = rs.align(rs.stream.color)
            self._filters = self._make_filters()
            self.captures = 0
            if settings.recording is None:
                for _ in range(settings.warmup_frames):
                    self._next_frameset()
        except BaseException:
            self.close()
            raise

    # --- opening ---------------------------------------------------------------------------

    def _configure_live(self, config: rs.config) -> dict:
        devices = list(self._context.query_devices())
        if not devices:
            raise CameraError(f"no RealSense camera found; {_CHECK_CONNECTION}")
        serials = [d.get_info(rs.camera_info.serial_number) for d in devices]
        wanted = self.settings.serial or serials[0]
        if wanted not in serials:
            raise CameraError(f"no RealSense camera with serial {wanted}; found {serials}")
        device = devices[serials.index(wanted)]
        s = self.settings
        self._require_profile(device, rs.stream.color, rs.format.rgb8, s.colour_size)
        self._require_profile(device, rs.stream.depth, rs.format.z16, s.depth_size)
        config.enable_device(wanted)
        config.enable_stream(rs.stream.color, *s.colour_size, rs.format.rgb8, s.fps)
        config.enable_stream(rs.stream.depth, *s.depth_size, rs.format.z16, s.fps)
        if s.record_to is not None:
            config.enable_record_to_file(str(s.record_to))
        return _describe(device)

    def _require_profile(
        self, device: rs.device, stream: rs.stream, fmt: rs.format, size: tuple[int, int]
    ) -> None:
        offered = set()
        for sensor in device.query_sensors():
            for p in sensor.get_stream_profiles():
                if p.stream_type() == stream and p.format() == fmt:
                    v = p.as_video_stream_profile()
                    offered.add((v.width(), v.height(), p.fps()))
        if (*size, self.settings.fps) not in offered:
            listed = ", ".join(f"{w}x{h}@{f}" for w, h, f in sorted(offered)) or "none"
            name = "colour" if stream == rs.stream.color else "depth"
            raise CameraError(
                f"{device.get_info(rs.camera_info.name)} does not offer {name} "
                f"{size[0]}x{size[1]}@{self.settings.fps} ({fmt}); it offers {listed}"
            )

    def _configure_playback(self, config: rs.config) -> dict:
        path = Path(self.settings.recording)
        if not path.is_file():
            raise CameraError(f"{path}: no such recording")
        config.enable_device_from_file(str(path), repeat_playback=False)
        return {"recording": str(path)}

    def _depth_sensor(self) -> rs.sensor:
        for sensor in self._device.query_sensors():
            if sensor.supports(rs.option.depth_units):
                return sensor
        raise CameraError("the device has no sensor with a depth scale (option depth_units)")

    def _sensor_depth_scale(self) -> float:
        return float(self._depth_sensor().get_option(rs.option.depth_units))

    def _set_depth_units(self, units_m: float) -> None:
        """Set the depth step where the camera allows it; otherwise keep the camera's."""
        sensor = self._depth_sensor()
        if not sensor.is_option_read_only(rs.option.depth_units):
            sensor.set_option(rs.option.depth_units, units_m)

    def _make_filters(self) -> list[rs.filter]:
        """Depth filters in Intel's recommended order; spatial and temporal work on disparity."""
        chosen = set(self.settings.filters)
        filters: list[rs.filter] = []
        smoothing = [
            f()
            for name, f in (("spatial", rs.spatial_filter), ("temporal", rs.temporal_filter))
            if name in chosen
        ]
        if smoothing:
            filters += [rs.disparity_transform(True), *smoothing, rs.disparity_transform(False)]
        if "hole_filling" in chosen:
            filters.append(rs.hole_filling_filter())
        return filters

    # --- capturing -------------------------------------------------------------------------

    def capture(self, not_before_s: float | None = None) -> RGBDCapture:
        """Average the depth of the next ``burst`` frame sets taken at or after not_before_s
        (seconds on the host clock; None: now for a live camera, the next frames of a
        recording). Raises CameraError; never half-returns."""
        if not_before_s is None:
            not_before_s = time.time() if self.settings.recording is None else 0.0
        frameset = self._next_frameset()
        if frameset.get_frame_timestamp_domain() in _HOST_CLOCK_DOMAINS:
            while frameset.get_timestamp() / 1000.0 < not_before_s:
                frameset = self._next_frameset()
        else:
            for _ in range(_STALE_FRAMESETS):
                frameset = self._next_frameset()
        shape = (self.intrinsics.height, self.intrinsics.width)
        samples = np.zeros(shape, dtype=np.uint8)
        depth_mean = None
        for i in range(self.settings.burst):
            if i > 0:
                frameset = self._next_frameset()
            for f in self._filters:
                frameset = f.process(frameset).as_frameset()
            depth = frameset.get_depth_frame()
            if depth_mean is None:
                depth_mean = DepthAverage((depth.get_height(), depth.get_width()))
            depth_mean.add(np.asarray(depth.get_data(), dtype=np.float64) * depth.get_units())
            samples += self._align.process(frameset).get_depth_frame().as_depth_frame().get_data() != 0
        mean_m = depth_mean.mean()
        rgb, aligned_m = self._aligned(self._with_depth(frameset, mean_m))
        depth_m = self._resampler.resample(aligned_m, mean_m)
        self.captures += 1
        return RGBDCapture(rgb, depth_m.astype(np.float32), samples, frameset.get_timestamp() / 1000.0)

    def _with_depth(self, frameset: rs.composite_frame, depth_m: np.ndarray) -> rs.composite_frame:
        """The frame set with its depth frame replaced by depth_m (depth image, metres),
        built by librealsense's frame source so that align treats it as camera depth."""
        units = frameset.get_depth_frame().get_units()
        steps = np.clip(np.rint(depth_m / units), 0, np.iinfo(np.uint16).max).astype(np.uint16)

        def build(frame: rs.frame, source: rs.frame_source) -> None:
            original = frame.as_frameset()
            depth = original.get_depth_frame()
            replaced = source.allocate_video_frame(
                depth.get_profile(), depth, frame_type=rs.extension.depth_frame
            )
            np.asarray(replaced.get_data())[:] = steps
            source.frame_ready(source.allocate_composite_frame([replaced, original.get_color_frame()]))

        block = rs.processing_block(build)
        queue = rs.frame_queue(1)
        block.start(queue)
        block.invoke(frameset)
        return queue.wait_for_frame(int(self.settings.timeout_s * 1000)).as_frameset()

    def _aligned(self, frameset: rs.composite_frame) -> tuple[np.ndarray, np.ndarray]:
        """Colour (H, W, 3) uint8 and depth aligned to it by rs.align: metres (float64) along
        the depth imager's axis."""
        aligned = self._align.process(frameset)
        colour, depth = aligned.get_color_frame(), aligned.get_depth_frame()
        if not colour or not depth:
            raise CameraError("a frame set lacked colour or depth after alignment")
        rgb = np.array(colour.get_data(), dtype=np.uint8, copy=True)
        return rgb, np.asarray(depth.get_data(), dtype=np.float64) * depth.get_units()

    def _next_frameset(self) -> rs.composite_frame:
        ok, frameset = self._pipeline.try_wait_for_frames(int(self.settings.timeout_s * 1000))
        if ok:
            return frameset
        if self.settings.recording is not None:
            raise CameraError(
                f"{self.settings.recording}: the recording ended after {self.captures} captures"
            )
        if not self._device.is_connected():
            raise CameraError(f"the camera was disconnected; {_CHECK_CONNECTION}")
        raise CameraError(
            f"no frame from the camera for {self.settings.timeout_s:g} s; {_CHECK_CONNECTION}, "
            "and that no other program is using it"
        )

    # --- the rest ------------------------------------------------------------------------

    def describe(self) -> dict:
        """What a dataset records about the camera: device, settings, depth scale and the
        depth imager's pose in the colour frame."""
        return {
            "kind": "realsense",
            "device": self.device_description,
            "settings": self.settings.to_dict(),
            "sensor_depth_scale_m": self.depth_scale_m,
            "T_colour_depth": [[float(v) for v in row] for row in self.T_colour_depth],
            "depth": "mean of the burst's valid samples in the depth image, aligned to colour by "
            "librealsense, re-expressed along the colour optical axis",
        }

    def close(self) -> None:
        if getattr(self, "_started", False):
            self._started = False
            try:
                self._pipeline.stop()
            except RuntimeError:
                pass  # already stopped by a disconnect; nothing left to release

    def __enter__(self) -> RealSenseCamera:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def _describe(device: rs.device) -> dict:
    info = {}
    for key, field in (
        ("name", rs.camera_info.name),
        ("serial", rs.camera_info.serial_number),
        ("firmware", rs.camera_info.firmware_version),
        ("usb", rs.camera_info.usb_type_descriptor),
    ):
        if device.supports(field):
            info[key] = device.get_info(field)
    return info
