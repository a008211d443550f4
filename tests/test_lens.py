"""hec.sim.lens: distorting pinhole RGB-D renders with OpenCV's Brown-Conrady model.

Ground truth is always OpenCV itself (cv2.projectPoints), never the module's own arithmetic."""

from functools import cache

import cv2
import numpy as np
import pytest

from hec.sim.lens import (
    depth_sampling,
    distort_depth,
    distort_rgb,
    distort_rgbd,
    distortion_maps,
    render_camera_for,
)

K_VGA = np.array([[615.0, 0.0, 322.5], [0.0, 612.0, 238.7], [0.0, 0.0, 1.0]])
K_HD = np.array([[920.0, 0.0, 641.3], [0.0, 918.0, 361.2], [0.0, 0.0, 1.0]])
NONE = (0.0, 0.0, 0.0, 0.0, 0.0)
BARREL = (-0.1, 0.05, 1e-3, -1e-3, 0.0)
PINCUSHION = (0.15, 0.05, -1e-3, 1e-3, 0.0)
STRONG_BARREL = (-0.3, 0.1, 1e-3, 1e-3, -0.01)
CAMERAS = {
    # name: (K_true, width, height, dist_true, oversample)
    "vga-none": (K_VGA, 640, 480, NONE, 1.0),
    "vga-barrel": (K_VGA, 640, 480, BARREL, 1.0),
    "vga-barrel-oversampled": (K_VGA, 640, 480, BARREL, 1.5),
    "vga-pincushion": (K_VGA, 640, 480, PINCUSHION, 1.0),
    "vga-strong-barrel": (K_VGA, 640, 480, STRONG_BARREL, 1.0),
    "hd-pincushion": (K_HD, 1280, 720, PINCUSHION, 1.0),
}


@cache
def _camera(
    name: str,
) -> tuple[np.ndarray, np.ndarray, int, int, np.ndarray, int, int, np.ndarray, np.ndarray]:
    K, W, H, dist, oversample = CAMERAS[name]
    dist = np.array(dist)
    K_r, W_r, H_r = render_camera_for(K, dist, W, H, oversample=oversample)
    map_x, map_y = distortion_maps(K, dist, W, H, K_r)
    return K, dist, W, H, K_r, W_r, H_r, map_x, map_y


def _project(xyz: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    uv, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), K, dist)
    return uv.reshape(-1, 2)


def _centroids(image: np.ndarray, starts: np.ndarray, radius: int = 6) -> np.ndarray:
    """Intensity centroids (N, 2) of the blobs near starts (N, 2), re-centring the window twice."""
    img = image.astype(np.float64)
    d = np.arange(-radius, radius + 1)
    c = starts.copy()
    for _ in range(3):
        iu, iv = np.rint(c).astype(int).T
        win = img[iv[:, None, None] + d[None, :, None], iu[:, None, None] + d[None, None, :]]
        mass = win.sum(axis=(1, 2))
        c = np.column_stack(
            [
                iu + (win * d[None, None, :]).sum(axis=(1, 2)) / mass,
                iv + (win * d[None, :, None]).sum(axis=(1, 2)) / mass,
            ]
        )
    return c


