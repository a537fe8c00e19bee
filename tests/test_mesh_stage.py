"""The ``mesh`` stage and ``hybridsplat mesh``: on a project holding a merged product (a sphere of MVS surfels with a
"glass" cap of faint splats, at a UTM origin) and training snapshots; truth: the analytic sphere."""

import json

import numpy as np
import pytest
from test_mesh_pipeline import CAP_Z, R, glass_scene

from core.errors import ConfigError
from core.io.gaussian_ply import write_gaussian_ply
from core.io.images import write_image
from core.io.origin import read_origin
from core.io.ply import read_ply
from fusion.export import export_gaussian_ply, export_points
from fusion.mesh import read_mesh
from hybridsplat.cli import run_cli
from hybridsplat.config import InputOptions, ProjectConfig
from hybridsplat.layout import ProjectLayout
from hybridsplat.options import options_with
from hybridsplat.pipeline import run_pipeline
from hybridsplat.stages import stage_named
from hybridsplat.stages.mesh import MeshStageOptions

UTM = np.array([500_000.0, 5_000_000.0, 300.0])


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("mesh_stage")
    photos = root / "photos"
    for i in range(3):  # any input resolves; the mesh stage reads only the project's files
        write_image(photos / f"p{i}.png", np.full((8, 8, 3), 100 + i, np.uint8))
    merged, snapshots, _ = glass_scene()
    merged.origin = UTM
    layout = ProjectLayout(root / "project")
    export_gaussian_ply(layout.merged_ply, merged)  # as the merge stage writes it: no extra fields
    export_points(layout.merged_points_ply, merged)
    for i, snap in enumerate(snapshots):
        snap.origin = UTM
        write_gaussian_ply(layout.snapshots_dir / f"iter_{(i + 1) * 500:05d}.ply", snap)
    return photos, layout


def run_mesh(photos, layout, **options):
    mesh_options = options_with(MeshStageOptions, options)
    config = ProjectConfig(input=InputOptions(path=str(photos)), stages={"mesh": mesh_options})
    manifest = run_pipeline(layout.root, config, [stage_named("mesh")])
    return json.loads(layout.manifest.read_text())["stages"]["mesh"], manifest


def test_stage_writes_three_georeferenced_formats_within_budget(project):
    photos, layout = project
    record, _ = run_mesh(photos, layout, budget=3000)
    counts = record["counts"]
    assert not record["skipped"] and counts["snapshots"] == 3 and counts["snapshot_points"] > 0
    assert abs(counts["triangles"] - 3000) <= 30 and counts["within_budget_tolerance"]
    assert counts["degenerate_triangles"] == 0 and counts["non_manifold_edges"] == 0
    assert np.array_equal(read_origin(layout.mesh_path("ply")), UTM)
    for fmt in ("ply", "obj", "glb"):
        mesh = read_mesh(layout.mesh_path(fmt))
        assert mesh.num_triangles == counts["triangles"]
        assert np.array_equal(mesh.origin, UTM)
        local = mesh.world_vertices - UTM  # the sphere is centred at the UTM origin
        assert np.median(np.abs(np.linalg.norm(local, axis=1) - R)) < 0.003
        assert (local[:, 2] > CAP_Z + 0.05).any()  # the glass cap is meshed (snapshots)
        assert mesh.vertex_colors is not None


def test_rerun_is_cached_and_the_command_changes_the_budget(project):
    photos, layout = project
    run_mesh(photos, layout, budget=3000)
    record, _ = run_mesh(photos, layout, budget=3000)
    assert record["cached"]
    assert run_cli(["mesh", str(layout.root), "--budget", "1500", "--format", "ply", "--no-snapshots"]) == 0
    record = json.loads(layout.manifest.read_text())["stages"]["mesh"]
    assert abs(record["counts"]["triangles"] - 1500) <= 15 and record["counts"]["snapshots"] == 0
    assert read_mesh(layout.mesh_path("ply")).num_triangles == record["counts"]["triangles"]


