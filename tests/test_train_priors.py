"""Depth / normal priors from the trusted MVS surface around a region, against analytic planes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError
from fusion.train.params import make_parameters
from fusion.train.priors import PriorOptions, depth_normals, prior_loss, view_priors, zbuffer
from fusion.train.views import prepare_views

W, H, F = 100, 80, 100.0


def one_camera() -> Cameras:
    """Camera at the origin looking down +z (identity pose), 100×80 px, focal 100, principal point (50, 40)."""
    cam = Camera.pinhole(F, F, W / 2, H / 2, W, H)
    return Cameras({1: cam}, {1: View(1, "a.png", 1, np.array([1.0, 0, 0, 0]), np.zeros(3))})


def tilted_plane(n_side: int = 301) -> tuple[np.ndarray, np.ndarray]:
    """Points of the plane z = 2 + 0.5 x (normal ∝ (0.5, 0, −1) towards the camera) and its unit normal."""
    xs, ys = np.meshgrid(np.linspace(-1.5, 1.5, n_side), np.linspace(-1.2, 1.2, n_side))
    pts = np.column_stack([xs.ravel(), ys.ravel(), 2.0 + 0.5 * xs.ravel()])
    n = np.array([0.5, 0.0, -1.0])
    return pts, n / np.linalg.norm(n)


def hole_mask() -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[25:55, 35:65] = True
    return m


def plane_view(options: PriorOptions):
    """One training view of the tilted plane with an MVS hole behind the mask; the view's prior."""
    cams = one_camera()
    plane, normal = tilted_plane()
    uv, _ = cams.project(cams.views[1], plane)
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    mask = hole_mask()
    inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    hole = np.zeros(len(plane), bool)
    hole[inside] = mask[row[inside], col[inside]]
    image = np.full((H, W, 3), 0.5, np.float32)
    views = prepare_views(cams, {"a.png": image}, {"a.png": mask}, np.zeros(3), holdout_fraction=0.0)
    return views[0], view_priors(views, plane[~hole], options)[0], normal, plane


def test_zbuffer_and_normals_of_a_tilted_plane_are_exact() -> None:
    plane, normal = tilted_plane(601)
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    depth = zbuffer(plane, np.eye(4), K, W, H)
    u = np.tile(np.arange(W, dtype=np.float64), (H, 1))
    left = 2.0 / (1 - 0.5 * (u - W / 2) / F)  # z = 2 + 0.5 x with x = z (u − cx) / f, at the pixel's left edge
    # the nearest sample in the pixel: at most one sample step (5 mm in x → 2.5 mm in z) beyond the left edge
    assert (depth >= left - 1e-9).all() and (depth <= left + 2.6e-3).all()
    exact = 2.0 / (1 - 0.5 * (u + 0.5 - W / 2) / F)
    normals = depth_normals(exact, K)
    inner = normals[1:-1, 1:-1].reshape(-1, 3)
    np.testing.assert_allclose(inner, np.tile(normal, (len(inner), 1)), atol=1e-9)
    assert not normals[0].any() and not normals[:, -1].any()  # border pixels have no central difference


def test_view_prior_interpolates_the_plane_into_the_hole_and_decays_from_the_border() -> None:
    _, prior, normal, _ = plane_view(PriorOptions(border_px=4.0, edge_scale=None))
    mask = hole_mask()
    w = prior.weight.numpy()
    assert (w[~mask] == 0).all() and prior.pixels == int((w > 0).sum()) > 0
    # weight: exp(-d / 4) by the distance to the edge (row 40 of the mask: pixels 35.. are 1, 2, 3 ... from it)
    assert w[40, 35] > w[40, 37] > w[40, 39] > 0
    assert w[40, 35] == pytest.approx(math.exp(-1 / 4), rel=0.05) and w[40, 50] == 0  # 15 px > 3 · 4 px: off
    u = np.arange(W) + 0.5
    exact = 2.0 / (1 - 0.5 * (u - W / 2) / F)
    rows, cols = np.nonzero(w > 0)
    # the first-order fit is exact on a plane; what remains is the z-buffer's quantisation (the nearest sample in
    # each pixel: up to half a pixel's depth change, ~4.5 mm on this ramp)
    np.testing.assert_allclose(prior.depth.numpy()[rows, cols], exact[cols], atol=5e-3)
    cos = prior.normal.numpy()[rows, cols] @ normal
    assert cos.min() > 0.99 and np.median(cos) > 0.9999  # facing the camera like the plane normal