@pytest.mark.parametrize(
    "name, max_rms",
    [
        ("vga-none", 0.01),
        ("vga-barrel", 0.05),
        ("vga-barrel-oversampled", 0.015),
        ("vga-pincushion", 0.05),
        ("hd-pincushion", 0.05),
    ],
)
def test_dots_land_where_opencv_projects_them(name: str, max_rms: float) -> None:
    """Gaussian dots on a plane, drawn analytically into the pinhole render, are found after remapping
    where cv2.projectPoints(K_true, dist_true) puts their centres, up to the image corners. (Bilinear
    resampling of a render at ~1 px shifts centroids by a few 0.01 px; oversampling shrinks that.)"""
    K, dist, W, H, K_r, W_r, H_r, map_x, map_y = _camera(name)
    # Dots whose images lie on a grid reaching 8 px from every border (placement only, not the truth).
    gu, gv = np.meshgrid(np.linspace(8, W - 9, W // 24), np.linspace(8, H - 9, H // 24))
    seeds = np.column_stack([gu.ravel(), gv.ravel()]).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(seeds, K, dist).reshape(-1, 2)
    xyz = np.column_stack([xy, np.ones(len(xy))]) * 1.5  # plane z = 1.5 m
    truth = _project(xyz, K, dist)

    # The pinhole render: a Gaussian of sigma 1.5 output px at each dot's centre (exact for a
    # fronto-parallel plane), sampled per render pixel.
    sigma = 1.5 * K_r[0, 0] / K[0, 0]
    centres = xy * K_r[[0, 1], [0, 1]] + K_r[:2, 2]
    n = int(np.ceil(5 * sigma))
    render = np.zeros((H_r + 2 * n, W_r + 2 * n))  # padded by n all round
    d = np.arange(-n, n + 1)
    for cu, cv in centres:
        u0, v0 = int(round(cu)), int(round(cv))
        g = np.exp(-(((u0 + d)[None, :] - cu) ** 2 + ((v0 + d)[:, None] - cv) ** 2) / (2 * sigma**2))
        render[v0 : v0 + 2 * n + 1, u0 : u0 + 2 * n + 1] += g
    rgb = np.repeat(np.rint(250.0 * render[n:-n, n:-n]).astype(np.uint8)[:, :, None], 3, axis=2)

    image = distort_rgb(rgb, map_x, map_y)
    assert image.shape == (H, W, 3) and image.dtype == np.uint8
    err = np.linalg.norm(_centroids(image[:, :, 1], truth) - truth, axis=1)
    rms, worst = float(np.sqrt(np.mean(err**2))), float(err.max())
    print(f"{name}: {len(err)} dots, RMS {rms:.4f} px, max {worst:.4f} px")
    assert rms < max_rms and worst < 0.15
    corners = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]])
    assert (np.linalg.norm(truth[None] - corners[:, None], axis=2).min(axis=1) < 12).all()


def test_no_distortion_is_a_change_of_K() -> None:
    K, dist, W, H, K_r, W_r, H_r, map_x, map_y = _camera("vga-none")
    assert K_r[0, 0] == K[0, 0] and K_r[1, 1] == K[1, 1]
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    np.testing.assert_allclose(map_x, u - K[0, 2] + K_r[0, 2], atol=1e-4)
    np.testing.assert_allclose(map_y, v - K[1, 2] + K_r[1, 2], atol=1e-4)


@pytest.mark.parametrize("name", ["vga-barrel", "vga-strong-barrel", "hd-pincushion"])
def test_maps_invert_opencv_projection(name: str) -> None:
    """Each map entry is the pinhole image of the ray cv2.projectPoints sends to that output pixel."""
    K, dist, W, H, K_r, W_r, H_r, map_x, map_y = _camera(name)
    u, v = np.meshgrid(np.r_[0 : W - 1 : 5, W - 1], np.r_[0 : H - 1 : 5, H - 1])  # borders included
    xy = (np.column_stack([map_x[v, u].ravel(), map_y[v, u].ravel()]) - K_r[:2, 2]) / K_r[[0, 1], [0, 1]]
    uv = _project(np.column_stack([xy, np.ones(len(xy))]), K, dist)
    assert np.abs(uv - np.column_stack([u.ravel(), v.ravel()])).max() < 2e-3


