"""Pixels at infinity (no parallax between neighbouring photos) against an analytic scene with exact truth: a
textured square on z = 0 in front of an environment that depends on the ray's direction only (as data_synth's
sky and distant ground do), seen by three cameras side by side; and a blank square, which agrees with every depth."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from classify.masks import MaskOptions, SeenInView, at_infinity, photo_mask
from core.cameras import Camera, Cameras, View
from data_synth.rig import look_at

W, H, F = 120, 90, 100.0
HALF = 0.4  # the square's half side (metres)


def _environment(d: np.ndarray) -> np.ndarray:
    az, el = np.arctan2(d[:, 1], d[:, 0]), np.arcsin(np.clip(d[:, 2], -1, 1))
    return np.stack([128 + 60 * np.sin(13 * az + 3 * el), 128 + 50 * np.sin(17 * el - 5 * az),
                     128 + 40 * np.sin(11 * az) * np.cos(7 * el)], axis=1)  # fmt: skip


def _square(p: np.ndarray) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    return np.stack([120 + 70 * np.sin(9.1 * x + 3.7 * y), 110 + 60 * np.sin(7.3 * y - 4.9 * x),
                     100 + 50 * np.sin(5.3 * x) * np.cos(6.1 * y)], axis=1)  # fmt: skip


def _render(cams: Cameras, view: View, blank: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 photo and (H, W) bool truth "the ray misses the square" (it sees the environment); with
    ``blank`` the square is uniform grey (a textureless surface)."""
    rows, cols = np.mgrid[0:H, 0:W]
    pix = np.c_[cols.ravel() + 0.5, rows.ravel() + 0.5]
    d = cams.camera_of(view).unproject(pix, 1.0) @ view.rotation
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = view.center
    t = np.where(d[:, 2] < 0, -c[2] / np.minimum(d[:, 2], -1e-12), np.inf)
    p = c + t[:, None] * d
    hit = np.isfinite(t) & (np.abs(p[:, 0]) <= HALF) & (np.abs(p[:, 1]) <= HALF)
    square = np.full((len(d), 3), 128.0) if blank else _square(np.where(hit[:, None], p, 0.0))
    rgb = np.where(hit[:, None], square, _environment(d))
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8).reshape(H, W, 3), ~hit.reshape(H, W)


