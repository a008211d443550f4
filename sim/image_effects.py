"""Image effects of a real camera in a real office, applied to the renderer's ideal colour image.

Vignetting, a light gradient across the board, a specular highlight (glare on a glossy print),
per-view exposure and motion blur, plus two geometric helpers (where a glare appears, how far the
image moves while the arm has not settled). Pure numpy/OpenCV, deterministic (nothing is random).

Images are (H, W, 3) float32 grey levels 0..255 before noise and rounding; every function returns
a new float32 array and does not clip (a highlight may exceed 255; the caller clips). Pixel (0, 0)
is the centre of the top-left pixel, u to the right, v down; K is a (3, 3) OpenCV camera matrix.
"""

from __future__ import annotations

import cv2
import numpy as np


def _image(rgb: np.ndarray) -> np.ndarray:
    """rgb as float32 (H, W, 3), checked (may be the input itself; callers never write to it)."""
    img = np.asarray(rgb, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"rgb must be (H, W, 3), got shape {img.shape}")
    return img


def _normalised(K: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised image coordinates x (H, W) and y (H, 1) of the pixel centres (K^-1 [u, v, 1])."""
    K = np.asarray(K, dtype=np.float64)
    y = ((np.arange(h) - K[1, 2]) / K[1, 1]).astype(np.float32)
    x = ((np.arange(w) - K[0, 2]) / K[0, 0]).astype(np.float32)[None, :]
    if K[0, 1] != 0.0:
        x = x - np.float32(K[0, 1] / K[0, 0]) * y[:, None]
    return x, y[:, None]


def natural_corner_falloff(K: np.ndarray, width: int, height: int) -> float:
    """The corner_falloff of an ideal lens (cos^4 law): 1 - cos^4 of the angle to the farthest corner."""
    K = np.asarray(K, dtype=np.float64)
    corners = np.array([[0, 0, 1], [width - 1, 0, 1], [0, height - 1, 1], [width - 1, height - 1, 1.0]])
    rays = np.linalg.solve(K, corners.T)
    return float(1.0 - np.min(rays[2] ** 2 / np.sum(rays**2, axis=0)) ** 2)


def vignetting(rgb: np.ndarray, K: np.ndarray, corner_falloff: float) -> np.ndarray:
    """Radial brightness fall-off with the profile of the cos^4 law, scaled so that the corner pixel
    farthest from the principal point is corner_falloff darker (0.3 = 30 % darker) and the principal
    point unchanged. corner_falloff = natural_corner_falloff(K, W, H) is exactly the cos^4 law."""
    if not 0.0 <= corner_falloff <= 1.0:
        raise ValueError(f"corner_falloff must be in [0, 1], got {corner_falloff}")
    img = _image(rgb)
    x, y = _normalised(K, *img.shape[:2])
    cos2 = 1.0 / (1.0 + x * x + y * y)
    corner = natural_corner_falloff(K, img.shape[1], img.shape[0])
    scale = np.float32(corner_falloff / corner if corner > 0.0 else 0.0)
    gain = (1.0 - scale) + scale * (cos2 * cos2)  # 1 - scale (1 - cos^4 theta)
    return img * gain[:, :, None]


def light_gradient(rgb: np.ndarray, direction_rad: float, change_across_image: float) -> np.ndarray:
    """Multiplicative linear brightness ramp increasing along direction_rad in the image (0 = +u to the
    right, pi/2 = +v down). The gain is 1 at the image centre and 1 -/+ change_across_image / 2 at the
    extreme pixels, so 0.2 = the bright side is brighter than the dark side by 20 % of the centre."""
    if abs(change_across_image) >= 2.0:
        raise ValueError(f"|change_across_image| must be < 2, got {change_across_image}")
    img = _image(rgb)
    h, w = img.shape[:2]
    c, s = np.cos(direction_rad), np.sin(direction_rad)
    extent = abs(c) * (w - 1) + abs(s) * (h - 1)  # range of the projection over the image
    k = change_across_image / extent if extent > 0.0 else 0.0
    gu = (1.0 + k * c * (np.arange(w) - (w - 1) / 2.0)).astype(np.float32)
    gv = (k * s * (np.arange(h) - (h - 1) / 2.0)).astype(np.float32)
    return img * (gv[:, None] + gu[None, :])[:, :, None]


def highlight_blob(
    shape: tuple[int, int], centre_px: tuple[float, float] | np.ndarray, radius_px: float, peak_grey: float
) -> np.ndarray:
    """(H, W) float32 white Gaussian glare blob for an image of shape (H, W): peak_grey at centre_px
    (u, v; may be sub-pixel or off the image), peak_grey / 2 at radius_px (half width at half maximum)."""
    if radius_px <= 0.0:
        raise ValueError(f"radius_px must be > 0, got {radius_px}")
    h, w = shape
    a = np.log(2.0) / radius_px**2  # exp(-a r^2) = 1/2 at r = radius_px
    gu = np.exp(-a * (np.arange(w) - centre_px[0]) ** 2).astype(np.float32)
    gv = (peak_grey * np.exp(-a * (np.arange(h) - centre_px[1]) ** 2)).astype(np.float32)
    return np.outer(gv, gu)


def specular_highlight(
    rgb: np.ndarray, centre_px: tuple[float, float] | np.ndarray, radius_px: float, peak_grey: float
) -> np.ndarray:
    """Add the white glare blob of highlight_blob to every channel. Not clipped: it saturates when
    clipped. (cv2.add: numpy's broadcast add took 10x as long on a view into a larger image.)"""
    img = _image(rgb)
    blob = highlight_blob(img.shape[:2], centre_px, radius_px, peak_grey)
    return cv2.add(img, cv2.merge([blob] * 3))


def mirror_point(camera_position: np.ndarray, light_position: np.ndarray) -> np.ndarray:
    """(3,) point on the plane z = 0 where the light's mirror reflection reaches the camera.

    Both positions (3,) in the plane's frame, metres, z > 0. It is where the line from the camera
    to the light's mirror image (x, y, -z) crosses the plane."""
    cam = np.asarray(camera_position, dtype=np.float64)
    light = np.asarray(light_position, dtype=np.float64)
    if cam.shape != (3,) or light.shape != (3,) or cam[2] <= 0.0 or light[2] <= 0.0:
        raise ValueError("camera_position and light_position must be (3,) with z > 0")
    p = (cam * light[2] + light * cam[2]) / (cam[2] + light[2])
    p[2] = 0.0
    return p


def exposure(rgb: np.ndarray, gain: float) -> np.ndarray:
    """Multiplicative exposure gain (1 = unchanged), e.g. a per-view auto-exposure difference."""
    if gain < 0.0:
        raise ValueError(f"gain must be >= 0, got {gain}")
    return _image(rgb) * np.float32(gain)


def motion_blur_kernel(shift_px: np.ndarray | tuple[float, float]) -> np.ndarray:
    """Anti-aliased line kernel (float32, square, odd size) for a shift (du, dv) in pixels.

    The segment from -shift/2 to +shift/2 (image at mid-exposure) sampled every <= 0.05 px with
    bilinear splatting. Sums to 1, point-symmetric (so correlation = convolution), [[1]] for zero shift."""
    s = np.asarray(shift_px, dtype=np.float64).reshape(2)
    length = float(np.hypot(*s))
    if length == 0.0:
        return np.ones((1, 1), dtype=np.float32)
    half = max(1, int(np.ceil(np.abs(s).max() / 2.0)))
    kernel = np.zeros((2 * half + 1, 2 * half + 1), dtype=np.float64)
    n = max(1, int(np.ceil(length / 0.05)))
    t = (np.arange(n) + 0.5) / n - 0.5  # midpoint rule over the segment
    pu, pv = half + t * s[0], half + t * s[1]
    u0, v0 = np.floor(pu).astype(int), np.floor(pv).astype(int)
    fu, fv = pu - u0, pv - v0
    for du, dv, wgt in (
        (0, 0, (1 - fu) * (1 - fv)),
        (1, 0, fu * (1 - fv)),
        (0, 1, (1 - fu) * fv),
        (1, 1, fu * fv),
    ):
        np.add.at(kernel, (v0 + dv, u0 + du), wgt / n)
    return kernel.astype(np.float32)


def motion_blur(rgb: np.ndarray, shift_px: np.ndarray | tuple[float, float]) -> np.ndarray:
    """Blur along the straight line of the image motion shift_px (du, dv) during the exposure
    (spatially uniform, reflected border). A copy for zero shift."""
    img = _image(rgb)
    kernel = motion_blur_kernel(shift_px)
    if kernel.shape == (1, 1):
        return img.copy()
    return cv2.filter2D(img, cv2.CV_32F, kernel, borderType=cv2.BORDER_REFLECT_101)


def motion_blur_shift(
    K: np.ndarray,
    depth_m: float,
    v_cam: np.ndarray,
    w_cam: np.ndarray,
    exposure_s: float,
    pixel_uv: tuple[float, float] | None = None,
) -> np.ndarray:
    """(2,) image shift (du, dv), pixels, of a static scene point at depth depth_m (along the optical
    axis) seen at pixel_uv (default the principal point) while the camera moves with linear velocity
    v_cam (m/s) and angular velocity w_cam (rad/s), both in the camera frame, for exposure_s seconds.
    First order (constant image velocity over the exposure)."""
    K = np.asarray(K, dtype=np.float64)
    uv = K[:2, 2] if pixel_uv is None else np.asarray(pixel_uv, dtype=np.float64)
    p = depth_m * np.linalg.solve(K, np.array([uv[0], uv[1], 1.0]))  # point in the camera frame
    p_dot = -np.asarray(v_cam, dtype=np.float64) - np.cross(w_cam, p)  # the point seen from the camera
    q, q_dot = K @ p, K @ p_dot
    return exposure_s * (q_dot[:2] / q[2] - q[:2] * q_dot[2] / q[2] ** 2)
