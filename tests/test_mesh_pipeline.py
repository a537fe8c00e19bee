"""fusion.mesh.pipeline and transparent: the whole chain on a sphere whose cap is "glass" (faint, sparse splats);
early-iteration snapshots close the hole the MVS-only mesh leaves. Truth: the analytic sphere."""

import numpy as np
import pytest
from mesh_shapes import (
    distance_to_mesh,
    fibonacci_sphere,
    mesh_surface_samples,
    sphere_distance,
    surfels,
)

from core.errors import ConfigError, DataError
from core.gaussians import GaussianSet
from fusion.convert import Source
from fusion.mesh.pipeline import MeshOptions, MeshSource, mesh_from_gaussians
from fusion.mesh.transparent import SnapshotOptions, snapshot_union

R = 0.5
CAP_Z = 0.25  # z above this is glass
TAU = 0.01  # completeness threshold (m), about a third of the MVS point spacing


def glass_scene() -> tuple[GaussianSet, list[GaussianSet], np.ndarray]:
    """Merged set (MVS surfels below the cap, 1/10 as many faint splats on it), 3 snapshots, camera centres."""
    rng = np.random.default_rng(0)
    pts = fibonacci_sphere(3000, R)
    spacing = R * np.sqrt(4 * np.pi / 3000)
    mvs_pts = pts[pts[:, 2] <= CAP_Z]
    mvs = surfels(mvs_pts, mvs_pts / R, sigma=0.6 * spacing, source=Source.MVS)
    cap = pts[pts[:, 2] > CAP_Z]
    sparse = cap[::10]
    signs = np.where(rng.random(len(sparse)) < 0.5, -1.0, 1.0)[:, None]
    splats = surfels(sparse, sparse / R * signs, sigma=spacing, alpha=0.03, source=Source.SPLAT)
    merged = GaussianSet.concatenate([mvs, splats])
    snapshots = []
    for k in range(3):  # early iterations: the cap is covered, faint; a snapshot also holds some MVS-area splats
        p = fibonacci_sphere(1500 + 100 * k, R)
        p = p + rng.normal(scale=0.002, size=p.shape)
        s = np.where(rng.random(len(p)) < 0.5, -1.0, 1.0)[:, None]
        n = p / np.linalg.norm(p, axis=1, keepdims=True) * s
        snap = surfels(p, n, sigma=0.8 * spacing, alpha=0.08, source=Source.SPLAT)
        snap.fields = {}
        snapshots.append(snap)
    return merged, snapshots, fibonacci_sphere(30, 3.0)


@pytest.fixture(scope="module")
def scene():
    return glass_scene()


def cap_completeness(mesh) -> float:
    truth = fibonacci_sphere(20_000, R)
    truth = truth[truth[:, 2] > CAP_Z + 0.02]
    return float((distance_to_mesh(truth, mesh.vertices, mesh.triangles) < TAU).mean())


def test_snapshot_union_keeps_only_splat_regions_at_full_opacity(scene):
    merged, snapshots, _ = scene
    union, stats = snapshot_union(snapshots, merged)
    assert stats.per_snapshot == [len(s) for s in snapshots]
    assert len(union) == stats.kept > 0
    assert np.all(union.opacities > 0.999)
    assert (union.fields["source"] == Source.SPLAT).all()
    # every kept Gaussian is in the glass region (a rim of one MVS spacing allowed)
    assert union.means[:, 2].min() > CAP_Z - 0.04
    # and nearly all snapshot Gaussians of the cap interior are kept
    stacked = np.concatenate([s.means for s in snapshots])
    interior = stacked[:, 2] > CAP_Z + 0.05
    assert len(union) >= 0.95 * interior.sum()


def test_snapshot_union_edge_cases(scene):
    merged, snapshots, _ = scene
    only_mvs = merged.subset(merged.fields["source"] == Source.MVS)
    union, stats = snapshot_union(snapshots, only_mvs)
    assert len(union) == 0 and stats.kept == 0  # no splat region: nothing from snapshots
    no_source = merged.subset(slice(None))
    no_source.fields = {}
    with pytest.raises(DataError, match="source"):
        snapshot_union(snapshots, no_source)
    with pytest.raises(ConfigError):
        SnapshotOptions(region_radius=-1.0)