def _block(blank: bool = False) -> tuple[Cameras, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """v1 in the middle, v0 / v2 0.3 m to its sides, v3 / v4 0.3 m above and below it, all aimed at the square."""
    cam = Camera.pinhole(F, F, W / 2, H / 2, W, H)
    centres = [(-0.3, -0.9, 0.45), (0.0, -0.9, 0.45), (0.3, -0.9, 0.45), (0.0, -0.9, 0.75), (0.0, -0.9, 0.15)]
    views = {}
    for i, c in enumerate(centres):
        m = look_at(np.array(c), np.array([0.0, 0.0, 0.1]))
        views[i + 1] = View.from_matrix(i + 1, f"v{i}.png", 1, m)
    cams = Cameras({1: cam}, views)
    photos, backdrop = {}, {}
    for v in cams:
        photos[v.name], backdrop[v.name] = _render(cams, v, blank)
    return cams, photos, backdrop


def test_at_infinity_finds_the_environment_and_never_the_finite_square():
    cams, photos, backdrop = _block()
    view = cams.by_name("v1.png")
    inf = at_infinity(cams, view, photos.__getitem__)
    bg = backdrop["v1.png"]
    assert 0.15 < bg.mean() < 0.85  # the photo shows both
    # Inside the window, away from the photo's border and the square's outline (resampling, occlusion at edges).
    interior = np.zeros_like(bg)
    interior[4:-4, 4:-4] = True
    far_from_edge = ndimage.binary_erosion(bg, iterations=4) & interior
    assert inf[far_from_edge].mean() > 0.9
    assert not inf[~bg].any()  # the square is about 1 m away, 0.3 m baselines: ~30 px of parallax


def test_a_blank_surface_agrees_with_every_depth_and_is_not_called_infinity():
    """A uniform square agrees with its neighbours at infinity as well as at its own depth: the photos cannot say
    where it is. Given a finite depth to compare with (the view's points lie about 1 m away), only the textured
    environment, which disagrees there, stays at infinity."""
    cams, photos, backdrop = _block(blank=True)
    view = cams.by_name("v1.png")
    bg = backdrop["v1.png"]
    interior = np.zeros_like(bg)
    interior[4:-4, 4:-4] = True
    # Away from the square's outline, where the comparison window straddles square and environment.
    inside_square = ndimage.binary_erosion(~bg, iterations=8) & interior
    far_from_edge = ndimage.binary_erosion(bg, iterations=4) & interior
    assert inside_square.sum() > 300
    plain = at_infinity(cams, view, photos.__getitem__)
    assert plain[inside_square].mean() > 0.9  # the parallax test alone calls the blank square infinity
    depth = float(np.linalg.norm(view.center - np.array([0.0, 0.0, 0.1])))
    decided = at_infinity(cams, view, photos.__getitem__, finite_depth=depth)
    assert not decided[inside_square].any()
    assert decided[far_from_edge].mean() > 0.9
    # The textured square's block: the finite depth changes nothing where the parallax test could decide.
    cams, photos, backdrop = _block()
    textured = at_infinity(cams, view, photos.__getitem__, finite_depth=depth)
    assert textured[ndimage.binary_erosion(backdrop["v1.png"], iterations=4) & interior].mean() > 0.9
    assert not textured[~backdrop["v1.png"]].any()


def test_at_infinity_needs_a_neighbour():
    cams, photos, _ = _block()
    alone = Cameras({1: cams.camera_of(cams.by_name("v1.png"))}, {2: cams.by_name("v1.png")})
    assert not at_infinity(alone, cams.by_name("v1.png"), photos.__getitem__).any()
    # Neighbours looking the other way (optical axes 180° apart) are not used either.
    turned = {}
    for v in cams:
        r = np.diag([-1.0, 1.0, -1.0]) @ v.rotation  # turned by 180° about its own y axis
        turned[v.image_id] = View.from_matrix(v.image_id, v.name, 1, np.c_[r, -r @ v.center])
    turned[2] = cams.by_name("v1.png")
    assert not at_infinity(Cameras(dict(cams.cameras), turned), turned[2], photos.__getitem__).any()


def test_the_environment_beside_the_reconstructed_square_is_no_hole_but_a_missing_patch_is():
    """MVS reconstructed the square (dense points, every one seen) except a 24 cm patch. Without the parallax test
    the environment below the cloud's upper envelope reads as unreconstructed surface (a hole); with it, it does
    not, and the missing patch (a finite surface) stays a hole."""
    cams, photos, backdrop = _block()
    g = np.arange(-HALF, HALF + 1e-9, 0.01)
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    patch = (np.abs(pts[:, 0]) < 0.12) & (np.abs(pts[:, 1] + 0.1) < 0.12)
    colors = np.clip(np.round(_square(pts)), 0, 255).astype(np.uint8)
    seen = SeenInView(None, colors[~patch], photos.__getitem__)
    view = cams.by_name("v1.png")

    def holes(infinity: bool) -> np.ndarray:
        opts = MaskOptions(
            close_px=0, dilate_px=0, dilate_spacings=0, grow_area=0, infinity=infinity, hole_area="hull_below"
        )
        return photo_mask(cams, view, pts[~patch], np.zeros(int((~patch).sum()), bool), 0.01, opts, seen=seen).mask

    with_test, without = holes(True), holes(False)
    bg = backdrop["v1.png"]
    uv, _ = cams.project(view, pts[patch])
    missing = np.zeros_like(bg)
    missing[uv[:, 1].astype(int), uv[:, 0].astype(int)] = True
    missing = ndimage.binary_erosion(ndimage.binary_closing(missing, iterations=2), iterations=3)  # its inside
    assert missing.sum() > 20
    assert without[missing].mean() > 0.75 and np.array_equal(with_test[missing], without[missing])
    assert (without & bg).sum() > 300  # the environment below the envelope
    # What stays lies along the square's outline and the photo's border (the 5 × 5 comparison window straddles
    # them, and the square hides the backdrop next to it from the neighbours).
    near = ndimage.binary_dilation(~bg, iterations=4)
    near[:4], near[-4:], near[:, :4], near[:, -4:] = True, True, True, True
    assert not (with_test & bg & ~near).any() and (with_test & bg).sum() < 0.5 * (without & bg).sum()
