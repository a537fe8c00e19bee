"""The viewer in a real headless browser: Debian's chromium driven by playwright, WebGL by SwiftShader.

The page loads, the splats render (the canvas differs from the same view with the splats hidden, around where
the splats project), and scripted clicks at the projections of a known point in two jumped-to photo cameras,
then the GUI's "Finish point" button, produce a measurement of that point. Skipped (with the reason) when
chromium or playwright is missing. The server binds 127.0.0.1 only; every wait is bounded.

Tolerance of the measured point: a mouse click lands on a CSS pixel (±0.5 px); at ~1.2 m with the canvas focal
length of ~650 px that is ~1 mm across the ray, and the 60° intersection keeps it ~1–2 mm in 3D: 5 mm is safe.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from test_viewer_scene import ORIGIN, make_project

from hybridsplat.viewer.browser import (
    CHROMIUM,
    FLAGS,
    browser_missing,
    canvas_rgb,
    jump_and_settle,
    screen_position,
    track_camera_reports,
    wait_for,
)
from hybridsplat.viewer.project import open_project

TARGET = np.array([0.05, -0.04, 0.0])
VIEWPORT = {"width": 800, "height": 600}

pytestmark = pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))


@pytest.fixture
def viewer(tmp_path):
    from hybridsplat.viewer.app import ViewerApp, ViewerOptions
    from hybridsplat.viewer.scene import load_project

    make_project(tmp_path)
    app = ViewerApp(
        load_project(tmp_path), ViewerOptions(host="127.0.0.1", port=0, pick_sigma_px=1.0), open_project(tmp_path)
    )
    try:
        yield app
    finally:
        app.stop()


def test_page_renders_splats_and_a_click_measures(viewer, tmp_path) -> None:
    from playwright.sync_api import sync_playwright

    assert viewer.server.get_host() == "127.0.0.1"

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=list(FLAGS), timeout=60_000)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.set_default_timeout(60_000)
            tracked = track_camera_reports(viewer.server)
            page.goto(f"http://127.0.0.1:{viewer.port}/")
            page.wait_for_selector("canvas")
            client = wait_for(lambda: next(iter(viewer.server.get_clients().values()), None), 60, "the page to connect")
            reports = wait_for(lambda: tracked.get(client.client_id), 30, "camera tracking")
            wait_for(lambda: client.camera.image_width > 0, 30, "the client camera")
            box = page.locator("canvas").first.bounding_box()
            views = list(viewer.scene.cameras)

            # -- the splats render: the canvas with splats differs from the canvas without, where they project.
            jump_and_settle(viewer, client, views[0], reports)
            time.sleep(3.0)
            with_splats = canvas_rgb(page, box)
            viewer.layers["splats"].visible = False
            time.sleep(2.0)
            without = canvas_rgb(page, box)
            viewer.layers["splats"].visible = True
            changed = np.abs(with_splats - without).max(axis=2) > 40
            assert changed.mean() > 0.02, f"only {changed.mean():.2%} of the canvas changed with the splats"
            x, y = screen_position(client, np.zeros(3), box)  # the splat square's centre
            ys, xs = np.nonzero(changed)
            assert xs.min() <= x - box["x"] <= xs.max() and ys.min() <= y - box["y"] <= ys.max()

            # -- a scripted click in two photo cameras, then the GUI button: a measurement.
            for index in (0, 2):
                jump_and_settle(viewer, client, views[index], reports)
                before = len(viewer.session.current)
                page.mouse.click(*screen_position(client, TARGET, box))
                wait_for(lambda b=before: len(viewer.session.current) > b, 30, "the click to reach the server")
            assert [p.image for p in viewer.session.current] == [views[0].name, views[2].name]  # photo picks
            for pick in viewer.session.current:  # each within a click's rounding of the true projection
                truth_px = pick.camera.project(pick.view.world_to_camera(TARGET[None]))[0]
                assert np.abs(pick.pixel - truth_px).max() < 2.0, (pick.image, pick.pixel, truth_px)
            page.get_by_role("button", name="Finish point").click()
            point = wait_for(lambda: viewer.session.points[0] if viewer.session.points else None, 30, "the measurement")
            error = np.linalg.norm(point.world - (ORIGIN + TARGET))
            assert error < 0.005, f"measured {point.world - ORIGIN}, truth {TARGET}: {error * 1000:.2f} mm off"
            assert 0 < point.sigma_3d < 0.01
            time.sleep(1.5)
            page.screenshot(path=str(tmp_path / "viewer_measurement.png"))
        finally:
            browser.close()
    written = viewer.export()
    assert {p.name for p in written} >= {"measurements.csv", "measurements.geojson", "picks.json"}
