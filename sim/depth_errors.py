"""Depth errors of a real stereo depth camera (Intel RealSense D435) beyond white per-pixel noise.

Spatially correlated noise, depth-to-colour misregistration (an error in the calibrated pose of
the depth imager), flying pixels at depth edges and blob-shaped holes. numpy/scipy/OpenCV, the
per-pixel loops compiled (hec.sim.compiled).

All randomness comes from the ``numpy.random.Generator`` passed in; the same inputs and generator
state give bit-identical results. Depth images are (H, W) float32 metres along the optical axis,
0.0 = invalid. K is a (3, 3) OpenCV camera matrix; pixel (0, 0) is the centre of the top-left pixel.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from scipy.fft import irfft2, next_fast_len, rfft2
from scipy.optimize import brentq

from hec.sim.compiled import compiled, compiled_inline
from hec.sim.fast_normal import quantised_normal

_INV_E = float(np.exp(-1.0))


def _one_over_e_lag(rho: np.ndarray) -> float:
    """First lag (samples) where the autocorrelation rho[lag] (rho[0] = 1) falls to 1/e.

    Interpolated between the integer lags linearly in (lag^2, ln rho), which is exact for a
    Gaussian rho = exp(-lag^2 / L^2); linearly in (lag, rho) if rho drops to <= 0 there.
    """
    below = np.flatnonzero(rho < _INV_E)
    if below.size == 0:
        raise ValueError("the autocorrelation does not fall to 1/e within the lags available")
    k = int(below[0])
    r0, r1 = float(rho[k - 1]), float(rho[k])
    if r1 <= 0.0:
        return k - 1 + (r0 - _INV_E) / (r0 - r1)
    frac = (-1.0 - np.log(r0)) / (np.log(r1) - np.log(r0))
    return float(np.sqrt((k - 1) ** 2 + frac * (2 * k - 1)))


def _gaussian_kernel(sigma: float) -> np.ndarray:
    """(2r+1,) float64 sampled Gaussian, r = ceil(4 sigma), scaled to unit sum of squares."""
    r = max(1, int(np.ceil(4.0 * sigma)))
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    return g / np.sqrt(np.sum(g * g))


def _kernel_lag(sigma: float) -> float:
    """The 1/e lag of white noise filtered by _gaussian_kernel(sigma) (pixels)."""
    g = _gaussian_kernel(sigma)
    return _one_over_e_lag(np.append(np.correlate(g, g, "full")[g.size - 1 :], 0.0))


@lru_cache(maxsize=64)
def _kernel_for_length(correlation_px: float) -> np.ndarray:
    """(2r+1,) float32 kernel giving exactly the 1/e lag correlation_px (about sigma = L / 2)."""
    sigma = brentq(lambda s: _kernel_lag(s) - correlation_px, 0.05, correlation_px, xtol=1e-6)
    return _gaussian_kernel(sigma).astype(np.float32)


def correlated_unit_noise(
    shape: tuple[int, int], correlation_px: float, rng: np.random.Generator
) -> np.ndarray:
    """(H, W) float32 (C-contiguous) stationary zero-mean, unit-variance Gaussian random field.

    Correlation length: its autocorrelation along x and along y is ~exp(-lag^2 / L^2), falling to 1/e
    at lag L = correlation_px pixels (as autocorrelation_length measures it). White noise filtered by
    a Gaussian (sigma ~ L / 2, solved so that the discrete field hits L exactly), generated on a
    padded grid and cropped so the border is as correlated as the centre. L <= 0.5 gives white noise.
    The white noise is hec.sim.fast_normal's quantised Gaussian.
    """
    h, w = shape
    if correlation_px <= 0.5:
        return quantised_normal(rng, (h, w))
    g = _kernel_for_length(float(correlation_px))
    r = g.size // 2
    white = quantised_normal(rng, (h + 2 * r, w + 2 * r))
    return np.ascontiguousarray(cv2.sepFilter2D(white, cv2.CV_32F, g, g)[r : r + h, r : r + w])


def autocorrelation_length(field: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Measured correlation length (pixels) of field (H, W): the 1/e lag, as defined in _one_over_e_lag,
    of the normalised autocorrelation averaged over the x and y directions.

    valid: (H, W) bool, pixels to use (default all finite ones). The mean over the valid pixels is
    removed; each lag's autocovariance is divided by its number of valid pixel pairs (zero-padded FFT,
    no wrap-around). For a residual image (e.g. measured minus fitted board plane) pass its mask.
    """
    f = np.asarray(field, dtype=np.float32)
    m = np.isfinite(f) if valid is None else np.asarray(valid, dtype=bool) & np.isfinite(f)
    f = np.where(m, f - f[m].mean(), 0.0).astype(np.float32)
    h, w = f.shape
    s = (next_fast_len(2 * h, real=True), next_fast_len(2 * w, real=True))

    def acov(a: np.ndarray) -> np.ndarray:
        spec = rfft2(a, s=s, workers=-1)
        return irfft2(spec.real**2 + spec.imag**2, s=s, workers=-1)

    cov, pairs = acov(f), acov(m.astype(np.float32))
    n = min(h, w) // 2
    with np.errstate(invalid="ignore", divide="ignore"):
        cx, cy = cov[0, :n] / pairs[0, :n], cov[:n, 0] / pairs[:n, 0]
    return _one_over_e_lag(0.5 * (cx / cx[0] + cy / cy[0]))


