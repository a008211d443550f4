"""Headless RGB + metric depth from one MuJoCo render pass.

Depth is the distance along the optical axis (camera z), in metres, recovered
from MuJoCo's reversed-Z depth buffer the same way mujoco.Renderer does. The
offscreen buffer is made without multisampling: a multisampled depth buffer
resolves to one sample that is not at the pixel centre (about 0.4 px off,
0.2 mm of depth on a tilted board). The board's texture filtering still
anti-aliases the marker edges, which is what the corners are measured on.
"""

from __future__ import annotations

import mujoco
import numpy as np


class RGBDRenderer:
    """Offscreen renderer for one model; reuse it across frames (it owns a GL context)."""

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(
                f"{width}x{height} exceeds the model's offscreen buffer "
                f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}"
            )
        self._model = model
        self.width, self.height = width, height
        self._gl = mujoco.GLContext(width, height)
        self._gl.make_current()
        saved_samples = model.vis.quality.offsamples
        model.vis.quality.offsamples = 0
        try:
            self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        finally:
            model.vis.quality.offsamples = saved_samples
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        # Read depth as 0 at the far plane (reversed Z), for precision at range.
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=2000)
        self._option = mujoco.MjvOption()
        self._rect = mujoco.MjrRect(0, 0, width, height)
        extent = model.stat.extent
        near = np.float32(model.vis.map.znear * extent)
        far = np.float32(model.vis.map.zfar * extent)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        # Reversed-Z projection: window depth maps to metric depth as d' / (z + c').
        self._c = np.float32(-0.5) * c - np.float32(0.5)
        self._d = np.float32(-0.5) * d

    def render(
        self, data: mujoco.MjData, camera: int | str | mujoco.MjvCamera
    ) -> tuple[np.ndarray, np.ndarray]:
        """Render the view of ``camera`` (id, name or free MjvCamera).

        Returns rgb (H, W, 3) uint8 and depth (H, W) float32 metres, row 0 at the top.
        """
        if isinstance(camera, mujoco.MjvCamera):
            mjv_camera = camera
        else:
            mjv_camera = mujoco.MjvCamera()
            mjv_camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
            mjv_camera.fixedcamid = camera if isinstance(camera, int) else self._model.camera(camera).id
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self._model, data, self._option, None, mjv_camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        mujoco.mjr_render(self._rect, self._scene, self._context)
        rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        window_depth = np.empty((self.height, self.width), dtype=np.float32)
        mujoco.mjr_readPixels(rgb, window_depth, self._rect, self._context)
        # OpenGL's row 0 is the bottom one; both come back C-contiguous (compiled passes want that).
        depth = (self._d / (window_depth[::-1].astype(np.float64) + self._c)).astype(np.float32)
        return np.ascontiguousarray(rgb[::-1]), depth

    def close(self) -> None:
        self._gl.make_current()
        self._context.free()
        self._gl.free()