def test_budget_zero_skips_and_bad_options(project):
    photos, layout = project
    record, _ = run_mesh(photos, layout, budget=0)
    assert record["skipped"] and "no mesh asked" in record["reason"]
    assert not layout.mesh_path("ply").exists()  # outputs of the earlier run are stale, removed
    with pytest.raises(ConfigError):
        MeshStageOptions(budget=-1)
    with pytest.raises(ConfigError):
        MeshStageOptions(formats=("stl",))
    with pytest.raises(ConfigError):
        MeshStageOptions(method="marching")


def test_tsdf_method_renders_at_the_project_cameras(project, tmp_path):
    from test_mesh_tsdf import look_at_cameras

    from core.io.colmap import write_model

    photos, layout = project
    cams = look_at_cameras(
        np.array([[1.6, 0, 0.4], [0, 1.6, 0.4], [-1.6, 0, 0.4], [0, -1.6, 0.4], [0.1, 0, 1.7]]), size=48, origin=UTM
    )
    write_model(layout.sparse, cams)  # a model is local; its origin is what the sfm stage records
    from core.io.json_io import write_json_atomic

    write_json_atomic(layout.record("sfm"), {"origin": UTM.tolist()})
    try:
        record, _ = run_mesh(photos, layout, budget=1500, method="tsdf", formats=("ply",))
        counts = record["counts"]
        assert counts["method"] == "tsdf" and abs(counts["triangles"] - 1500) <= 15
        mesh = read_mesh(layout.mesh_path("ply"))
        local = mesh.world_vertices - UTM
        assert np.median(np.abs(np.linalg.norm(local, axis=1) - R)) < 0.02  # within a voxel of the sphere
    finally:
        import shutil

        shutil.rmtree(layout.sparse)
        layout.record("sfm").unlink()


def test_eval_scores_the_mesh_from_points_sampled_on_it(project):
    # the eval stage's "mesh" product: world points on the mesh, about τ/3 apart, scored per material like a cloud
    from eval.per_material import geometry_per_material
    from hybridsplat.stages.evaluate import _mesh_points

    photos, layout = project
    record, _ = run_mesh(photos, layout, budget=3000)
    tau = 0.01
    pts = _mesh_points(layout.mesh_path("ply"), tau)
    area = read_mesh(layout.mesh_path("ply")).triangle_areas().sum()
    assert len(pts) == int(area / (tau / 3) ** 2)
    local = pts - UTM
    assert np.abs(np.linalg.norm(local, axis=1) - R).max() < 0.01  # on the sphere, in world coordinates
    # reference: the analytic sphere, "glass" above CAP_Z (material 2), the rest material 1
    ref = np.random.default_rng(3).normal(size=(5000, 3))
    ref = R * ref / np.linalg.norm(ref, axis=1, keepdims=True)
    material = np.where(ref[:, 2] > CAP_Z, 2, 1)
    scores = geometry_per_material(pts, ref + UTM, material, tau)
    assert scores[1].completeness > 0.99 and scores[2].completeness > 0.95
    # accuracy against a sampled reference includes its spacing: compare with the same points put on the sphere
    ideal = geometry_per_material(R * local / np.linalg.norm(local, axis=1, keepdims=True) + UTM, ref + UTM,
                                  material, tau)  # fmt: skip
    for m in (1, 2):
        assert abs(scores[m].accuracy_mean - ideal[m].accuracy_mean) < 0.001
    assert _mesh_points(layout.root / "no_mesh.ply", tau) is None


def test_the_command_meshes_the_survey_points(project):
    photos, layout = project
    assert run_cli(["mesh", str(layout.root), "--budget", "2000", "--format", "ply", "--source", "survey"]) == 0
    record = json.loads(layout.manifest.read_text())["stages"]["mesh"]
    counts = record["counts"]
    survey = len(read_ply(layout.merged_points_ply).positions)
    # one oriented point per survey point (not the Gaussians' sampled ellipses), plus the snapshots' points
    assert counts["oriented_points"] == survey + counts["snapshot_points"] - counts["splat_points_dropped_near_mvs"]
    mesh = read_mesh(layout.mesh_path("ply"))
    local = mesh.world_vertices - UTM
    assert abs(mesh.num_triangles - 2000) <= 20
    assert np.median(np.abs(np.linalg.norm(local, axis=1) - R)) < 0.003
    assert (local[:, 2] > CAP_Z + 0.05).any()  # the glass cap: its splat points and the snapshots
