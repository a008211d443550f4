"""A D435-like librealsense software device that streams what a simulated cell sees.

librealsense's ``software_device`` is a real device inside the real library: we
declare its sensors, stream profiles (with intrinsics) and the depth-to-colour
extrinsics, and push frames into it; the pipeline, the syncer, ``rs.align`` and the
recorder then run librealsense's own code. Colour comes from the cell's camera,
depth from the cell's separate depth sensor (another pose and other intrinsics),
both with the scenario's noise models, stamped on the host clock.

What a capture gets does not depend on timing: the noise of a frame is drawn from the seed, the
cell's pose (counted: each change of the cell's joints is a new pose) and the frame's number since
that change modulo ``burst``, so any ``burst`` consecutive frames at one pose carry the same draws
and average to the same depth however late the capture starts; the colour noise is one draw per
pose. (A capture that lost a frame within its burst, a consumer slower than the stream, would
break that.)
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pyrealsense2 as rs

from hec.estimator.common.depth_png import encode_depth
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.transforms import make_transform
from hec.sim.cell import SimCell
from hec.sim.noise import apply_depth_models, apply_rgb_models
from hec.sim.scenario import CameraSettings, Scenario
from hec.sim.scene import DepthSensor

SERIAL = "000000000001"
FPS = 30
DEPTH_UNITS_M = 0.001  # a D435's default
# D435-like colour at 640x480 and depth at 848x480; values exact in float32 so the
# intrinsics that come back through librealsense can be compared exactly.
COLOUR_INTRINSICS = CameraIntrinsics(640, 480, 615.5, 615.75, 318.875, 241.625)
DEPTH_INTRINSICS = CameraIntrinsics(848, 480, 421.25, 421.25, 423.5, 239.25)


def d435_depth_sensor() -> DepthSensor:
    """The depth imager in the colour optical frame: ~15 mm to the side, slightly turned."""
    angle = np.radians(0.3)
    R = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
    return DepthSensor(make_transform(R, np.array([-0.0148, 0.0002, 0.0004])), DEPTH_INTRINSICS)


def d435_scenario(scenario: Scenario) -> Scenario:
    """The scenario with the colour camera set to COLOUR_INTRINSICS."""
    k = COLOUR_INTRINSICS
    camera = CameraSettings(width=k.width, height=k.height, fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)
    return scenario.model_copy(update={"camera": camera})


def _rs_intrinsics(k: CameraIntrinsics) -> rs.intrinsics:
    out = rs.intrinsics()
    out.width, out.height = k.width, k.height
    out.fx, out.fy, out.ppx, out.ppy = k.fx, k.fy, k.cx, k.cy
    out.model = rs.distortion.brown_conrady
    out.coeffs = list(k.dist)
    return out


def _video_stream(
    stream: rs.stream, uid: int, k: CameraIntrinsics, fmt: rs.format, bpp: int
) -> rs.video_stream:
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid = stream, 0, uid
    vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = k.width, k.height, FPS, bpp, fmt
    vs.intrinsics = _rs_intrinsics(k)
    return vs


class SoftwareD435:
    """Streams the cell's view through a software device while its sensors are started.

    cell: a SimCell built with ``d435_depth_sensor()`` and colour intrinsics
    COLOUR_INTRINSICS; lock guards the cell (a robot stand-in may move it concurrently).
    ``context`` is the librealsense context that lists the device. depth_units_m: the
    starting depth step (a D435's default, 1 mm); the option is writable, as on a D435.
    rng: draws the device's noise seed; burst: the frames a capture averages (the camera's
    settings), the period of the depth noise draws at one pose (module doc).
    """

    def __init__(
        self,
        cell: SimCell,
        lock: threading.Lock,
        rng: np.random.Generator,
        depth_units_m: float = DEPTH_UNITS_M,
        burst: int = 4,
    ) -> None:
        if cell.depth_sensor is None or cell.intrinsics != COLOUR_INTRINSICS:
            raise ValueError("build the cell with d435_depth_sensor() and COLOUR_INTRINSICS")
        self.cell, self.lock = cell, lock
        self.noise_seed = int(rng.integers(2**63))
        self.burst = burst
        self._pose: np.ndarray | None = None
        self._pose_count = 0
        self._frames_at_pose = 0
        self.device = rs.software_device()
        self.device.register_info(rs.camera_info.name, "Intel RealSense D435 (software device)")
        self.device.register_info(rs.camera_info.serial_number, SERIAL)
        self.device.register_info(rs.camera_info.firmware_version, "5.16.0.1")
        self._depth_sensor = self.device.add_sensor("Stereo Module")
        self._colour_sensor = self.device.add_sensor("RGB Camera")
        self._depth_profile = self._depth_sensor.add_video_stream(
            _video_stream(rs.stream.depth, 0, DEPTH_INTRINSICS, rs.format.z16, 2), True
        ).as_video_stream_profile()
        self._colour_profile = self._colour_sensor.add_video_stream(
            _video_stream(rs.stream.color, 1, COLOUR_INTRINSICS, rs.format.rgb8, 3), True
        ).as_video_stream_profile()
        # Writable, like a D435's, so the camera source may choose finer steps. The Python
        # constructor's order is (min, max, default, step); step 0 = any value (float32
        # rounding makes 0.001 "not a multiple" of a 1e-6 step).
        units_range = rs.option_range(1e-6, 0.01, depth_units_m, 0.0)
        self._depth_sensor.add_option(rs.option.depth_units, units_range)
        T_colour_depth = cell.depth_sensor.T_cam_depth
        extrinsics = rs.extrinsics()
        extrinsics.rotation = [float(v) for v in T_colour_depth[:3, :3].T.ravel()]  # column-major
        extrinsics.translation = [float(v) for v in T_colour_depth[:3, 3]]
        self._depth_profile.register_extrinsics_to(self._colour_profile, extrinsics)
        self.device.create_matcher(rs.matchers.default)
        self.context = rs.context()
        # librealsense keeps only a weak reference to a software device added to a
        # context (rs2_context_add_software_device); the device-added event holds a
        # strong one, so keep that event's list alive for as long as the context.
        self._added: list[rs.device_list] = []
        self.context.set_devices_changed_callback(lambda event: self._added.append(event.get_new_devices()))
        self.device.add_to(self.context)
        self.frames_pushed = 0
        self._paused = threading.Event()
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._stream, name="software-d435", daemon=True)
        self._thread.start()

    def pause(self) -> None:
        """Stop delivering frames (a camera that hangs or is unplugged)."""
        self._paused.set()

    def resume(self) -> None:
        self._paused.clear()

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=10)

    def __enter__(self) -> SoftwareD435:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def _streaming(self) -> bool:
        return bool(self._depth_sensor.get_active_streams()) and bool(
            self._colour_sensor.get_active_streams()
        )

    def _stream(self) -> None:
        """The streaming thread; it owns the cell's GL contexts (a context is current in
        one thread only) and frees them when it ends."""
        period = 1.0 / FPS
        try:
            while not self._closed.is_set():
                started = time.monotonic()
                if self._paused.is_set() or not self._streaming():
                    time.sleep(0.01)
                    continue
                self._push_one()
                time.sleep(max(0.0, period - (time.monotonic() - started)))
        finally:
            with self.lock:
                self.cell.close()

    def _push_one(self) -> None:
        with self.lock:
            stamp_ms = time.time() * 1000.0
            if self._pose is None or not np.array_equal(self._pose, self.cell.joints):
                self._pose = self.cell.joints.copy()
                self._pose_count += 1
                self._frames_at_pose = 0
            rgb_true, _ = self.cell.render_true()
            depth_true = self.cell.render_depth_sensor()
        draw = self._frames_at_pose % self.burst
        self._frames_at_pose += 1
        depth_rng = np.random.default_rng([self.noise_seed, self._pose_count, draw])
        rgb_rng = np.random.default_rng([self.noise_seed, self._pose_count, self.burst])
        units_m = self._depth_sensor.get_option(rs.option.depth_units)
        noise = self.cell.scenario.noise
        # The camera rounds to its current depth units, whatever the scenario's step.
        steps = noise.depth_quantisation.model_copy(update={"depth_scale_m": units_m})
        noise = noise.model_copy(update={"depth_quantisation": steps})
        rgb = apply_rgb_models(rgb_true, noise.rgb, rgb_rng)
        depth = apply_depth_models(depth_true, DEPTH_INTRINSICS, noise, depth_rng)
        self.frames_pushed += 1
        for sensor, profile, pixels, bpp in (
            (self._depth_sensor, self._depth_profile, encode_depth(depth, units_m), 2),
            (self._colour_sensor, self._colour_profile, np.ascontiguousarray(rgb), 3),
        ):
            frame = rs.software_video_frame()
            frame.pixels = pixels
            frame.bpp = bpp
            frame.stride = pixels.shape[1] * bpp
            frame.timestamp = stamp_ms
            frame.domain = rs.timestamp_domain.system_time
            frame.frame_number = self.frames_pushed
            frame.profile = profile
            if sensor is self._depth_sensor:
                frame.depth_units = units_m
            sensor.on_video_frame(frame)
