"""Driving the viewer in a headless browser: Debian's chromium through playwright, WebGL by SwiftShader.

Used by the browser test and by ``bench/bench_measure.py`` (screenshots). Never ``playwright install``: the
browser is the system's (``apt-get install chromium``, done by ``scripts/bootstrap.sh``).
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from core.cameras import Cameras, View, rotmat_to_quat

CHROMIUM = Path(os.environ.get("HYBRIDSPLAT_CHROMIUM", "/usr/bin/chromium"))
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
)


def browser_missing() -> str | None:
    """Why the headless browser cannot run here (None when it can)."""
    if not CHROMIUM.is_file():
        return f"no chromium at {CHROMIUM} (apt-get install chromium, or set HYBRIDSPLAT_CHROMIUM)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install playwright)"
    return None


def wait_for(condition: Callable[[], Any], timeout: float, what: str) -> Any:
    """Poll ``condition`` every 0.1 s until it returns a truthy value; TimeoutError after ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(0.1)
    raise TimeoutError(f"timed out after {timeout} s waiting for {what}")


def _matches(position: np.ndarray, wxyz: np.ndarray, fov: float, view: View, cameras: Cameras) -> bool:
    q = rotmat_to_quat(view.rotation.T)
    intr = cameras.camera_of(view)
    photo_fov = 2 * np.arctan(0.5 * intr.height / intr.focal[1])
    return bool(
        np.allclose(position, view.center, atol=1e-6)
        and min(np.abs(wxyz - q).max(), np.abs(wxyz + q).max()) < 1e-5
        and abs(fov - photo_fov) < 1e-6
    )


def at_photo(client: Any, view: View, cameras: Cameras) -> bool:
    """Whether the server's copy of a client's camera is the photo's: centre, orientation (±q), vertical fov."""
    cam = client.camera
    return _matches(cam.position, cam.wxyz, cam.fov, view, cameras)


class CameraReports:
    """The cameras the browser reported to the server: (``time.monotonic()``, position, wxyz, fov) each."""

    def __init__(self, client: Any) -> None:
        self.reports: list[tuple[float, np.ndarray, np.ndarray, float]] = []
        client.camera.on_update(self._record)

    def _record(self, camera: Any) -> None:
        self.reports.append((time.monotonic(), camera.position.copy(), camera.wxyz.copy(), float(camera.fov)))

    @property
    def times(self) -> list[float]:
        return [r[0] for r in self.reports]


def track_camera_reports(server: Any) -> dict[int, CameraReports]:
    """Camera reports of every client that connects from now on, by client id.

    Call before the page loads: a page's first reports come right after it connects, and a camera that never
    moves again never reports again.
    """
    reports: dict[int, CameraReports] = {}
    server.on_client_connect(lambda client: reports.setdefault(client.client_id, CameraReports(client)))
    return reports


def settle_at_photo(
    client: Any, view: View, cameras: Cameras, reports: CameraReports, timeout: float = 60.0, hold: float = 1.0
) -> None:
    """Wait until the browser's own latest camera report is the photo's and ``hold`` seconds of quiet followed.

    The server's copy of the camera is set at once by a jump, before the browser has applied it, and the browser's
    reports can describe a half-applied jump (position moved, orientation not yet). Only the browser's report,
    followed by quiet, describes what a click will hit.
    """
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if reports.reports:
            t, position, wxyz, fov = reports.reports[-1]
            if time.monotonic() - t >= hold and _matches(position, wxyz, fov, view, cameras):
                return
        time.sleep(0.1)
    last = reports.reports[-1] if reports.reports else None
    raise TimeoutError(
        f"the browser's camera did not settle at {view.name} within {timeout} s: {len(reports.reports)} reports, "
        f"last {last}; photo centre {view.center}, wxyz {rotmat_to_quat(view.rotation.T)}"
    )


def jump_and_settle(
    app: Any, client: Any, view: View, reports: CameraReports, tries: int = 3, timeout: float = 20.0
) -> None:
    """Jump a client to a photo camera (``ViewerApp.jump_to``) and wait until the browser confirms it.

    A jump sent while the page is still initialising its camera can be dropped by the page: it is sent again,
    up to ``tries`` times.
    """
    for attempt in range(tries):
        app.jump_to(client, view)
        try:
            settle_at_photo(client, view, app.scene.cameras, reports, timeout=timeout)
            return
        except TimeoutError:
            if attempt == tries - 1:
                raise


def screen_position(client: Any, point_local: np.ndarray, box: dict) -> tuple[float, float]:
    """Page coordinates (CSS pixels) where a local-frame point appears in the client's canvas ``box``."""
    from hybridsplat.viewer.scene import virtual_camera

    cam = client.camera
    camera, view = virtual_camera(cam.position, cam.wxyz, cam.fov, cam.image_width, cam.image_height)
    u, v = camera.project(view.world_to_camera(np.asarray(point_local, np.float64)[None]))[0]
    return box["x"] + u * box["width"] / cam.image_width, box["y"] + v * box["height"] / cam.image_height


def canvas_rgb(page: Any, box: dict) -> np.ndarray:
    """(H, W, 3) int16 screenshot of the canvas region."""
    from PIL import Image

    png = page.screenshot(clip=box)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)
