"""fusion.mesh.tsdf: TSDF fusion of depth rendered from Gaussians; truth: the analytic sphere the surfels lie on."""

import numpy as np
import pytest
from mesh_shapes import fibonacci_sphere, sphere_distance, sphere_gaussians

from core.cameras import Camera, Cameras, View
from core.errors import ConfigError, DataError
from fusion.mesh.quality import mesh_quality
from fusion.mesh.tsdf import TSDFOptions, tsdf_mesh

R = 0.5


def look_at_cameras(
    centres: np.ndarray, size: int = 64, origin: np.ndarray | None = None, target: np.ndarray | None = None
) -> Cameras:
    """Pinhole views (60° field of view) at ``centres`` looking at ``target`` (default 0), both relative to
    ``origin``; OpenCV axes (x right, y down, z forward)."""
    f = size / (2 * np.tan(np.radians(30)))
    cam = Camera.pinhole(f, f, size / 2, size / 2, size, size)
    views = {}
    for i, c in enumerate(centres, start=1):
        z = (np.zeros(3) if target is None else target) - c
        z = z / np.linalg.norm(z)
        x = np.cross(z, [0, 0, 1.0])
        x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0, 0])
        y = np.cross(z, x)
        rot = np.stack([x, y, z])  # rows: camera axes in world
        views[i] = View.from_matrix(i, f"v{i}.png", 1, np.c_[rot, -rot @ c])
    return Cameras({1: cam}, views, np.zeros(3) if origin is None else origin)


def test_tsdf_of_a_rendered_sphere_lies_on_the_sphere():
    g = sphere_gaussians(1500, R)  # σ = 0.6 × spacing = 2.7 cm
    sigma = float(g.scales[0, 0])
    cams = look_at_cameras(fibonacci_sphere(10, 1.6), size=48)
    mesh = tsdf_mesh(g, cams, TSDFOptions(voxel_size=0.0075))
    signed = np.linalg.norm(mesh.vertices, axis=1) - R
    # Truth for the bias: the renderer's own depth, back-projected, lies behind the convex surface by a fraction of
    # σ (alpha-blended depth of the means); the TSDF surface must agree with it within a voxel, and both stay
    # within σ / 2 of the sphere.
    from fusion.render.scene import render_gaussian_set

    view = next(iter(cams))
    cam = cams.camera_of(view)
    out = render_gaussian_set(g, cam, view)
    rows, cols = np.nonzero(out.alpha.numpy() > 0.9)
    z = out.depth.numpy()[rows, cols]
    (fx, fy), (cx, cy) = cam.focal, cam.principal_point
    pts = view.camera_to_world(np.c_[(cols + 0.5 - cx) / fx * z, (rows + 0.5 - cy) / fy * z, z])
    rendered_bias = np.median(np.linalg.norm(pts, axis=1) - R)
    assert abs(np.median(signed) - rendered_bias) < 0.0075
    assert abs(np.median(signed)) < sigma / 2 and np.percentile(np.abs(signed), 95) < sigma
    q = mesh_quality(mesh)
    assert q.triangles > 1000 and q.degenerate_triangles == 0
    assert np.median(np.abs(mesh.vertex_colors - [0.8, 0.4, 0.2])) < 0.01  # the rendered SH DC colour


def test_tsdf_keeps_world_coordinates_at_a_utm_origin():
    """Gaussians and cameras both at a UTM origin (different ones): the mesh is in the Gaussians' frame."""
    utm = np.array([500_000.0, 5_000_000.0, 300.0])
    g = sphere_gaussians(1500, R)
    g.origin = utm
    centres = np.array([[1.6, 0, 0.3], [0, 1.6, 0.3], [-1.6, 0, 0.3], [0, -1.6, 0.3], [0.2, 0.1, 1.6]])
    cams_origin = utm + [10.0, -20.0, 5.0]
    shift = np.array([10.0, -20.0, 5.0])
    cams = look_at_cameras(centres - shift, size=48, origin=cams_origin, target=-shift)
    mesh = tsdf_mesh(g, cams, TSDFOptions(voxel_size=0.02))
    assert np.array_equal(mesh.origin, utm)
    assert np.median(sphere_distance(mesh.vertices, R)) < 0.02  # within a voxel: frames line up


def test_bad_input():
    g = sphere_gaussians(200, R)
    with pytest.raises(DataError, match="at least one camera"):
        tsdf_mesh(g, Cameras({}, {}, np.zeros(3)))
    away = look_at_cameras(np.array([[1.6, 0, 0.2]]), size=16)
    faint = g.subset(slice(None))
    faint.logit_opacities[:] = -8.0
    with pytest.raises(DataError, match="reached opacity"):
        tsdf_mesh(faint, away)
    with pytest.raises(ConfigError):
        TSDFOptions(min_alpha=0.0)