def test_edge_aware_weight_falls_on_image_edges() -> None:
    cams = one_camera()
    plane, _ = tilted_plane()
    mask = hole_mask()
    image = np.full((H, W, 3), 0.5, np.float32)
    image[:, 36:] = 0.9  # a vertical edge between columns 35 and 36, inside the mask's border strip
    views = prepare_views(cams, {"a.png": image}, {"a.png": mask}, np.zeros(3), holdout_fraction=0.0)
    flat = view_priors(views, plane, PriorOptions(edge_scale=None))[0].weight.numpy()
    aware = view_priors(views, plane, PriorOptions(edge_scale=0.1))[0].weight.numpy()
    assert aware[40, 35] < 0.2 * flat[40, 35]  # on the edge
    assert aware[40, 40] == pytest.approx(flat[40, 40])  # away from it


def splat_params(means: np.ndarray, quats: np.ndarray | None = None) -> dict[str, torch.nn.Parameter]:
    n = len(means)
    q = np.tile([1.0, 0, 0, 0], (n, 1)) if quats is None else quats
    scales = np.tile(np.log([0.01, 0.01, 0.001]), (n, 1))  # smallest axis = z
    return make_parameters(
        {
            "means": torch.tensor(means, dtype=torch.float32),
            "quats": torch.tensor(q, dtype=torch.float32),
            "log_scales": torch.tensor(scales, dtype=torch.float32),
            "logit_opacities": torch.zeros(n),
            "sh_dc": torch.zeros((n, 1, 3)),
            "sh_rest": torch.zeros((n, 0, 3)),
        }
    )


def test_prior_loss_pulls_border_splats_onto_the_surface_and_ignores_the_rest() -> None:
    opts = PriorOptions(border_px=4.0, edge_scale=None, normal_weight=0.0)
    view, prior, _, _ = plane_view(opts)
    # pixel (40.5, 40.5) is in the mask's border strip (5 px in); (50.5, 40.5) is 15 px > 3 · 4 px in (weight 0)
    z_ray = 2.0 / (1 - 0.5 * (40.5 - 50) / F)  # the plane's depth on the ray of pixel (40.5, 40.5)
    border = np.array([-0.095, 0.005, 1.0]) * (z_ray * 1.1)  # 10 % behind the surface on that ray
    centre = np.array([0.005, 0.005, 1.0]) * 2.5
    params = splat_params(np.stack([border, centre]))
    opt = torch.optim.Adam([params["means"]], lr=0.005)
    first = prior_loss(params, view, prior, opts)
    assert first.splats == 1 and float(first.depth) == pytest.approx(math.log(1.1), abs=3e-3)
    for _ in range(200):
        terms = prior_loss(params, view, prior, opts)
        assert terms.splats == 1
        opt.zero_grad()
        terms.loss.backward()
        assert params["means"].grad[1].abs().max() == 0  # no prior where the weight is 0
        assert params["means"].grad[0, :2].abs().max() == 0  # the camera is at the origin: only z moves
        opt.step()
    # x is fixed, so the splat ends where the vertical line x = const meets the plane z = 2 + 0.5 x
    x, z = params["means"].detach().numpy()[0, [0, 2]]
    assert abs(z - (2.0 + 0.5 * x)) < 5e-3  # the prior's quantisation (see above), from 0.19 m off
    assert float(terms.depth) < 3e-3


