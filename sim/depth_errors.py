"""Depth errors of a real stereo depth camera (Intel RealSense D435) beyond white per-pixel noise.

Spatially correlated noise, depth-to-colour misregistration (an error in the calibrated pose of
the depth imager), flying pixels at depth edges and blob-shaped holes. Pure numpy/scipy/OpenCV.

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

from sim.fast_normal import quantised_normal

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
    """(H, W) float32 stationary zero-mean, unit-variance Gaussian random field.

    Correlation length: its autocorrelation along x and along y is ~exp(-lag^2 / L^2), falling to 1/e
    at lag L = correlation_px pixels (as autocorrelation_length measures it). White noise filtered by
    a Gaussian (sigma ~ L / 2, solved so that the discrete field hits L exactly), generated on a
    padded grid and cropped so the border is as correlated as the centre. L <= 0.5 gives white noise.
    The white noise is sim.fast_normal's quantised Gaussian.
    """
    h, w = shape
    if correlation_px <= 0.5:
        return quantised_normal(rng, (h, w))
    g = _kernel_for_length(float(correlation_px))
    r = g.size // 2
    white = quantised_normal(rng, (h + 2 * r, w + 2 * r))
    return cv2.sepFilter2D(white, cv2.CV_32F, g, g)[r : r + h, r : r + w]


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


def _pairs(axis: int) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
    """Index slices of the first and second pixel of each neighbour pair along axis (1: x, 0: y)."""
    lo, hi = [slice(None), slice(None)], [slice(None), slice(None)]
    lo[axis], hi[axis] = slice(None, -1), slice(1, None)
    return tuple(lo), tuple(hi)


def _gradient(z: np.ndarray, dx: int, dy: int, max_abs: float) -> np.ndarray:
    """(H, W) float32 central difference of z along x (dx=1) or y (dy=1), one-sided on the image
    border, set to 0 where |gradient| > max_abs (a depth edge or an invalid neighbour)."""
    g = cv2.Sobel(z, cv2.CV_32F, dx, dy, ksize=1, scale=0.5, borderType=cv2.BORDER_REPLICATE)
    edges = (slice(None), [0, -1]) if dx else ([0, -1], slice(None))
    g[edges] *= 2.0  # replicated border: the one-sided difference was halved
    g[np.abs(g) > max_abs] = 0.0
    return g


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
    z = np.asarray(depth_m, dtype=np.float32)
    if not np.all(z >= 0.0):  # NaN or negative: invalid
        z = np.where(np.isfinite(z) & (z > 0.0), z, np.float32(0.0))
    h, w = z.shape
    Kd, T = np.asarray(K, dtype=np.float64), np.asarray(T_cam_cammeasured, dtype=np.float64)
    H, Kt = Kd @ T[:3, :3] @ np.linalg.inv(Kd), Kd @ T[:3, 3]
    # Homogeneous target pixel z' (u', v', 1) = H z (u, v, 1) + K t; its last entry is the new depth z'.
    uz = np.arange(w, dtype=np.float32)[None, :] * z
    vz = np.arange(h, dtype=np.float32)[:, None] * z
    qu, qv, zm = cv2.split(cv2.transform(cv2.merge([uz, vz, z]), np.hstack([H, Kt[:, None]])))
    u, v = cv2.divide(qu, zm), cv2.divide(qv, zm)
    iu, iv = np.rint(u), np.rint(v)
    # Sub-pixel correction to the target pixel centre, d z'/d u' ~ d z'/d u (the warp is ~1:1).
    zc = (
        zm
        + _gradient(zm, 1, 0, continuity_m / 2) * (iu - u)
        + _gradient(zm, 0, 1, continuity_m / 2) * (iv - v)
    )
    keep = (z > 0.0) & (zc > 0.0) & (iu >= 0.0) & (iu <= w - 1) & (iv >= 0.0) & (iv <= h - 1)
    idx = np.flatnonzero(keep)
    buf = np.full(h * w, np.inf, dtype=np.float32)
    lin = iv.ravel()[idx].astype(np.intp) * w + iu.ravel()[idx].astype(np.intp)
    np.minimum.at(buf, lin, zc.ravel()[idx])
    buf[buf == np.inf] = 0.0
    out = buf.reshape(h, w)
    # Cracks: empty pixels with a pair of opposite neighbours (-, |, both diagonals) on one surface,
    # kept if the inverse warp at the filled depth lands on a source pixel of about that depth.
    for _ in range(2):  # a second pass closes where cracks cross
        filled = (out > 0.0).astype(np.uint8)
        jj, ii = np.nonzero(cv2.dilate(filled, np.ones((3, 3), np.uint8)) > filled)
        p = np.pad(out, 1)
        total, count = np.zeros(jj.size, np.float32), np.zeros(jj.size, np.float32)
        for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a, b = p[jj + 1 + dy, ii + 1 + dx], p[jj + 1 - dy, ii + 1 - dx]
            ok = (a > 0.0) & (b > 0.0) & (np.abs(a - b) < continuity_m)
            total += np.where(ok, a + b, np.float32(0.0))
            count += 2 * ok
        sel = count > 0
        jj, ii, zf = jj[sel], ii[sel], total[sel] / count[sel]
        qs = np.linalg.solve(H, np.stack([ii * zf, jj * zf, zf]) - Kt[:, None])
        with np.errstate(invalid="ignore", divide="ignore"):
            us, vs = np.rint(qs[0] / qs[2]), np.rint(qs[1] / qs[2])
        ok = (qs[2] > 0) & (us >= 0) & (us <= w - 1) & (vs >= 0) & (vs <= h - 1)
        ok[ok] = np.abs(z[vs[ok].astype(np.intp), us[ok].astype(np.intp)] - qs[2, ok]) < continuity_m
        out[jj[ok], ii[ok]] = zf[ok]
    return out


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
    z = np.asarray(depth_m, dtype=np.float32)
    valid = np.isfinite(z) & (z > 0.0)
    edge = np.zeros(z.shape, dtype=np.uint8)
    for axis in (1, 0):
        lo, hi = _pairs(axis)
        jump = (np.abs(z[hi] - z[lo]) > edge_threshold_m) & valid[lo] & valid[hi]
        edge[lo] |= jump
        edge[hi] |= jump
    win = np.ones((2 * width_px + 1, 2 * width_px + 1), dtype=np.uint8)
    if width_px > 1:
        edge = cv2.dilate(edge, np.ones((2 * width_px - 1, 2 * width_px - 1), dtype=np.uint8))
    idx = np.flatnonzero(edge.astype(bool) & valid)
    pick = idx[rng.random(idx.size) < probability]
    a = rng.random(pick.size, dtype=np.float32)
    fg = cv2.erode(np.where(valid, z, np.float32(np.inf)), win).ravel()[pick]
    bg = cv2.dilate(np.where(valid, z, np.float32(0.0)), win).ravel()[pick]
    out = z.copy()
    out.ravel()[pick] = fg + a * (bg - fg)
    return out


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
    for i in range(n):
        u0, u1 = max(0, int(np.ceil(cu[i] - a[i]))), min(w, int(np.floor(cu[i] + a[i])) + 1)
        v0, v1 = max(0, int(np.ceil(cv[i] - a[i]))), min(h, int(np.floor(cv[i] + a[i])) + 1)
        if u0 >= u1 or v0 >= v1:
            continue
        du = np.arange(u0, u1, dtype=np.float32)[None, :] - np.float32(cu[i])
        dv = np.arange(v0, v1, dtype=np.float32)[:, None] - np.float32(cv[i])
        c, s = np.float32(np.cos(ang[i])), np.float32(np.sin(ang[i]))
        inside = ((c * du + s * dv) / a[i]) ** 2 + ((c * dv - s * du) / b[i]) ** 2 <= 1.0
        out[v0:v1, u0:u1][inside] = 0.0
    return out