@pytest.mark.parametrize("name", list(CAMERAS))
def test_render_covers_every_pixel_densely_enough(name: str) -> None:
    K, dist, W, H, K_r, W_r, H_r, map_x, map_y = _camera(name)
    margin = 2.5 - 1e-3  # margin_px + half an output pixel (>= 0.5 render px): rays through pixel edges
    assert map_x.min() > margin and map_x.max() < W_r - 1 - margin
    assert map_y.min() > margin and map_y.max() < H_r - 1 - margin
    assert distort_rgb(np.full((H_r, W_r, 3), 255, np.uint8), map_x, map_y).min() == 255
    # One output pixel step spans >= 1 render pixel in every direction (render at least as dense).
    (a, b), (c, d) = (np.gradient(m.astype(np.float64), axis=(1, 0)) for m in (map_x, map_y))
    frob2, det = a * a + b * b + c * c + d * d, a * d - b * c
    sigma_min = np.sqrt((frob2 - np.sqrt(frob2 * frob2 - 4.0 * det * det)) / 2.0)  # of [[a, b], [c, d]]
    assert sigma_min.min() > 1.0 - 1e-3
    # ... and not needlessly denser: the focal length only grows for pincushion distortion.
    assert (K_r[0, 0] / K[0, 0] / CAMERAS[name][4] > 1.1) == ("pincushion" in name)


def test_depth_never_mixes_across_edges_or_holes() -> None:
    K, dist, W, H, K_r, W_r, H_r, map_x, map_y = _camera("vga-barrel")
    u, v = np.meshgrid(np.arange(W_r, dtype=np.float32), np.arange(H_r, dtype=np.float32))
    near = 1.0 + 1e-3 * u  # tilted plane, 1.0 .. 1.67 m
    far = v > 0.4 * u + 150.0  # behind a slanted step edge: a wall at 2 m
    hole = (np.abs(u - 330) < 40) & (np.abs(v - 200) < 25)  # invalid pixels
    depth_r = np.where(far, np.float32(2.0), near)
    depth_r[hole] = 0.0
    rgb, depth = distort_rgbd(np.zeros((H_r, W_r, 3), np.uint8), depth_r, map_x, map_y)
    assert rgb.shape == (H, W, 3) and depth.shape == (H, W) and depth.dtype == np.float32
    assert ((depth == 0.0) | ((depth >= 1.0) & (depth <= near.max())) | (depth == 2.0)).all()
    assert (depth == 0.0).any() and (depth == 2.0).any()

    # Where the 4 bilinear neighbours differ, the value is one of theirs (nearest); on the plane, far
    # from the edge and the hole, it is bilinear (nearest would miss the plane by up to 5e-4 m).
    x0, y0 = np.floor(map_x).astype(int), np.floor(map_y).astype(int)
    region = np.where(hole, 2, far.astype(int))
    quad = [(depth_r[y0 + i, x0 + j], region[y0 + i, x0 + j]) for i in (0, 1) for j in (0, 1)]
    mixed = np.any([r != quad[0][1] for _, r in quad], axis=0)
    assert mixed.sum() > 100
    assert np.any([depth[mixed] == z[mixed] for z, _ in quad], axis=0).all()
    inner = cv2.erode((region == 0).astype(np.uint8), np.ones((7, 7), np.uint8))[y0, x0].astype(bool)
    assert inner.mean() > 0.5
    # Exact bilinear: a plane linear in u is reproduced to float32 rounding (OpenCV's remap, which
    # quantises the sampling point to 1/32 px, missed it by up to 3e-5 m).
    np.testing.assert_allclose(depth[inner], 1.0 + 1e-3 * map_x[inner].astype(np.float64), atol=5e-7)


def test_depth_sampling_refuses_a_render_of_another_size() -> None:
    K, dist, W, H, K_r, W_r, H_r, map_x, map_y = _camera("vga-barrel")
    sampling = depth_sampling(map_x, map_y, (H_r, W_r))
    assert sampling.shape == (H, W) and sampling.render_shape == (H_r, W_r)
    assert (sampling.nearest >= 0).all()  # the render's margin holds every map point
    with pytest.raises(ValueError, match="sampling is for"):
        distort_depth(np.ones((H_r - 1, W_r), np.float32), sampling)
    # A map point beyond the render's pixel centres gives an invalid pixel, not a read past the render.
    outside = depth_sampling(map_x + W_r, map_y, (H_r, W_r))
    assert (distort_depth(np.ones((H_r, W_r), np.float32), outside) == 0.0).all()
