"""CesiumJS draws our 3D Tiles tileset of SPZ glTF splat tiles, placed on the earth, where the camera looks.

A georeferenced set (two coloured halves of a 10 m slab, EPSG:32632 origin at 500000 E 5000000 N) is exported by
fusion.export.export_tileset (SPZ, ``KHR_gaussian_splatting_compression_spz_2``), then loaded by CesiumJS (npm
``cesium``, from node_tools/) in Debian's chromium (playwright, headless, WebGL2 by SwiftShader). Everything is
served by a local HTTP server on 127.0.0.1; Cesium ion, imagery, terrain, geocoder and the globe are off, and every
request not to that server is aborted and recorded (the test asserts there was none).

The camera is put, independently of the tileset's own bounding volume, 20 m straight above the origin's
longitude / latitude / ellipsoidal height from pyproj (EPSG:4979), heading north. The slab then projects to a
square of half-width f·5/20 px about the canvas centre (f from the camera's field of view); the screenshot must
show the west half's colour left of the centre and the east half's right of it (so no mirror, no y-up/z-up
swap: a vertical slab would be a line), black outside the square, and the same view with the tileset hidden
(the control) must be black. CesiumJS must have drawn the tiles as Gaussian splats (its ``gaussianSplatPrimitive``
holding every splat), not as points. Console errors and page errors fail the test with their text.

Tolerances: splats are 0.12 m (σ) on a 0.16 m grid; at 20 m (≈ 35 px/m) a splat's visible edge (≈ 2σ) reaches
≈ 8 px beyond the slab's outermost means, which lie at ±5 m (measured: 8–9 px): the footprint's edges are checked
to ±15 px. Colours: SPZ keeps 8 bits of colour and opacity; SwiftShader blends the overlapping splats (each
α ≈ 0.9975): ±40 per channel (measured: within 1).
"""

from __future__ import annotations

import functools
import http.server
import io
import math
import threading
import time
from pathlib import Path

import numpy as np
import pyproj
import pytest
from npm_readers import cesium_build

from core.gaussians import SH_C0, GaussianSet
from fusion.export import ExportOptions, export_tileset
from hybridsplat.viewer.browser import CHROMIUM, FLAGS, browser_missing

pytestmark = pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))

CRS = "EPSG:32632"
ORIGIN = np.array([500000.0, 5000000.0, 100.0])
HALF = 5.0  # the slab spans ±5 m east and north of the origin (outermost means)
WEST_RGB = np.array([0.1, 0.9, 0.2])  # green: x < 0
EAST_RGB = np.array([0.95, 0.2, 0.9])  # magenta: x > 0
HEIGHT = 20.0  # the camera, metres above the origin
VIEWPORT = {"width": 800, "height": 600}
EDGE_TOL_PX = 15
COLOUR_TOL = 40

PAGE = """<!doctype html>
<html><head><meta charset="utf-8">
<link rel="stylesheet" href="Cesium/Widgets/widgets.css">
<script src="Cesium/Cesium.js"></script>
<style>html, body, #viewer { margin: 0; width: 100%; height: 100%; overflow: hidden; background: #000; }</style>
</head><body><div id="viewer"></div><script>
window.state = {done: false, errors: []};
const frames = (n) => new Promise((resolve) => {
  const step = () => (n-- <= 0 ? resolve() : requestAnimationFrame(step));
  step();
});
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
(async () => {
  try {
    Cesium.Ion.defaultAccessToken = undefined;
    const viewer = new Cesium.Viewer("viewer", {
      baseLayer: false, globe: false, skyBox: false, skyAtmosphere: false, terrain: undefined,
      baseLayerPicker: false, geocoder: false, timeline: false, animation: false, homeButton: false,
      sceneModePicker: false, navigationHelpButton: false, fullscreenButton: false, infoBox: false,
      selectionIndicator: false, requestRenderMode: false,
    });
    const scene = viewer.scene;
    scene.backgroundColor = Cesium.Color.BLACK;
    if (scene.sun) scene.sun.show = false;
    if (scene.moon) scene.moon.show = false;
    viewer.cesiumWidget.creditContainer.style.display = "none";  // the logo would be lit pixels of its own
    window.viewer = viewer;
    state.webgl2 = scene.context.webgl2;
    const p = new URLSearchParams(location.search);
    const tileset = await Cesium.Cesium3DTileset.fromUrl(p.get("tileset"));
    scene.primitives.add(tileset);
    window.tileset = tileset;
    viewer.camera.setView({
      destination: Cesium.Cartesian3.fromDegrees(+p.get("lon"), +p.get("lat"), +p.get("h")),
      orientation: {heading: 0.0, pitch: -Math.PI / 2, roll: 0.0},
    });
    state.fov = viewer.camera.frustum.fov;
    state.canvas = [scene.canvas.width, scene.canvas.height];
    const t0 = performance.now();
    const splats = () => (tileset.gaussianSplatPrimitive ? tileset.gaussianSplatPrimitive._numSplats : 0);
    while (performance.now() - t0 < 60000 && !(tileset.tilesLoaded && splats() >= +p.get("n"))) await sleep(100);
    await frames(30);
    state.tilesLoaded = tileset.tilesLoaded;
    state.gaussianSplatPrimitive = tileset.gaussianSplatPrimitive !== undefined;
    state.numSplats = splats();
    state.seconds = (performance.now() - t0) / 1000;
  } catch (e) {
    state.errors.push(String((e && e.stack) || e));
  }
  state.done = true;
})();
window.hideTileset = async () => { tileset.show = false; await frames(30); return true; };
</script></body></html>
"""


