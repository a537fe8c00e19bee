"""fusion.mesh.export: PLY / OBJ / GLB round trips at a UTM-like origin, sidecar, colours, GLB Y-up node."""

import json

import numpy as np
import pytest
import trimesh

from core.errors import ConfigError, DataError
from core.io.origin import read_origin, sidecar_path
from fusion.mesh.export import Z_UP_TO_Y_UP, read_mesh, write_mesh
from fusion.mesh.types import TriangleMesh

UTM = np.array([500_000.0, 5_000_000.0, 300.0])


@pytest.fixture
def mesh() -> TriangleMesh:
    ico = trimesh.creation.icosphere(2, radius=10.0)  # a 10 m object
    rgb = np.random.default_rng(0).integers(0, 256, (len(ico.vertices), 3)) / 255.0
    return TriangleMesh(ico.vertices + [0.1234567, -0.7654321, 2.0], ico.faces, UTM, rgb)


@pytest.mark.parametrize("ext", ["ply", "obj", "glb"])
def test_round_trip_keeps_world_coordinates_to_micrometres(tmp_path, mesh, ext):
    path = write_mesh(tmp_path / f"mesh.{ext}", mesh)
    back = read_mesh(path)
    assert np.array_equal(back.origin, UTM)  # float64 exactly, from the sidecar
    assert json.loads(sidecar_path(path).read_text())["origin"] == UTM.tolist()
    # local float32 (PLY, GLB) or 8 decimals (OBJ) at ~10 m: error < 2 µm; world = origin + local
    assert np.abs(back.world_vertices - mesh.world_vertices).max() < 2e-6
    assert np.array_equal(back.triangles, mesh.triangles)
    assert np.abs(back.vertex_colors - np.rint(mesh.vertex_colors * 255) / 255).max() < 1e-6
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary left behind


def test_glb_node_turns_z_up_into_y_up(tmp_path, mesh):
    path = write_mesh(tmp_path / "m.glb", mesh)
    scene = trimesh.load(str(path))
    shown = scene.to_mesh() if hasattr(scene, "to_mesh") else scene.dump(concatenate=True)
    # what a glTF viewer shows: (x, y, z) -> (x, z, -y), so the local +z (up) becomes +y (glTF up)
    expected = np.c_[mesh.vertices[:, 0], mesh.vertices[:, 2], -mesh.vertices[:, 1]]
    assert np.abs(np.asarray(shown.vertices) - expected).max() < 1e-5
    assert np.allclose(Z_UP_TO_Y_UP[:3, :3] @ [0, 0, 1], [0, 1, 0])
    assert scene.metadata["origin"] == UTM.tolist() and scene.metadata["units"] == "m"  # glTF scene extras


def test_zero_origin_writes_no_sidecar_and_removes_a_stale_one(tmp_path, mesh):
    path = write_mesh(tmp_path / "m.ply", mesh)
    assert sidecar_path(path).exists()
    local = TriangleMesh(mesh.vertices, mesh.triangles)
    write_mesh(path, local)
    assert not sidecar_path(path).exists() and np.array_equal(read_origin(path), np.zeros(3))


def test_bad_output(tmp_path, mesh):
    with pytest.raises(ConfigError, match="stl"):
        write_mesh(tmp_path / "m.stl", mesh)
    with pytest.raises(DataError, match="without triangles"):
        write_mesh(tmp_path / "m.ply", TriangleMesh(mesh.vertices, np.zeros((0, 3))))
    bad = TriangleMesh(mesh.vertices.copy(), mesh.triangles, UTM)
    bad.vertices[0, 0] = np.nan
    with pytest.raises(DataError, match="NaN"):
        write_mesh(tmp_path / "m.obj", bad)
    assert not (tmp_path / "m.obj").exists()
