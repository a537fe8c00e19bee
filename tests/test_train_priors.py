"""Depth / normal priors from the trusted MVS surface around a region, against analytic planes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError
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


def test_prior_loss_pulls_the_rendered_depth_onto_the_surface_where_it_has_weight() -> None:
    """The per-pixel prior on a rendered depth map (here a free parameter): log-L1 to the interpolated plane over the
    prior's border strip only, with no gradient where the weight is 0 or the rendered depth is invalid."""
    opts = PriorOptions(border_px=4.0, edge_scale=None, normal_weight=0.0)
    view, prior, _, _ = plane_view(opts)
    has = prior.weight > 0
    assert has[40, 40] and not has[40, 50]  # 5 px inside the mask's edge / 15 px > 3 · 4 px in (weight 0)
    depth = torch.nn.Parameter(torch.where(has, prior.depth, torch.full_like(prior.depth, 2.0)) * 1.1)
    valid = torch.ones(H, W, dtype=torch.bool)
    valid[40, 41] = False
    normal = torch.zeros(H, W, 3)
    first = prior_loss(normal, depth, valid, view, prior, opts)
    assert first.pixels == int(has.sum()) - 1 and float(first.depth) == pytest.approx(math.log(1.1), rel=1e-4)
    opt = torch.optim.Adam([depth], lr=0.01)
    for _ in range(100):
        terms = prior_loss(normal, depth, valid, view, prior, opts)
        opt.zero_grad()
        terms.loss.backward()
        assert depth.grad[~has].abs().max() == 0 and depth.grad[40, 41] == 0
        opt.step()
    assert float(terms.depth) < 2e-3
    assert float(prior_loss(normal, depth, torch.zeros_like(valid), view, prior, opts).loss) == 0.0


def test_normal_term_turns_the_rendered_normal_to_the_surface_normal() -> None:
    opts = PriorOptions(border_px=6.0, edge_scale=None, depth_weight=0.0, normal_weight=1.0)
    view, prior, normal, _ = plane_view(opts)
    # the rendered normal (camera frame = training frame here: identity pose, centre 0), premultiplied by alpha 0.8
    rendered = torch.nn.Parameter(torch.tensor([0.0, 0.0, -0.8]).expand(H, W, 3).clone())
    depth = torch.full((H, W), 2.0)
    opt = torch.optim.Adam([rendered], lr=0.02)
    start = prior_loss(rendered, depth, torch.ones(H, W, dtype=torch.bool), view, prior, opts)
    assert float(start.normal) == pytest.approx(1 - abs(normal[2]), abs=1e-3)  # cos 0.894: prior normal to ~1e-3
    for _ in range(150):
        terms = prior_loss(rendered, depth, torch.ones(H, W, dtype=torch.bool), view, prior, opts)
        opt.zero_grad()
        terms.loss.backward()
        opt.step()
    n = rendered.detach()[40, 40].numpy()
    assert n @ normal / np.linalg.norm(n) > 0.999 and float(terms.normal) < 1e-3


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