def _slab() -> GaussianSet:
    """64 × 64 bright, opaque, flat splats on a 10 m square, west half green, east half magenta."""
    grid = np.linspace(-HALF, HALF, 64)
    x, y = (a.ravel() for a in np.meshgrid(grid, grid))
    n = x.size
    rgb = np.where((x < 0)[:, None], WEST_RGB, EAST_RGB)
    return GaussianSet(
        np.c_[x, y, np.zeros(n)],
        np.tile(np.log([0.12, 0.12, 0.03]), (n, 1)),
        np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        np.full(n, 6.0),  # α ≈ 0.9975
        (rgb - 0.5) / SH_C0,
        origin=ORIGIN.copy(),
    )


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format, *args) -> None:  # noqa: A002 (the base class's name)
        pass


def _serve(root: Path) -> http.server.ThreadingHTTPServer:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(root)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def _rgb(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)


@pytest.mark.slow
def test_cesium_draws_the_tileset_as_splats_where_the_camera_looks(tmp_path) -> None:
    cesium = cesium_build()
    from playwright.sync_api import sync_playwright

    site = tmp_path / "site"
    site.mkdir()
    (site / "Cesium").symlink_to(cesium, target_is_directory=True)
    (site / "index.html").write_text(PAGE)
    gaussians = _slab()
    export_tileset(site / "tiles" / "tileset.json", gaussians, ExportOptions(crs=CRS))
    lon, lat, h = pyproj.Transformer.from_crs(CRS, "EPSG:4979", always_xy=True).transform(*ORIGIN)

    server = _serve(site)
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    console: list[str] = []
    outside: list[str] = []

    def route(r) -> None:
        if r.request.url.startswith(base):
            r.continue_()
        else:
            outside.append(r.request.url)
            r.abort()

    try:
        with sync_playwright() as pw:
            # Name resolution off for every host but 127.0.0.1: a second layer under the route below.
            args = [*FLAGS, "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1"]
            browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=args, timeout=60_000)
            try:
                context = browser.new_context(viewport=VIEWPORT)
                context.route("**/*", route)  # the page's requests and its workers'
                page = context.new_page()
                page.set_default_timeout(120_000)
                page.on("console", lambda m: console.append(f"{m.type}: {m.text}") if m.type == "error" else None)
                page.on("pageerror", lambda e: console.append(f"pageerror: {e}"))
                t0 = time.monotonic()
                page.goto(
                    f"{base}index.html?tileset=tiles/tileset.json&lon={lon!r}&lat={lat!r}&h={h + HEIGHT!r}"
                    f"&n={len(gaussians)}"
                )
                try:
                    page.wait_for_function("window.state && window.state.done")
                except Exception as e:  # a page that never finished: say what the browser said
                    raise AssertionError(f"the page did not finish ({e}); browser errors: {console}") from e
                state = page.evaluate("window.state")
                with_splats = _rgb(page.screenshot())
                page.screenshot(path=str(tmp_path / "cesium_splats.png"))
                page.evaluate("window.hideTileset()")
                control = _rgb(page.screenshot())
                seconds = time.monotonic() - t0
            finally:
                browser.close()
    finally:
        server.shutdown()
        server.server_close()

    print(f"\ncesium: {state}, {seconds:.1f} s in the browser; screenshot {tmp_path / 'cesium_splats.png'}")
    assert not outside, f"requests outside 127.0.0.1 were attempted: {outside}"
    assert not state["errors"] and not console, f"browser errors: {state['errors'] + console}"
    assert state["webgl2"], "CesiumJS got no WebGL2 context (it draws Gaussian splats only with WebGL2)"
    assert state["tilesLoaded"], f"the tileset did not finish loading: {state}"
    assert state["gaussianSplatPrimitive"] and state["numSplats"] == len(gaussians), f"not drawn as splats: {state}"

    height, width, _ = with_splats.shape
    assert [width, height] == state["canvas"] == [VIEWPORT["width"], VIEWPORT["height"]]
    # Cesium's fov is the horizontal one when the canvas is wider than tall.
    focal = (width / 2) / math.tan(state["fov"] / 2)
    half_px = focal * HALF / HEIGHT
    cx, cy = width / 2, height / 2
    lit = with_splats.max(axis=2) > 60
    ys, xs = np.nonzero(lit)
    assert lit.any(), "nothing was drawn"
    footprint = np.array([xs.min(), xs.max() + 1, ys.min(), ys.max() + 1]) - [cx, cx, cy, cy]
    expected = np.array([-half_px, half_px, -half_px, half_px])
    assert np.abs(footprint - expected).max() < EDGE_TOL_PX, f"splats drawn over {footprint}, expected {expected} px"

    def patch(dx: float) -> np.ndarray:  # mean colour of a 40 px square half-way between the centre and an edge
        x, y = int(cx + dx * half_px / 2), int(cy)
        return with_splats[y - 20 : y + 20, x - 20 : x + 20].reshape(-1, 3).mean(axis=0)

    west, east = patch(-1), patch(+1)
    print(f"footprint {footprint} px (expected ±{half_px:.1f}), west {west.round()}, east {east.round()}")
    assert np.abs(west - WEST_RGB * 255).max() < COLOUR_TOL, f"west half {west}, expected {WEST_RGB * 255}"
    assert np.abs(east - EAST_RGB * 255).max() < COLOUR_TOL, f"east half {east}, expected {EAST_RGB * 255}"
    margin = int(half_px + EDGE_TOL_PX + 5)  # outside the slab's square: background
    outside_slab = lit.copy()
    outside_slab[int(cy) - margin : int(cy) + margin, int(cx) - margin : int(cx) + margin] = False
    assert outside_slab.sum() < 50, f"{outside_slab.sum()} lit pixels outside the slab's square"
    control_lit = (control.max(axis=2) > 60).sum()
    assert control_lit < 50, f"the same view with the tileset hidden has {control_lit} lit pixels"
