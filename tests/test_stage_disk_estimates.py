"""Every stage's estimate of what it writes (``Stage.expected_bytes``, checked against the free disk before it runs)
is an upper bound of what it wrote on the tiny scene, and not an absurd one; a stage that would not fit is refused
before it touches anything."""

import json

import numpy as np
import pytest

from core.errors import DiskSpaceError
from core.gaussians import GaussianSet
from core.io.gaussian_ply import write_gaussian_ply
from core.io.images import write_image
from data_synth import generate_scene
from fusion.train.masked import MaskedTrainingOptions, WholeSceneOptions
from hybridsplat.config import InputOptions, ProjectConfig
from hybridsplat.disk_space import format_bytes
from hybridsplat.layout import ProjectLayout
from hybridsplat.manifest import hash_path
from hybridsplat.options import options_with
from hybridsplat.pipeline import run_pipeline
from hybridsplat.source import resolve_source
from hybridsplat.stages import registered_stages, sizes, stage_names
from hybridsplat.stages.base import StageContext
from hybridsplat.stages.mesh import MeshStageOptions

MIB = 1 << 20
# Fixed costs (a stage log, figures bounded by their raw RGBA pixels, JSON records) dominate the estimates of a
# tiny scene: they are what the 4 MiB allow for; what scales with the scene must stay within 20 times.
FACTOR, SLACK = 20, 4 * MIB

STAGES = {
    "train": options_with(MaskedTrainingOptions, {"training.iterations": 40, "snapshot_iterations": [20]}),
    "baseline": options_with(WholeSceneOptions, {"enabled": True, "training.iterations": 40, "checkpoints": [20]}),
    "mesh": options_with(MeshStageOptions, {"budget": 2000}),
}


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("disk_estimates")
    scene = generate_scene("tiny", root / "scene", seed=0)
    config = ProjectConfig(input=InputOptions(path=str(scene)), stages=STAGES)
    run_pipeline(root / "project", config)
    return config, ProjectLayout(root / "project")


def _records(layout: ProjectLayout) -> dict:
    return json.loads(layout.manifest.read_text())["stages"]


# tiles runs only when asked (run --tiles): tests/test_tiled_run.py checks its estimate on a tiled run
UNTILED = tuple(n for n in stage_names() if n not in ("control", "tiles"))  # skipped: no GCPs, no tiles


def test_every_stage_ran(project):
    _, layout = project
    skipped = {name: r["reason"] for name, r in _records(layout).items() if r["skipped"]}
    assert list(skipped) == ["control", "tiles"] and list(_records(layout)) == list(stage_names())


@pytest.mark.parametrize("name", UNTILED)
def test_estimate_bounds_what_the_stage_wrote(project, name):
    _, layout = project
    record = _records(layout)[name]
    expected, written = record["bytes_expected"], record["bytes_written"]
    what = f"{name}: expected {format_bytes(expected)}, wrote {format_bytes(written)}"
    assert 0 < written <= expected, what
    assert expected <= FACTOR * written + SLACK, what


def test_estimates_never_raise_on_an_empty_project(project, tmp_path):
    config, _ = project
    ctx = StageContext(ProjectLayout(tmp_path / "empty"), config, resolve_source(config.input))
    for stage in registered_stages():
        assert stage.expected_bytes(ctx) >= 0, stage.name


def test_size_helpers_bound_real_files_and_read_headers(project, tmp_path):
    _, layout = project
    rng = np.random.default_rng(0)
    n = 500
    gaussians = GaussianSet(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) - 3, rng.normal(size=(n, 4)),
                            rng.normal(size=n), rng.normal(size=(n, 3)), rng.normal(size=(n, 15, 3)),
                            fields={"source": np.ones(n, np.uint8), "surface": np.zeros(n, np.uint8)})  # fmt: skip
    ply = write_gaussian_ply(tmp_path / "g.ply", gaussians, extra_fields=True)
    header = sizes.ply_vertices(ply)
    assert (header.count, header.sh_degree, header.extras) == (n, 3, ("source", "surface"))
    assert ply.stat().st_size <= sizes.gaussian_ply_bytes(n, 3, 2) <= ply.stat().st_size + 4 * 1024
    noise = write_image(tmp_path / "noise.png", rng.integers(0, 256, (61, 97, 3), dtype=np.uint8))
    assert noise.stat().st_size <= sizes.png_bytes(97, 61, 3)
    assert sizes.photo_sizes(tmp_path, ["noise.png", "missing.png"]) == [(97, 61)]
    assert set(sizes.camera_sizes(layout.sparse)) == {(96, 72)}
    assert sizes.model_count(layout.sparse, "images") == len(sizes.camera_sizes(layout.sparse))
    assert sizes.ply_vertices(tmp_path / "missing.ply") == sizes.PlyVertices()
    assert sizes.camera_sizes(tmp_path) == [] and sizes.model_count(tmp_path, "points3D") == 0


def _tree(path):
    return {str(p.relative_to(path)): (p.stat().st_size, p.stat().st_mtime_ns) for p in path.rglob("*")}


def test_a_stage_that_does_not_fit_is_refused_before_it_touches_anything(project, monkeypatch):
    config, layout = project
    before = (_tree(layout.dense), hash_path(layout.dense), layout.record("mvs").read_bytes(), _records(layout)["mvs"])
    monkeypatch.setattr("hybridsplat.disk_space.free_bytes", lambda folder: 4096)
    with pytest.raises(DiskSpaceError, match="stage mvs needs about") as err:
        run_pipeline(layout.root, config, force=["mvs"])
    assert err.value.free == 4096 and err.value.needed == _records(layout)["mvs"]["bytes_expected"]
    after = (_tree(layout.dense), hash_path(layout.dense), layout.record("mvs").read_bytes(), _records(layout)["mvs"])
    assert after == before