@compiled_inline
def _landing(z: np.ndarray, zm: np.ndarray, warp: tuple, at: tuple) -> tuple[int, np.float32]:
    """Where pixel (j, i) of z (H, W) lands under warp (H, Kt, max_slope): the flat index of the
    nearest target pixel (-1: none) and its depth there, corrected to that pixel's centre with the
    slope of zm (H, W, the new depths) between the neighbours at = (j, i, (up, down), (left, right));
    a slope above max_slope is an edge or an invalid neighbour and is taken as 0."""
    H, Kt, max_slope = warp
    j, i, (up, down), (left, right) = at
    h, w = z.shape
    d = np.float64(z[j, i])
    u = ((H[0, 0] * i + H[0, 1] * j + H[0, 2]) * d + Kt[0]) / zm[j, i]
    v = ((H[1, 0] * i + H[1, 1] * j + H[1, 2]) * d + Kt[1]) / zm[j, i]
    iu, iv = np.rint(u), np.rint(v)
    # Sub-pixel correction to the target pixel centre, d z'/d u' ~ d z'/d u (the warp is ~1:1).
    slope_u = (zm[j, right] - zm[j, left]) / (right - left)
    slope_v = (zm[down, i] - zm[up, i]) / (down - up)
    slope_u = slope_u if abs(slope_u) <= max_slope else 0.0
    slope_v = slope_v if abs(slope_v) <= max_slope else 0.0
    zc = zm[j, i] + slope_u * (iu - u) + slope_v * (iv - v)
    lands = (d > 0.0) & (zc > 0.0) & (iu >= 0.0) & (iu <= w - 1) & (iv >= 0.0) & (iv <= h - 1)
    return (np.int32(iv) * w + np.int32(iu) if lands else -1), np.float32(zc)


