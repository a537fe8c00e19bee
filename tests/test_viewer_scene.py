"""The viewer's data side without a browser: splat arrays, click rays → picks, the measuring session.

Truth: brute-force covariances from scales and rotations; exact projections of known points through the
project's cameras; ``hybridsplat measure`` on the picks the viewer saves must give the viewer's own points.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.cameras import Camera, Cameras, View, quat_to_rotmat, rotmat_to_quat
from core.errors import DataError
from core.gaussians import GaussianSet, logit
from core.io.colmap import write_model
from core.io.gaussian_ply import write_gaussian_ply
from core.io.origin import write_origin
from eval.measure.project import Georeference, measure_picks
from hybridsplat.viewer.scene import load_project, splat_arrays, virtual_camera
from hybridsplat.viewer.session import ClientCamera, MeasureSession, pick_from_click

ORIGIN = np.array([500000.0, 5000000.0, 300.0])
CRS = "EPSG:32632"
TARGETS = np.array([[0.05, -0.04, 0.0], [-0.12, 0.09, 0.0]])


def look_at(center: np.ndarray, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    z = np.asarray(target, float) - center
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return np.concatenate([R, (-R @ center)[:, None]], axis=1)


def make_cameras(n: int = 4) -> Cameras:
    cam = Camera.pinhole(300.0, 300.0, 160.0, 120.0, 320, 240)
    views = {}
    for i, a in enumerate(np.radians(np.linspace(-60, 60, n))):
        c = np.array([1.0 * np.cos(a), 1.0 * np.sin(a), 0.7])
        views[i + 1] = View.from_matrix(i + 1, f"{i + 1:04d}.png", 1, look_at(c))
    return Cameras({1: cam}, views)


def make_gaussians(n_side: int = 48) -> GaussianSet:
    """A checkered square of flat splats on z = 0 (0.6 m wide), in a UTM-like local frame."""
    g = np.linspace(-0.3, 0.3, n_side)
    xx, yy = np.meshgrid(g, g)
    means = np.c_[xx.ravel(), yy.ravel(), np.zeros(xx.size)]
    checker = ((np.floor(xx / 0.1) + np.floor(yy / 0.1)) % 2).ravel()
    colour = np.where(checker[:, None] > 0, [0.9, 0.2, 0.1], [0.1, 0.3, 0.9])
    step = g[1] - g[0]
    n = len(means)
    return GaussianSet(
        means=means,
        log_scales=np.log(np.tile([0.6 * step, 0.6 * step, 0.1 * step], (n, 1))),
        quats=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        logit_opacities=np.full(n, logit(np.array(0.95))),
        sh_dc=(colour - 0.5) / 0.28209479177387814,
        origin=ORIGIN,
    )


def make_project(root) -> Cameras:
    """PROJECT/sparse (4 cameras) and PROJECT/export/merged.ply with a georeferenced sidecar (UTM 32N)."""
    cameras = make_cameras()
    write_model(root / "sparse", cameras)
    merged = root / "export" / "merged.ply"
    write_gaussian_ply(merged, make_gaussians())
    write_origin(merged, ORIGIN, crs=CRS)
    return cameras


def test_splat_arrays_match_brute_force_covariances() -> None:
    rng = np.random.default_rng(0)
    n = 50
    q = rng.normal(size=(n, 4))
    gs = GaussianSet(
        means=rng.normal(size=(n, 3)),
        log_scales=np.log(rng.uniform(0.01, 0.1, (n, 3))),
        quats=q,
        logit_opacities=rng.normal(size=n),
        sh_dc=rng.normal(size=(n, 3)),
        origin=ORIGIN + 10.0,
    )
    arrays = splat_arrays(gs, ORIGIN)
    for i in range(n):
        R = quat_to_rotmat(q[i] / np.linalg.norm(q[i]))
        S = np.diag(np.exp(gs.log_scales[i].astype(np.float64)))
        np.testing.assert_allclose(arrays.covariances[i], R @ S @ S @ R.T, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(arrays.centers, gs.means + 10.0, atol=1e-5)
    np.testing.assert_allclose(arrays.opacities[:, 0], 1 / (1 + np.exp(-gs.logit_opacities)), rtol=1e-6)
    capped = splat_arrays(gs, ORIGIN, max_splats=20)
    assert len(capped.centers) == 20 and capped.total == n


def test_virtual_camera_reproduces_the_click_ray() -> None:
    R_wc = quat_to_rotmat(np.array([0.9, 0.1, -0.3, 0.2]))
    position = np.array([0.3, -1.0, 0.8])
    camera, view = virtual_camera(position, rotmat_to_quat(R_wc), np.radians(50.0), 800, 600)
    f = 300.0 / np.tan(np.radians(25.0))
    x = np.array([0.1, 0.2, 0.05])
    xc = R_wc.T @ (x - position)
    np.testing.assert_allclose(
        camera.project(view.world_to_camera(x[None]))[0], [f * xc[0] / xc[2] + 400, f * xc[1] / xc[2] + 300]
    )
    np.testing.assert_allclose(view.center, position, atol=1e-12)


def test_clicks_become_photo_picks_and_measure_the_truth(tmp_path) -> None:
    cameras = make_project(tmp_path)
    session = MeasureSession(ORIGIN, "m", CRS)
    for target in TARGETS:
        for view in list(cameras)[::2]:  # cameras 1 and 3: 60° apart
            # The browser's ray: from the camera centre through the target (a jumped-to photo camera).
            direction = target - view.center
            client = ClientCamera(view.center, rotmat_to_quat(view.rotation.T), 0.8, 800, 600)
            pick = pick_from_click(cameras, client, view.center, direction, 0.5, 1e-6, session.free_name())
            assert pick.image == view.name  # snapped to the photo
            expected = cameras.camera_of(view).project(view.world_to_camera(target[None]))[0]
            np.testing.assert_allclose(pick.pixel, expected, atol=1e-9)
            session.add_pick(pick)
        session.finish_point()
    world = np.stack([p.world for p in session.points])
    np.testing.assert_allclose(world - ORIGIN, TARGETS, atol=1e-9)
    assert session.measurements().distances[0].length == pytest.approx(np.linalg.norm(TARGETS[1] - TARGETS[0]))
    # The picks the viewer saves give the same points through `hybridsplat measure`'s code path.
    again = measure_picks(session.picks_file(), cameras, Georeference(ORIGIN, "m", CRS))
    np.testing.assert_allclose(np.stack([p.world for p in again.points]), world, atol=1e-9)
    assert again.distances[0].length == pytest.approx(session.measurements().distances[0].length, abs=1e-12)


def test_free_clicks_triangulate_from_anywhere(tmp_path) -> None:
    cameras = make_cameras()
    session = MeasureSession(ORIGIN)
    target = TARGETS[0]
    for position in ([0.0, -1.2, 0.9], [1.1, 0.4, 0.6]):
        position = np.asarray(position)
        R_wc = look_at(position)[:, :3].T
        client = ClientCamera(position, rotmat_to_quat(R_wc), 0.9, 1024, 768)
        pick = pick_from_click(cameras, client, position, target - position, 1.0, 1e-6, session.free_name())
        assert pick.image.startswith("<viewer")
        session.add_pick(pick)
    point = session.finish_point()
    np.testing.assert_allclose(point.local, target, atol=1e-9)
    assert session.picks_file().points == ()  # free picks have no photo to save
    with pytest.raises(DataError, match="at least 2 images"):
        session.add_pick(pick)
        session.finish_point()


def test_load_project_puts_everything_in_the_cameras_frame(tmp_path) -> None:
    make_project(tmp_path)
    scene = load_project(tmp_path)
    assert scene.georef.crs == CRS and np.all(scene.georef.origin == ORIGIN)
    assert len(scene.cameras) == 4 and scene.splats is not None and scene.cloud is None and scene.mesh is None
    assert np.abs(scene.splats.centers).max() <= 0.3 + 1e-6  # local, not UTM, in float32
    np.testing.assert_allclose(scene.centre, [0.0, 0.0, 0.0], atol=0.02)


def test_view_command_serves_a_project_and_a_bare_ply(tmp_path, capsys) -> None:
    from hybridsplat.cli import main

    make_project(tmp_path)
    for target, cameras in ((tmp_path, "4 cameras"), (tmp_path / "export" / "merged.ply", "0 cameras")):
        try:
            main(["view", str(target), "--port", "0", "--seconds", "0.2"])
        except SystemExit as exc:
            assert not exc.code
        out = capsys.readouterr().out
        assert "http://127.0.0.1:" in out and "(splats;" in out and cameras in out, out


def test_cloud_and_mesh_layers_are_shifted_into_the_cameras_frame(tmp_path) -> None:
    import trimesh

    from core.io.ply import write_ply
    from core.pointcloud import PointCloud
    from hybridsplat.viewer.scene import cloud_arrays, mesh_arrays

    world = ORIGIN + np.array([[0.1, 0.2, 0.3], [-0.1, 0.0, 0.05]])
    write_ply(tmp_path / "fused.ply", PointCloud.from_world(world, colors=np.array([[255, 0, 0], [0, 255, 0]])))
    cloud = cloud_arrays(tmp_path / "fused.ply", ORIGIN)
    np.testing.assert_allclose(cloud.points, world - ORIGIN, atol=1e-6)
    assert cloud.colors.tolist() == [[255, 0, 0], [0, 255, 0]] and cloud.total == 2
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    box.export(tmp_path / "mesh.ply")
    write_origin(tmp_path / "mesh.ply", ORIGIN + 1.0)
    mesh = mesh_arrays(tmp_path / "mesh.ply", ORIGIN)
    np.testing.assert_allclose(mesh.vertices, np.asarray(box.vertices) + 1.0, atol=1e-6)
    assert mesh.faces.shape == (12, 3)
