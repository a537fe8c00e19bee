"""The viser application behind ``hybridsplat view``: layers, cameras, picking, error ellipsoids, exports.

The browser shows the scene in the COLMAP model's local frame (float32 is safe there); the GUI shows world
coordinates (local + origin, float64) in the project's unit. Clicks in the 3D view are rays; they go through
:mod:`hybridsplat.viewer.session` into :mod:`eval.measure`. Bound to 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.cameras import Cameras, View, rotmat_to_quat
from core.errors import HybridSplatError
from eval.measure import MeasuredPoint, write_csv, write_geojson
from eval.measure.picks import write_picks
from hybridsplat.layout import ProjectLayout
from hybridsplat.viewer.scene import ViewerScene
from hybridsplat.viewer.session import ClientCamera, MeasureSession, pick_from_click

TRAIN_COLOUR = (40, 90, 220)
TEST_COLOUR = (230, 140, 20)
POINT_COLOUR = (230, 30, 40)


@dataclass(frozen=True)
class ViewerOptions:
    """Options of the viewer.

    host, port: where the web server listens (default 127.0.0.1:8080; port 0 picks a free one).
    pick_sigma_px: default σ of a click in pixels (default 1.0; editable in the GUI).
    probability: probability content of the drawn error ellipsoids (default 0.95, χ²₃).
    exaggeration: initial scale factor of the drawn ellipsoids (default 1; editable, millimetre ellipsoids are
        invisible at scene scale).
    frustum_scale: frustum depth in metres (default: 4 % of the camera spread).
    """

    host: str = "127.0.0.1"
    port: int = 8080
    pick_sigma_px: float = 1.0
    probability: float = 0.95
    exaggeration: float = 1.0
    frustum_scale: float | None = None


def _world_from_cam_wxyz(view: View) -> np.ndarray:
    return rotmat_to_quat(view.rotation.T)


def _vertical_fov(cameras: Cameras, view: View) -> float:
    cam = cameras.camera_of(view)
    return float(2.0 * np.arctan(0.5 * cam.height / cam.focal[1]))


def _unit_sphere() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2)
    return np.asarray(sphere.vertices, np.float64), np.asarray(sphere.faces, np.int32)


class ViewerApp:
    """One viser server showing one scene. ``files`` (a project's layout) enables exports."""

    def __init__(
        self, scene: ViewerScene, options: ViewerOptions = ViewerOptions(), files: ProjectLayout | None = None
    ):
        import viser

        self.scene = scene
        self.options = options
        self.files = files
        self.session = MeasureSession(scene.georef.origin, scene.georef.unit, scene.georef.crs)
        self.lock = threading.Lock()
        self.messages: list[str] = []  # what the GUI reported, newest last (tests read it)
        self.server = viser.ViserServer(host=options.host, port=options.port, verbose=False)
        self._sphere = _unit_sphere()
        self._ray_handles: list = []
        self._point_handles: list = []
        self._frustum_scale = options.frustum_scale or 0.04 * scene.extent
        self._build_scene()
        self._build_gui()
        self.server.on_client_connect(self._on_connect)
        self.server.scene.on_click()(self._on_click)

    # -- scene ------------------------------------------------------------------------------------
    def _build_scene(self) -> None:
        sc, s = self.server.scene, self.scene
        sc.set_up_direction("+z")
        sc.world_axes.visible = False
        self.layers: dict[str, object] = {}
        if s.splats is not None:
            sp = s.splats
            self.layers["splats"] = sc.add_gaussian_splats(
                "/splats", centers=sp.centers, covariances=sp.covariances, rgbs=sp.rgbs, opacities=sp.opacities
            )
        if s.cloud is not None:
            self.layers["MVS cloud"] = sc.add_point_cloud(
                "/mvs_cloud",
                points=s.cloud.points,
                colors=s.cloud.colors,
                point_size=0.002 * s.extent,
                visible=s.splats is None,
            )
        if s.mesh is not None:
            m = s.mesh
            self.layers["mesh"] = sc.add_mesh_simple(
                "/mesh", vertices=m.vertices, faces=m.faces, color=(180, 180, 180), visible=False
            )
        self.frusta: dict[str, object] = {}
        for group, cams, colour in (("train", s.cameras, TRAIN_COLOUR), ("test", s.test_cameras, TEST_COLOUR)):
            for view in cams:
                cam = cams.camera_of(view)
                handle = sc.add_camera_frustum(
                    f"/cameras/{group}/{view.image_id}",
                    fov=_vertical_fov(cams, view),
                    aspect=cam.width / cam.height,
                    scale=self._frustum_scale,
                    thickness=0.05 * self._frustum_scale,
                    color=colour,
                    wxyz=_world_from_cam_wxyz(view),
                    position=view.center,
                )
                # No on_click on frusta: a clickable frustum swallows the clicks meant for picking behind it.
                self.frusta[f"{group}/{view.name}"] = handle

    # -- GUI --------------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui, s = self.server.gui, self.scene
        gui.main_panel.dock_right()  # beside the 3D view, not over it: every part of the scene can be clicked
        o = s.georef.origin
        gui.add_markdown(
            f"**{s.name}** — world = local + origin; unit **{s.georef.unit}**, CRS **{s.georef.crs or 'unknown'}**  \n"
            f"origin: {o[0]:.3f}, {o[1]:.3f}, {o[2]:.3f} {s.georef.unit}"
        )
        with gui.add_folder("Layers"):
            for name, handle in self.layers.items():
                box = gui.add_checkbox(name, initial_value=bool(handle.visible))  # type: ignore[attr-defined]
                box.on_update(lambda _e, h=handle, b=box: setattr(h, "visible", b.value))
            for group in ("train", "test"):
                keys = [k for k in self.frusta if k.startswith(group + "/")]
                if keys:
                    box = gui.add_checkbox(f"{group} cameras ({len(keys)})", initial_value=True)
                    box.on_update(lambda _e, ks=keys, b=box: [setattr(self.frusta[k], "visible", b.value) for k in ks])
        with gui.add_folder("Cameras"):
            names = [v.name for v in s.cameras] + [v.name for v in s.test_cameras]
            self.camera_choice = gui.add_dropdown("photo", options=names or ["(none)"])
            jump = gui.add_button("Jump to camera")
            jump.on_click(lambda event: self._jump_by_name(event.client, self.camera_choice.value))
            step = gui.add_button_group("step", options=("previous", "next"))
            step.on_click(lambda event: self._step(event.client, -1 if step.value == "previous" else 1))
        with gui.add_folder("Measure"):
            gui.add_markdown(
                "Click the same feature in 2+ views (jump to photos for photo picks), then *Finish point*."
            )
            self.sigma = gui.add_number("pick σ (px)", initial_value=self.options.pick_sigma_px, min=0.01, step=0.1)
            self.exaggeration = gui.add_slider(
                "ellipsoid ×", min=1.0, max=1000.0, step=1.0, initial_value=self.options.exaggeration
            )
            self.exaggeration.on_update(lambda _e: self._redraw_points())
            self.status = gui.add_markdown("picks: 0")
            gui.add_button("Finish point").on_click(lambda _e: self.finish_point())
            gui.add_button("Clear picks").on_click(lambda _e: self._clear_picks())
            gui.add_button("Undo last point").on_click(lambda _e: self._undo())
            export = gui.add_button("Export CSV / GeoJSON", disabled=self.files is None)
            export.on_click(lambda _e: self.export())
            self.table = gui.add_markdown("")

    def _say(self, text: str) -> None:
        self.messages.append(text)
        self.status.content = text

    # -- cameras ----------------------------------------------------------------------------------
    def _on_connect(self, client) -> None:
        s = self.scene
        with client.atomic():
            client.camera.near = 1e-3 * s.extent
            client.camera.far = 1e3 * s.extent
            views = list(s.cameras)
            if views:
                client.camera.position = views[0].center
                client.camera.look_at = s.centre
                client.camera.up_direction = (0.0, 0.0, 1.0)

    def _jump_by_name(self, client, name: str) -> None:
        for cams in (self.scene.cameras, self.scene.test_cameras):
            for view in cams:
                if view.name == name:
                    self.jump_to(client, view, cams)
                    return

    def _step(self, client, delta: int) -> None:
        names = list(self.camera_choice.options)
        if self.camera_choice.value in names:
            self.camera_choice.value = names[(names.index(self.camera_choice.value) + delta) % len(names)]
            self._jump_by_name(client, self.camera_choice.value)

    def jump_to(self, client, view: View, cameras: Cameras | None = None) -> None:
        """Put a client's camera at a photo's pose with its vertical field of view."""
        cameras = cameras or self.scene.cameras
        with client.atomic():
            client.camera.fov = _vertical_fov(cameras, view)
            client.camera.position = view.center
            client.camera.wxyz = _world_from_cam_wxyz(view)
        self._say(f"at camera {view.name}; picks: {len(self.session.current)}")

    # -- picking ----------------------------------------------------------------------------------
    def _on_click(self, event) -> None:
        cam = event.client.camera
        client = ClientCamera(
            np.asarray(cam.position, np.float64),
            np.asarray(cam.wxyz, np.float64),
            float(cam.fov),
            int(cam.image_width),
            int(cam.image_height),
        )
        all_cams = Cameras(
            {**self.scene.cameras.cameras, **self.scene.test_cameras.cameras},
            {**self.scene.cameras.views, **self.scene.test_cameras.views},
        )
        with self.lock:
            try:
                pick = pick_from_click(
                    all_cams,
                    client,
                    np.asarray(event.ray_origin),
                    np.asarray(event.ray_direction),
                    float(self.sigma.value),
                    1e-3 * self.scene.extent,
                    self.session.free_name(),
                )
            except HybridSplatError as err:
                self._say(f"pick refused: {err.one_line()}")
                return
            n = self.session.add_pick(pick)
            self._draw_ray(pick, n)
            where = pick.image if not pick.image.startswith("<viewer") else "viewer camera"
            self._say(f"picks: {n} (last in {where} at {pick.pixel[0]:.1f}, {pick.pixel[1]:.1f} px)")

    def _draw_ray(self, pick, n: int) -> None:
        centre = pick.view.center
        direction = pick.view.rotation.T @ pick.camera.unproject(pick.pixel[None])[0]
        direction /= np.linalg.norm(direction)
        end = centre + direction * 2.0 * self.scene.extent
        handle = self.server.scene.add_line_segments(
            f"/picks/ray_{n}",
            points=np.array([[centre, end]], np.float32),
            colors=np.array([255, 200, 0], np.uint8),
            thickness=1.5,
            thickness_units="screen",
        )
        self._ray_handles.append(handle)

    def _clear_rays(self) -> None:
        for handle in self._ray_handles:
            handle.remove()
        self._ray_handles = []

    def _clear_picks(self) -> None:
        with self.lock:
            self.session.clear_picks()
            self._clear_rays()
            self._say("picks: 0")

    def finish_point(self) -> MeasuredPoint | None:
        """Triangulate the current picks; draws the point and its ellipsoid. None (with a message) on failure."""
        with self.lock:
            try:
                point = self.session.finish_point()
            except HybridSplatError as err:
                self._say(f"not measured: {err.one_line()}")
                return None
            self._clear_rays()
            note = self._auto_exaggeration(point)
            self._redraw_points()
            self._say(f"measured {point.name}; picks: 0{note}")
            return point

    def _auto_exaggeration(self, point: MeasuredPoint) -> str:
        """On the first point: a power-of-ten ellipsoid scale that makes it visible (≥ 0.5 % of the scene)."""
        if len(self.session.points) != 1 or float(self.exaggeration.value) != self.options.exaggeration:
            return ""
        axes, _ = point.ellipsoid(self.options.probability)
        visible = 0.005 * self.scene.extent
        largest = float(axes.max()) * self.options.exaggeration
        if largest <= 0 or largest >= visible:
            return ""
        factor = float(min(10 ** np.ceil(np.log10(visible / largest)), 1000.0))
        self.exaggeration.value = self.options.exaggeration * factor
        return f" (ellipsoids drawn ×{self.exaggeration.value:g}: see the slider)"

    def _undo(self) -> None:
        with self.lock:
            self.session.undo_point()
            self._redraw_points()

    def _redraw_points(self) -> None:
        for handle in self._point_handles:
            handle.remove()
        self._point_handles = []
        verts, faces = self._sphere
        k = float(self.exaggeration.value)
        for p in self.session.points:
            axes, vecs = p.ellipsoid(self.options.probability)
            v = p.local + (verts * np.maximum(axes, 1e-9) * k) @ vecs.T
            self._point_handles.append(
                self.server.scene.add_mesh_simple(
                    f"/points/{p.name}/ellipsoid",
                    vertices=v.astype(np.float32),
                    faces=faces,
                    color=POINT_COLOUR,
                    opacity=None,  # opaque: splats are drawn over transparent meshes and hid them
                )
            )
            self._point_handles.append(
                self.server.scene.add_label(f"/points/{p.name}/label", p.name, position=tuple(p.local.astype(float)))
            )
        self.table.content = self._table()

    def _table(self) -> str:
        unit = self.scene.georef.unit
        rows = [f"| point | X | Y | Z | σ3D ({unit}) |", "|---|---|---|---|---|"]
        for p in self.session.points:
            x, y, z = p.world
            rows.append(f"| {p.name} | {x:.4f} | {y:.4f} | {z:.4f} | {p.sigma_3d:.4f} |")
        m = self.session.measurements()
        for d in m.distances:
            rows.append(f"| {d.a}–{d.b} | {d.length:.4f} ± {d.sigma:.4f} {unit} | | | |")
        return "\n".join(rows) if self.session.points else ""

    def export(self) -> list[Path]:
        """Write the measurements (CSV, GeoJSON with a CRS) and the photo picks (picks.json) into the project."""
        if self.files is None:
            self._say("export needs a project folder")
            return []
        from core.errors import ProjectBusyError
        from hybridsplat.project_lock import ProjectLock

        try:
            with self.lock, ProjectLock(self.files.root, command="hybridsplat view (Export)"):
                return self._write_exports()
        except ProjectBusyError as err:
            self._say(f"not written: {err.problem}")
            return []

    def _write_exports(self) -> list[Path]:
        m = self.session.measurements()
        f = self.files
        write_csv(f.measurements_csv, m, f.measurement_distances_csv if m.distances else None)
        written = [f.measurements_csv] + ([f.measurement_distances_csv] if m.distances else [])
        if m.crs:
            write_geojson(f.measurements_geojson, m)
            written.append(f.measurements_geojson)
        picks = self.session.picks_file()
        if picks.points:
            write_picks(f.picks_json, picks)
            written.append(f.picks_json)
        self._say("wrote " + ", ".join(p.name for p in written))
        return written

    # -- lifetime ---------------------------------------------------------------------------------
    @property
    def port(self) -> int:
        return int(self.server.get_port())

    def stop(self) -> None:
        self.server.stop()
