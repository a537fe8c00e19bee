"""A mesh from the survey point product (MeshSource.SURVEY): on a sphere whose cap MVS missed, the survey product's
trustworthy splat centres (source 2) close the cap the MVS points alone leave open. Truth: the analytic sphere."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_shapes import distance_to_mesh, fibonacci_sphere, mesh_surface_samples, sphere_distance, surfels

from core.errors import DataError
from core.pointcloud import PointCloud
from fusion.convert import Source
from fusion.mesh.options import OrientedPointOptions
from fusion.mesh.pipeline import MeshOptions, MeshSource, mesh_from_gaussians
from fusion.mesh.survey_points import oriented_points_from_survey

R, CAP_Z, TAU = 0.5, 0.25, 0.01


def _survey(with_surface: bool, origin: np.ndarray | None = None) -> tuple[PointCloud, np.ndarray]:
    """MVS points below the cap; splat centres (1 mm of noise) on it when ``with_surface``; camera centres."""
    rng = np.random.default_rng(1)
    pts = fibonacci_sphere(4000, R)
    mvs = pts[pts[:, 2] <= CAP_Z]
    parts, sources = [mvs], [np.full(len(mvs), Source.MVS)]
    if with_surface:
        cap = fibonacci_sphere(2500, R)
        cap = cap[cap[:, 2] > CAP_Z] + rng.normal(scale=0.001, size=(1, 3))
        parts.append(cap)
        sources.append(np.full(len(cap), Source.SPLAT))
    positions = np.concatenate(parts)
    origin = np.zeros(3) if origin is None else origin
    cloud = PointCloud(positions, origin, colors=np.full((len(positions), 3), 200, np.uint8),
                       fields={"source": np.concatenate(sources).astype(np.uint8)})  # fmt: skip
    return cloud, fibonacci_sphere(30, 3.0)


def _cap_completeness(mesh) -> float:
    truth = fibonacci_sphere(20_000, R)
    truth = truth[truth[:, 2] > CAP_Z + 0.02]
    return float((distance_to_mesh(truth, mesh.vertices, mesh.triangles) < TAU).mean())


def _merged() -> object:
    pts = fibonacci_sphere(2000, R)
    return surfels(pts, pts / R, sigma=0.02)  # colours the mesh only


def test_oriented_survey_points_face_the_cameras_and_lie_on_the_surface():
    cloud, cams = _survey(with_surface=True)
    points = oriented_points_from_survey(cloud, OrientedPointOptions(), cams)
    assert len(points) == len(cloud.positions)
    np.testing.assert_array_equal(points.source, cloud.fields["source"])
    outward = np.einsum("ij,ij->i", points.normals, cloud.positions / R)
    assert (outward > 0.95).mean() > 0.99  # PCA normals of a sphere, turned towards the cameras outside it
    spacing = R * np.sqrt(4 * np.pi / 4000)
    assert 0.5 * spacing < np.median(points.footprint) < 3 * spacing  # from the neighbours: no scale field


def test_the_survey_mesh_closes_the_cap_with_the_splat_centres():
    merged = _merged()
    meshes = {}
    for with_surface in (False, True):
        cloud, cams = _survey(with_surface)
        options = MeshOptions(budget=4000, source=MeshSource.SURVEY)
        meshes[with_surface] = mesh_from_gaussians(merged, options, viewpoints=cams, survey_points=cloud)
    assert _cap_completeness(meshes[False].mesh) < 0.5
    assert _cap_completeness(meshes[True].mesh) > 0.95
    result = meshes[True]
    assert result.point_stats is None and abs(result.mesh.num_triangles - 4000) <= 40
    samples = mesh_surface_samples(result.mesh.vertices, result.mesh.triangles, 10_000)
    assert sphere_distance(samples, R).mean() < 0.003


def test_a_survey_product_in_another_frame_gives_the_same_mesh_in_the_gaussians_frame():
    merged = _merged()
    shift = np.array([500_000.0, 5_000_000.0, 300.0])
    local, cams = _survey(True)
    elsewhere = PointCloud(local.positions - shift, shift, local.colors, fields=dict(local.fields))
    options = MeshOptions(budget=2000, source=MeshSource.SURVEY)
    a = mesh_from_gaussians(merged, options, viewpoints=cams, survey_points=local).mesh
    b = mesh_from_gaussians(merged, options, viewpoints=cams, survey_points=elsewhere).mesh
    np.testing.assert_array_equal(a.origin, b.origin)
    # the same surface up to the decimator's choices (the frames differ in the last bits of every coordinate)
    gap = distance_to_mesh(mesh_surface_samples(b.vertices, b.triangles, 5000), a.vertices, a.triangles)
    assert gap.mean() < 5e-4 and np.quantile(gap, 0.99) < 3e-3, (gap.mean(), np.quantile(gap, 0.99))
    assert abs(a.num_triangles - b.num_triangles) <= 40


def test_without_survey_points_or_with_too_few_it_says_so():
    with pytest.raises(DataError, match="merged_points"):
        mesh_from_gaussians(_merged(), MeshOptions(budget=100, source=MeshSource.SURVEY))
    with pytest.raises(DataError, match="too few"):
        oriented_points_from_survey(PointCloud(np.zeros((2, 3))))


def test_training_snapshots_fill_the_same_regions_as_for_a_mesh_of_the_gaussians():
    from test_mesh_pipeline import glass_scene  # the sphere with a glass cap: faint splats, three snapshots

    merged, snapshots, cams = glass_scene()
    mvs = merged.means[merged.fields["source"] == Source.MVS]
    cloud = PointCloud(mvs, merged.origin, fields={"source": np.full(len(mvs), Source.MVS, np.uint8)})
    gaussians = mesh_from_gaussians(merged, MeshOptions(budget=4000), snapshots=snapshots, viewpoints=cams)
    survey = mesh_from_gaussians(merged, MeshOptions(budget=4000, source=MeshSource.SURVEY), snapshots=snapshots,
                                 viewpoints=cams, survey_points=cloud)  # fmt: skip
    assert survey.snapshot_points == gaussians.snapshot_points > 0
    assert _cap_completeness(survey.mesh) > 0.95  # the MVS points leave the cap open; the snapshots close it