def test_hybrid_mesh_closes_the_glass_hole_the_mvs_mesh_leaves(scene):
    merged, snapshots, cams = scene
    mvs_only = mesh_from_gaussians(merged, MeshOptions(budget=4000, source=MeshSource.MVS), viewpoints=cams)
    no_snap = mesh_from_gaussians(merged, MeshOptions(budget=4000), viewpoints=cams)
    hybrid = mesh_from_gaussians(merged, MeshOptions(budget=4000), snapshots=snapshots, viewpoints=cams)
    assert hybrid.snapshot_points > 0 and mvs_only.snapshot_points == 0
    c_mvs, c_plain, c_hybrid = (cap_completeness(r.mesh) for r in (mvs_only, no_snap, hybrid))
    assert c_mvs < 0.5 and c_plain < 0.5, (c_mvs, c_plain)
    assert c_hybrid > 0.95, c_hybrid
    for r in (mvs_only, hybrid):
        assert abs(r.mesh.num_triangles - 4000) <= 40
        assert r.quality.degenerate_triangles == 0 and r.quality.edge_manifold
        assert r.quality_trimmed.edge_manifold
        samples = mesh_surface_samples(r.mesh.vertices, r.mesh.triangles, 10_000)
        assert sphere_distance(samples, R).mean() < 0.003  # a tenth of the point spacing
    # closed sampling: Poisson's implicit surface is closed before trimming, without caps; the MVS-only sampling is
    # open (the glass cap missing) and may run into the reconstruction cube: closed there by caps
    assert hybrid.quality_untrimmed.watertight and hybrid.quality_untrimmed.pieces == 1
    assert not hybrid.untrimmed_is_cap.any()
    assert mvs_only.quality_untrimmed.watertight and mvs_only.closing.closed
    assert mvs_only.quality_trimmed.boundary_edges > 0  # the hole is reported as boundary
    # vertex colours come from the Gaussians' SH DC (all surfels are (0.8, 0.4, 0.2))
    assert np.abs(hybrid.mesh.vertex_colors - [0.8, 0.4, 0.2]).max() < 1e-5


def test_no_budget_and_bad_options(scene):
    merged, _, cams = scene
    r = mesh_from_gaussians(merged, MeshOptions(budget=None), viewpoints=cams)
    assert r.decimation is None and r.mesh.num_triangles == r.trimmed.num_triangles
    with pytest.raises(ConfigError, match="budget"):
        MeshOptions(budget=0)
    with pytest.raises(ConfigError, match="option source must be one of all, mvs, survey, got .lidar."):
        MeshOptions(source="lidar")
    splats_only = merged.subset(merged.fields["source"] == Source.SPLAT)
    with pytest.raises(DataError, match="no MVS Gaussians"):
        mesh_from_gaussians(splats_only, MeshOptions(source=MeshSource.MVS))


def test_georeferenced_input_gives_the_same_mesh_shifted(scene):
    merged, _, cams = scene
    utm = np.array([500_000.0, 5_000_000.0, 300.0])
    local = mesh_from_gaussians(merged, MeshOptions(budget=2000), viewpoints=cams)
    moved = merged.subset(slice(None))
    moved.origin = utm
    geo = mesh_from_gaussians(moved, MeshOptions(budget=2000), viewpoints=cams)
    assert np.array_equal(geo.mesh.origin, utm)
    assert np.allclose(geo.mesh.vertices, local.mesh.vertices, atol=1e-9)  # same local computation


def test_splat_points_near_mvs_are_dropped_and_far_ones_kept():
    """MVS grid points (spacing 1 cm) on z = 0 for x < 0.5; splat points 3 mm above it (within 2 spacings: dropped)
    and over the MVS-free half x > 0.6 (kept). Brute force decides which is which."""
    from fusion.mesh.pipeline import drop_splat_points_near_mvs
    from fusion.mesh.types import OrientedPoints

    g = np.stack(np.meshgrid(np.arange(0, 1, 0.01), np.arange(0, 1, 0.01)), -1).reshape(-1, 2)
    mvs = np.c_[g[g[:, 0] < 0.5], np.zeros((g[:, 0] < 0.5).sum())]
    near = np.c_[g[::7][g[::7, 0] < 0.45], np.full((g[::7, 0] < 0.45).sum(), 0.003)]
    far = np.c_[g[::7][g[::7, 0] > 0.6], np.zeros((g[::7, 0] > 0.6).sum())]
    pos = np.concatenate([mvs, near, far])
    src = np.r_[np.full(len(mvs), Source.MVS), np.full(len(near) + len(far), Source.SPLAT)]
    pts = OrientedPoints(pos, np.tile([0, 0, 1.0], (len(pos), 1)), np.zeros((len(pos), 3)), src, np.arange(len(pos)))
    out, dropped = drop_splat_points_near_mvs(pts, 2.0)
    brute = np.linalg.norm(pos[src == Source.SPLAT][:, None] - mvs[None], axis=2).min(axis=1) < 0.02
    assert dropped == int(brute.sum()) == len(near)
    assert len(out) == len(mvs) + len(far)
    with pytest.raises(ConfigError, match="mvs_priority"):
        MeshOptions(mvs_priority=-1.0)