@compiled
def _splat(
    z: np.ndarray, H: np.ndarray, Kt: np.ndarray, continuity_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The forward warp of misregister_depth: every valid pixel of z (H, W) moved by H, Kt and
    re-projected to the nearest pixel, nearest surface kept; (H, W) float32, 0 where nothing lands,
    and the flat indices of those empty pixels (E,) int64. Where each pixel lands is computed first
    (a loop that vectorises), then written."""
    h, w = z.shape
    zm = np.empty((h, w))  # every pixel's new depth z'
    for j in range(h):
        for i in range(w):
            zm[j, i] = (H[2, 0] * i + H[2, 1] * j + H[2, 2]) * np.float64(z[j, i]) + Kt[2]
    target = np.empty((h, w), dtype=np.int32)  # the flat index each pixel lands on, -1: none
    landed = np.empty((h, w), dtype=np.float32)  # its depth there
    warp = (H, Kt, continuity_m / 2)
    for j in range(h):
        rows = (max(j - 1, 0), min(j + 1, h - 1))
        for i in (0, w - 1):
            target[j, i], landed[j, i] = _landing(
                z, zm, warp, (j, i, rows, (max(i - 1, 0), min(i + 1, w - 1)))
            )
        for i in range(1, w - 1):
            target[j, i], landed[j, i] = _landing(z, zm, warp, (j, i, rows, (i - 1, i + 1)))
    out = np.full(h * w, np.inf, dtype=np.float32)
    flat_target, flat_landed = target.ravel(), landed.ravel()
    for k in range(flat_target.size):
        t = flat_target[k]
        if t >= 0:
            out[t] = min(out[t], flat_landed[k])
    empty = np.empty(out.size, dtype=np.int64)
    count = 0
    for k in range(out.size):
        if out[k] == np.inf:
            out[k] = 0.0
            empty[count] = k
            count += 1
    return out.reshape(h, w), empty[:count]


@compiled
def _close_cracks(
    out: np.ndarray, empty: np.ndarray, z: np.ndarray, inverse: tuple, continuity_m: float
) -> np.ndarray:
    """One pass of misregister_depth's crack filling on out (H, W) float32, in place, over its empty
    pixels empty (E,) (flat indices): each is judged on out as it was before the pass. inverse:
    (H_inv, Kt) of the warp. Returns the flat indices of those still empty."""
    H_inv, Kt = inverse
    h, w = out.shape
    flat = out.ravel()
    fill = np.zeros(empty.size, dtype=np.float32)  # 0: stays empty
    for n in range(empty.size):
        j, i = empty[n] // w, empty[n] % w
        total, count = np.float32(0.0), 0
        for dj, di in ((0, 1), (1, 0), (1, 1), (1, -1)):
            ja, ia, jb, ib = j + dj, i + di, j - dj, i - di
            if not (0 <= ja < h and 0 <= ia < w and 0 <= jb < h and 0 <= ib < w):
                continue
            a, b = out[ja, ia], out[jb, ib]
            if a > 0.0 and b > 0.0 and abs(a - b) < continuity_m:
                total += a + b
                count += 2
        if count == 0:
            continue
        zf = total / np.float32(count)
        p0, p1, p2 = i * np.float64(zf) - Kt[0], j * np.float64(zf) - Kt[1], np.float64(zf) - Kt[2]
        qz = H_inv[2, 0] * p0 + H_inv[2, 1] * p1 + H_inv[2, 2] * p2
        if not qz > 0.0:
            continue
        us = np.rint((H_inv[0, 0] * p0 + H_inv[0, 1] * p1 + H_inv[0, 2] * p2) / qz)
        vs = np.rint((H_inv[1, 0] * p0 + H_inv[1, 1] * p1 + H_inv[1, 2] * p2) / qz)
        if 0.0 <= us <= w - 1 and 0.0 <= vs <= h - 1 and abs(z[int(vs), int(us)] - qz) < continuity_m:
            fill[n] = zf
    for n in range(empty.size):
        if fill[n] > 0.0:
            flat[empty[n]] = fill[n]
    return empty[~(fill > 0.0)]


def misregister_depth(
    depth_m: np.ndarray, K: np.ndarray, T_cam_cammeasured: np.ndarray, continuity_m: float = 0.02
) -> np.ndarray:
    """(H, W) float32 aligned depth a camera reports when its depth imager is not where calibrated.

    depth_m: (H, W) ideal depth in the colour camera frame 'cam', metres. K: (3, 3), the same for
    input and output. Direction: a true point p (cam frame, metres) is reported at T_cam_cammeasured @ p;
    a translation (0, 0, +2 mm) makes everything look 2 mm further away. With the depth imager truly
    at T_cam_depth but calibrated at T_cam_depthcal, T_cam_cammeasured = T_cam_depthcal @ inv(T_cam_depth).
    Every valid pixel is moved and re-projected to the nearest pixel (z-buffer keeps the nearest
    surface); its depth is corrected to that pixel's centre with the local depth gradient, so planes
    come out exact to ~1e-5 m. Pixels nothing lands on stay 0 (occlusion shadows, the image border),
    except one-pixel cracks of magnification on a continuous surface (opposite neighbours within
    continuity_m) whose source pixel is valid: they get the neighbours' mean, since the real camera's
    footprint splatting leaves no cracks either.
    """
    z = np.ascontiguousarray(depth_m, dtype=np.float32)
    if not np.all(z >= 0.0):  # NaN or negative: invalid
        z = np.where(np.isfinite(z) & (z > 0.0), z, np.float32(0.0))
    Kd, T = np.asarray(K, dtype=np.float64), np.asarray(T_cam_cammeasured, dtype=np.float64)
    # Homogeneous target pixel z' (u', v', 1) = H z (u, v, 1) + K t; its last entry is the new depth z'.
    H, Kt = Kd @ T[:3, :3] @ np.linalg.inv(Kd), Kd @ T[:3, 3]
    out, empty = _splat(z, H, Kt, continuity_m)
    # Cracks: empty pixels with a pair of opposite neighbours (-, |, both diagonals) on one surface,
    # kept if the inverse warp at the filled depth lands on a source pixel of about that depth.
    inverse = (np.linalg.inv(H), Kt)
    for _ in range(2):  # a second pass closes where cracks cross
        empty = _close_cracks(out, empty, z, inverse, continuity_m)
    return out


@compiled_inline
def _valid(z: float) -> bool:
    """A depth that was measured: positive and finite (NaN is not). Branch-free."""
    return (z > np.float32(0.0)) & (z < np.float32(np.inf))


@compiled_inline
def _jump(a: float, b: float, edge_threshold_m: float) -> bool:
    """Whether depths a and b are both valid and differ by more than edge_threshold_m."""
    return _valid(a) & _valid(b) & (abs(a - b) > edge_threshold_m)


@compiled_inline
def _at_edge(z: np.ndarray, at: tuple, edge_threshold_m: float) -> bool:
    """Whether pixel (j, i) of z (H, W) jumps by more than edge_threshold_m to one of its valid
    neighbours at = (j, i, (up, down), (left, right))."""
    j, i, (up, down), (left, right) = at
    c, t = z[j, i], edge_threshold_m
    return (
        _jump(c, z[j, left], t) | _jump(c, z[j, right], t) | _jump(c, z[up, i], t) | _jump(c, z[down, i], t)
    )


@compiled
def _edge_pixels(z: np.ndarray, edge_threshold_m: float) -> np.ndarray:
    """(H, W) uint8, 1 on both pixels of every pair of valid 4-neighbours whose depths z (H, W)
    differ by more than edge_threshold_m: each pixel looks at its four neighbours, branch-free
    (the interior loop vectorises)."""
    h, w = z.shape
    edge = np.empty((h, w), dtype=np.uint8)
    for j in range(h):
        rows = (max(j - 1, 0), min(j + 1, h - 1))
        for i in (0, w - 1):  # a clamped neighbour is the pixel itself: no jump
            edge[j, i] = _at_edge(z, (j, i, rows, (max(i - 1, 0), min(i + 1, w - 1))), edge_threshold_m)
        for i in range(1, w - 1):
            edge[j, i] = _at_edge(z, (j, i, rows, (i - 1, i + 1)), edge_threshold_m)
    return edge


@compiled
def _window_depths(z: np.ndarray, pixels: np.ndarray, width_px: int) -> tuple[np.ndarray, np.ndarray]:
    """The nearest and farthest valid depth of z (H, W) within width_px pixels (Chebyshev) of each
    of the flat pixel indices pixels (N,): two (N,) float32."""
    h, w = z.shape
    near = np.full(pixels.size, np.inf, dtype=np.float32)
    far = np.zeros(pixels.size, dtype=np.float32)
    for k in range(pixels.size):
        j, i = pixels[k] // w, pixels[k] % w
        for jj in range(max(j - width_px, 0), min(j + width_px + 1, h)):
            for ii in range(max(i - width_px, 0), min(i + width_px + 1, w)):
                if _valid(z[jj, ii]):
                    near[k] = min(near[k], z[jj, ii])
                    far[k] = max(far[k], z[jj, ii])
    return near, far


def flying_pixels(
    depth_m: np.ndarray,
    rng: np.random.Generator,
    edge_threshold_m: float = 0.02,
    probability: float = 0.5,
    width_px: int = 1,
) -> np.ndarray:
    """(H, W) float32 depth with flying pixels, as stereo matching windows straddling an edge produce.

    Edge pixels: valid pixels within width_px pixels (Chebyshev) of a depth discontinuity, i.e. a pair
    of valid 4-neighbours differing by more than edge_threshold_m (both pixels of the pair are edge
    pixels). Each edge pixel, with the given probability, takes fg + a (bg - fg), a ~ U(0, 1), where
    fg / bg are the nearest / farthest valid depth within width_px pixels. Other pixels are unchanged.
    """
    z = np.ascontiguousarray(depth_m, dtype=np.float32)
    edge = _edge_pixels(z, edge_threshold_m)
    if width_px > 1:
        edge = cv2.dilate(edge, np.ones((2 * width_px - 1, 2 * width_px - 1), dtype=np.uint8))
        edge &= (z > 0.0) & np.isfinite(z)
    idx = np.flatnonzero(edge)
    pick = idx[rng.random(idx.size) < probability]
    a = rng.random(pick.size, dtype=np.float32)
    fg, bg = _window_depths(z, pick, width_px)
    out = z.copy()
    out.ravel()[pick] = fg + a * (bg - fg)
    return out


@compiled
def _cut_ellipses(out: np.ndarray, centre: tuple, axes: tuple, angle: np.ndarray) -> None:
    """Set to 0, in place, the pixels of out (H, W) whose centres lie inside any of the ellipses:
    centres (cu, cv) (N,) pixels, semi-axes (a, b) (N,) pixels (a >= b), angle (N,) radians of the
    a axis from +u towards +v."""
    h, w = out.shape
    cu, cv = centre
    a, b = axes
    for k in range(cu.size):
        u0, u1 = max(0, int(np.ceil(cu[k] - a[k]))), min(w, int(np.floor(cu[k] + a[k])) + 1)
        v0, v1 = max(0, int(np.ceil(cv[k] - a[k]))), min(h, int(np.floor(cv[k] + a[k])) + 1)
        c, s = np.float32(np.cos(angle[k])), np.float32(np.sin(angle[k]))
        for v in range(v0, v1):
            dv = np.float32(v) - np.float32(cv[k])
            for u in range(u0, u1):
                du = np.float32(u) - np.float32(cu[k])
                if ((c * du + s * dv) / a[k]) ** 2 + ((c * dv - s * du) / b[k]) ** 2 <= 1.0:
                    out[v, u] = 0.0


def depth_holes(
    depth_m: np.ndarray, rng: np.random.Generator, holes_per_megapixel: float, mean_radius_px: float
) -> np.ndarray:
    """(H, W) float32 depth with random elliptic holes (0.0), e.g. low-texture or IR-shadow dropouts.

    Hole centres: a Poisson process of holes_per_megapixel per 10^6 pixels (also just outside the
    image, so the border is hit as often). Each hole: area pi r^2 with r ~ Gamma(4, mean_radius_px / 4)
    pixels, axis ratio U(0.5, 1), random orientation; a pixel is a hole if its centre is inside.
    Expected hole fraction: 1 - exp(-holes_per_megapixel 1e-6 * 1.25 pi mean_radius_px^2).
    """
    out = np.array(depth_m, dtype=np.float32)
    h, w = out.shape
    m = 4.0 * mean_radius_px
    n = rng.poisson(holes_per_megapixel * 1e-6 * (h + 2 * m) * (w + 2 * m))
    cu, cv = rng.uniform(-0.5 - m, w - 0.5 + m, n), rng.uniform(-0.5 - m, h - 0.5 + m, n)
    r, q, ang = rng.gamma(4.0, mean_radius_px / 4.0, n), rng.uniform(0.5, 1.0, n), rng.uniform(0, np.pi, n)
    a, b = r / np.sqrt(q), r * np.sqrt(q)
    _cut_ellipses(out, (cu, cv), (a, b), ang)
    return out
