"""The z-buffer of a point set (fusion/render/zbuffer.py) against the analytic depth of a tilted plane."""

from __future__ import annotations

import numpy as np

from fusion.render.zbuffer import zbuffer

W, H, F = 100, 80, 100.0


def tilted_plane(n_side: int) -> np.ndarray:
    """Points of the plane z = 2 + 0.5 x on a regular grid (x in ±1.5 m, y in ±1.2 m)."""
    xs, ys = np.meshgrid(np.linspace(-1.5, 1.5, n_side), np.linspace(-1.2, 1.2, n_side))
    return np.column_stack([xs.ravel(), ys.ravel(), 2.0 + 0.5 * xs.ravel()])


def test_zbuffer_of_a_tilted_plane_is_its_nearest_sample_per_pixel() -> None:
    plane = tilted_plane(601)
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    depth = zbuffer(plane, np.eye(4), K, W, H)
    u = np.tile(np.arange(W, dtype=np.float64), (H, 1))
    left = 2.0 / (1 - 0.5 * (u - W / 2) / F)  # z = 2 + 0.5 x with x = z (u − cx) / f, at the pixel's left edge
    # the nearest sample in the pixel: at most one sample step (5 mm in x → 2.5 mm in z) beyond the left edge
    assert (depth >= left - 1e-9).all() and (depth <= left + 2.6e-3).all()


def test_zbuffer_keeps_the_nearest_point_and_leaves_empty_and_behind_pixels_at_zero() -> None:
    K = np.array([[10.0, 0, 2.0], [0, 10.0, 2.0], [0, 0, 1]])
    # two points in pixel (row 2, col 2) at z = 3 and 2, one behind the camera, one outside the image
    points = np.array([[0.05, 0.05, 3.0], [0.02, 0.02, 2.0], [0.0, 0.0, -1.0], [10.0, 0.0, 1.0]])
    depth = zbuffer(points, np.eye(4), K, 4, 4)
    expected = np.zeros((4, 4))
    expected[2, 2] = 2.0
    np.testing.assert_array_equal(depth, expected)
    shifted = np.eye(4)
    shifted[:3, 3] = [0.0, 0.0, 1.0]  # the camera 1 m behind: every depth + 1
    expected[2, 2] = 3.0  # both still land in pixel (2, 2); the one behind is now at z = 0: still left out
    np.testing.assert_array_equal(zbuffer(points, shifted, K, 4, 4), expected)