def test_normal_term_aligns_the_flat_axis_with_the_surface_normal() -> None:
    opts = PriorOptions(border_px=6.0, edge_scale=None, depth_weight=0.0, normal_weight=1.0)
    view, prior, normal, _ = plane_view(opts)
    z_true = 2.0 / (1 - 0.5 * (36.5 - 50) / F)
    params = splat_params(np.array([[-0.135, 0.005, 1.0]]) * z_true)
    opt = torch.optim.Adam([params["quats"]], lr=0.02)
    for _ in range(200):
        terms = prior_loss(params, view, prior, opts)
        opt.zero_grad()
        terms.loss.backward()
        opt.step()
    from fusion.train.priors import splat_axes

    axis = splat_axes(params["quats"].detach(), params["log_scales"].detach())[0].numpy()
    # started at the z axis (cos 0.894 with the plane normal), ends aligned with it
    assert abs(axis @ normal) > 0.999 and float(terms.normal) < 1e-3


def test_bad_prior_options_are_config_errors() -> None:
    with pytest.raises(ConfigError):
        PriorOptions(depth_weight=-1.0)
    with pytest.raises(ConfigError):
        PriorOptions(border_px=0.0)
    with pytest.raises(ConfigError):
        PriorOptions(band_px=0)
    assert not PriorOptions(depth_weight=0.0, normal_weight=0.0).active


def test_hull_test_keeps_a_flush_region_and_drops_the_background_behind_a_standing_object() -> None:
    """Two cameras looking down +z, the second 0.4 m to the side. A region flush with the plane z = 2 is masked in
    both views where it projects: its interpolated prior (the plane) is right and kept. An object standing at z = 1
    is masked where *it* projects: the plane behind it, its interpolated prior, lands outside its mask in the other
    view and is dropped."""
    cam = Camera.pinhole(F, F, W / 2, H / 2, W, H)
    views = {
        1: View(1, "a.png", 1, np.array([1.0, 0, 0, 0]), np.zeros(3)),
        2: View(2, "b.png", 1, np.array([1.0, 0, 0, 0]), np.array([-0.4, 0.0, 0.0])),  # centre (0.4, 0, 0)
    }
    cams = Cameras({1: cam}, views)
    xs, ys = np.meshgrid(np.linspace(-2.0, 2.0, 801), np.linspace(-1.2, 1.2, 481))
    plane = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 2.0)])

    def masks_of(corners_x: tuple[float, float], z: float) -> dict[str, np.ndarray]:
        """Masks of the square x in corners_x, |y| <= 0.1 at depth z, as each view sees it."""
        out = {}
        for v in cams:
            m = np.zeros((H, W), bool)
            c = -v.translation  # identity rotations: the centre is −t
            u0, u1 = (int(np.floor(W / 2 + F * (x - c[0]) / z)) for x in corners_x)
            v0, v1 = (int(np.floor(H / 2 + F * yy / z)) for yy in (-0.1, 0.1))
            m[max(v0, 0) : v1, max(u0, 0) : u1] = True
            out[v.name] = m
        return out

    grey = {v.name: np.full((H, W, 3), 0.5, np.float32) for v in cams}
    for case, masks, expect_kept in (("flush", masks_of((-0.2, 0.2), 2.0), True),
                                     ("standing", masks_of((-0.1, 0.1), 1.0), False)):  # fmt: skip
        views_t = prepare_views(cams, grey, masks, np.zeros(3), holdout_fraction=0.0)
        uv, _ = cams.project(cams.views[1], plane)
        col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        ok = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        hidden = np.zeros(len(plane), bool)
        hidden[ok] = masks["a.png"][row[ok], col[ok]]  # no trusted depth behind view a's mask (an MVS hole)
        trusted = plane[~hidden] if case == "flush" else plane
        plain = view_priors(views_t, trusted, PriorOptions(edge_scale=None, hull_share=None))[0]
        hull = view_priors(views_t, trusted, PriorOptions(edge_scale=None, hull_share=0.8))[0]
        assert plain.pixels > 50, case
        assert (hull.pixels == plain.pixels) if expect_kept else (hull.pixels == 0), (case, hull.pixels, plain.pixels)
