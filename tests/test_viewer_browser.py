"""The viewer in a real headless browser: Debian's chromium driven by playwright, WebGL by SwiftShader.

The page loads, the splats render (the canvas differs from the same view with the splats hidden, around where
the splats project), and scripted clicks at the projections of a known point in two jumped-to photo cameras,
then the GUI's "Finish point" button, produce a measurement of that point. Skipped (with the reason) when
chromium or playwright is missing. The server binds 127.0.0.1 only; every wait is bounded.

Tolerance of the measured point: a mouse click lands on a CSS pixel (±0.5 px); at ~1.2 m with the canvas focal
length of ~650 px that is ~1 mm across the ray, and the 60° intersection keeps it ~1–2 mm in 3D: 5 mm is safe.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from test_viewer_scene import ORIGIN, make_project

from hybridsplat.viewer.project import ProjectFiles

CHROMIUM = Path(os.environ.get("HYBRIDSPLAT_CHROMIUM", "/usr/bin/chromium"))
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]
TARGET = np.array([0.05, -0.04, 0.0])
VIEWPORT = {"width": 800, "height": 600}

playwright_sync = pytest.importorskip(
    "playwright.sync_api", reason="playwright is not installed (pip install playwright)"
)
pytestmark = pytest.mark.skipif(not CHROMIUM.is_file(), reason=f"no chromium at {CHROMIUM} (apt-get install chromium)")


def _wait(condition, timeout: float, what: str):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def _at_photo(client, view, cameras) -> bool:
    """Whether the client's reported camera is the photo's: centre, orientation (±q) and vertical fov."""
    from core.cameras import rotmat_to_quat

    cam = client.camera
    q = rotmat_to_quat(view.rotation.T)
    fov = 2 * np.arctan(0.5 * cameras.camera_of(view).height / cameras.camera_of(view).focal[1])
    return (
        np.allclose(cam.position, view.center, atol=1e-6)
        and min(np.abs(cam.wxyz - q).max(), np.abs(cam.wxyz + q).max()) < 1e-5
        and abs(cam.fov - fov) < 1e-6
    )


def _settle_at_photo(client, view, cameras, timeout: float = 30.0) -> None:
    """Wait until the reported camera has stayed at the photo for 1.5 s.

    The server's camera state is set at once by the jump, then overwritten by the browser's own reports, which
    can describe a half-applied jump (position moved, orientation not yet): only a state that holds is final.
    """
    end = time.monotonic() + timeout
    stable_since = None
    while time.monotonic() < end:
        if _at_photo(client, view, cameras):
            stable_since = stable_since or time.monotonic()
            if time.monotonic() - stable_since >= 1.5:
                return
        else:
            stable_since = None
        time.sleep(0.1)
    raise AssertionError(f"the browser's camera did not settle at {view.name} within {timeout} s")


def _canvas_rgb(page, box) -> np.ndarray:
    import io

    from PIL import Image

    png = page.screenshot(clip=box)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)


@pytest.fixture
def viewer(tmp_path):
    from hybridsplat.viewer.app import ViewerApp, ViewerOptions
    from hybridsplat.viewer.scene import load_project

    make_project(tmp_path)
    app = ViewerApp(
        load_project(tmp_path), ViewerOptions(host="127.0.0.1", port=0, pick_sigma_px=1.0), ProjectFiles.of(tmp_path)
    )
    try:
        yield app
    finally:
        app.stop()


def test_page_renders_splats_and_a_click_measures(viewer, tmp_path) -> None:
    from hybridsplat.viewer.scene import virtual_camera

    assert viewer.server.get_host() == "127.0.0.1"
    with playwright_sync.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=FLAGS, timeout=60_000)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.set_default_timeout(60_000)
            page.goto(f"http://127.0.0.1:{viewer.port}/")
            page.wait_for_selector("canvas")
            client = _wait(lambda: next(iter(viewer.server.get_clients().values()), None), 60, "the page to connect")
            _wait(lambda: client.camera.image_width > 0, 30, "the client camera")
            box = page.locator("canvas").first.bounding_box()
            views = list(viewer.scene.cameras)

            # -- the splats render: the canvas with splats differs from the canvas without, where they project.
            viewer.jump_to(client, views[0])
            cams = viewer.scene.cameras
            _settle_at_photo(client, views[0], cams)
            time.sleep(3.0)
            with_splats = _canvas_rgb(page, box)
            viewer.layers["splats"].visible = False
            time.sleep(2.0)
            without = _canvas_rgb(page, box)
            viewer.layers["splats"].visible = True
            changed = np.abs(with_splats - without).max(axis=2) > 40
            assert changed.mean() > 0.02, f"only {changed.mean():.2%} of the canvas changed with the splats"
            cam, view = virtual_camera(
                client.camera.position, client.camera.wxyz, client.camera.fov, client.camera.image_width,
                client.camera.image_height,
            )  # fmt: skip
            u, v = cam.project(view.world_to_camera(np.zeros((1, 3))))[0]
            sx, sy = box["width"] / client.camera.image_width, box["height"] / client.camera.image_height
            ys, xs = np.nonzero(changed)
            assert xs.min() <= u * sx <= xs.max() and ys.min() <= v * sy <= ys.max()

            # -- a scripted click in two photo cameras, then the GUI button: a measurement.
            for index in (0, 2):
                viewer.jump_to(client, views[index])
                _settle_at_photo(client, views[index], cams)
                cam, view = virtual_camera(
                    client.camera.position, client.camera.wxyz, client.camera.fov, client.camera.image_width,
                    client.camera.image_height,
                )  # fmt: skip
                u, v = cam.project(view.world_to_camera(TARGET[None]))[0]
                before = len(viewer.session.current)
                page.mouse.click(box["x"] + u * sx, box["y"] + v * sy)
                _wait(lambda b=before: len(viewer.session.current) > b, 30, "the click to reach the server")
            assert [p.image for p in viewer.session.current] == [views[0].name, views[2].name]  # photo picks
            for pick in viewer.session.current:  # each within a click's rounding of the true projection
                truth_px = pick.camera.project(pick.view.world_to_camera(TARGET[None]))[0]
                assert np.abs(pick.pixel - truth_px).max() < 2.0, (pick.image, pick.pixel, truth_px)
            page.get_by_role("button", name="Finish point").click()
            point = _wait(lambda: viewer.session.points[0] if viewer.session.points else None, 30, "the measurement")
            error = np.linalg.norm(point.world - (ORIGIN + TARGET))
            assert error < 0.005, f"measured {point.world - ORIGIN}, truth {TARGET}: {error * 1000:.2f} mm off"
            assert 0 < point.sigma_3d < 0.01
            time.sleep(1.5)
            page.screenshot(path=str(tmp_path / "viewer_measurement.png"))
        finally:
            browser.close()
    written = viewer.export()
    assert {p.name for p in written} >= {"measurements.csv", "measurements.geojson", "picks.json"}
