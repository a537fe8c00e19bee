"""Bad input to a command that uses torch is refused before torch is imported (issue 12: every case < 5 s).

Each case runs the real CLI (``python -m hybridsplat``) in a subprocess through a small wrapper that records,
when the interpreter exits, the names in ``sys.modules`` (``MODULE_RECORDER`` in ``tests/fuzz/harness.py``).
A case passes only when the command exits 2 with one line ``hybridsplat: error: ...`` naming the bad file, no
traceback, AND the recorded module list exists, holds ``hybridsplat.cli`` (the command really ran) and does
not hold ``torch``. A positive control (valid input whose command does compute with torch) shows that the
recording sees torch when it is imported.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fuzz.cases import cloud_ply, colmap_model, gaussian_ply, image_pair, png, truncate
from fuzz.harness import REPO, read_modules, run_cli


def _run(argv: list, tmp_path: Path) -> tuple[int, str, frozenset[str]]:
    """(exit status, stderr, names of the modules imported by the end) of the CLI run in a subprocess."""
    record = tmp_path / "modules.json"
    code, _out, err, _seconds, _peak = run_cli([str(a) for a in argv], tmp_path, timeout=120, record_modules=record)
    modules = read_modules(record)
    assert modules is not None, f"the module list was not written (exit {code}):\n{err}"
    assert "hybridsplat.cli" in modules, "the CLI did not run"
    assert code is not None, "killed at the time limit"
    return code, err, modules


def _torch_modules(modules: frozenset[str]) -> list[str]:
    return sorted(m for m in modules if m == "torch" or m.startswith("torch."))


def _lpips_weights(path: Path, seed: int = 0) -> Path:
    """Random weights with the shapes of LPIPS v0.1 / AlexNet (accepted by eval.lpips.read_weights)."""
    rng = np.random.default_rng(seed)
    arrays, cin = {}, 3
    for key, ch, k in (("features.0", 64, 11), ("features.3", 192, 5), ("features.6", 384, 3),
                       ("features.8", 256, 3), ("features.10", 256, 3)):  # fmt: skip
        arrays[f"{key}.weight"] = rng.normal(0, 0.05, (ch, cin, k, k)).astype(np.float32)
        arrays[f"{key}.bias"] = np.zeros(ch, np.float32)
        cin = ch
    for i, ch in enumerate((64, 192, 384, 256, 256)):
        arrays[f"lin{i}.model.1.weight"] = np.abs(rng.normal(0, 0.1, (1, ch, 1, 1))).astype(np.float32)
    np.savez(path, **arrays)
    return path


# -- the malformed inputs: each builds its files in a folder and returns (argv, the file the error names) ------
def _eval_images_truncated_photo(d: Path) -> tuple[list, str]:
    renders, photos = image_pair(d)
    truncate(photos / "v0.png", (photos / "v0.png").stat().st_size // 2)
    return ["eval", "images", renders, photos, "--no-lpips", "--json", d / "out.json"], "v0.png"


def _eval_images_truncated_photo_with_lpips(d: Path) -> tuple[list, str]:
    """Good LPIPS weights, bad photo: the images are read before the LPIPS network is built in torch."""
    renders, photos = image_pair(d)
    truncate(photos / "v0.png", (photos / "v0.png").stat().st_size // 2)
    w = _lpips_weights(d / "lpips.npz")
    return ["eval", "images", renders, photos, "--lpips-weights", w, "--json", d / "out.json"], "v0.png"


def _eval_images_mask_wrong_size(d: Path) -> tuple[list, str]:
    renders, photos = image_pair(d)
    png(d / "masks" / "v0.png", h=10, w=10)
    w = _lpips_weights(d / "lpips.npz")
    argv = ["eval", "images", renders, photos, "--masks", d / "masks", "--lpips-weights", w]
    return argv, "v0.png"


def _eval_images_truncated_weights(d: Path) -> tuple[list, str]:
    renders, photos = image_pair(d)
    w = _lpips_weights(d / "lpips.npz")
    truncate(w, w.stat().st_size // 2)
    return ["eval", "images", renders, photos, "--lpips-weights", w, "--json", d / "out.json"], "lpips.npz"


def _eval_images_nan_weights(d: Path) -> tuple[list, str]:
    renders, photos = image_pair(d)
    w = _lpips_weights(d / "lpips.npz")
    with np.load(w) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["features.3.bias"][7] = np.nan
    np.savez(w, **arrays)
    return ["eval", "images", renders, photos, "--lpips-weights", w], "lpips.npz"


def _eval_render_truncated_gaussians(d: Path) -> tuple[list, str]:
    model = colmap_model(d / "sparse")
    gs = gaussian_ply(d / "g.ply")
    truncate(gs, gs.stat().st_size - 7)
    return ["eval", "render", gs, model, d, "--no-lpips"], "g.ply"


def _eval_render_truncated_cameras(d: Path) -> tuple[list, str]:
    model = colmap_model(d / "sparse")
    gs = gaussian_ply(d / "g.ply")
    truncate(model / "cameras.bin", (model / "cameras.bin").stat().st_size - 1)
    return ["eval", "render", gs, model, d, "--no-lpips"], "cameras.bin"


def _eval_render_bad_weights(d: Path) -> tuple[list, str]:
    """Good splats and cameras, a photo for each view, bad weights: refused before rendering (torch)."""
    import pycolmap

    model = colmap_model(d / "sparse")
    for image in pycolmap.Reconstruction(str(model)).images.values():
        png(d / "photos" / image.name, h=48, w=64)
    gs = gaussian_ply(d / "g.ply")
    w = d / "lpips.npz"
    w.write_bytes(b"PK\x03\x04" + bytes(100))
    return ["eval", "render", gs, model, d / "photos", "--lpips-weights", w], "lpips.npz"


def _render_unknown_camera_model(d: Path) -> tuple[list, str]:
    import struct

    model = colmap_model(d / "sparse")
    data = bytearray((model / "cameras.bin").read_bytes())
    struct.pack_into("<i", data, 8 + 4, 99)
    (model / "cameras.bin").write_bytes(bytes(data))
    return ["render", gaussian_ply(d / "g.ply"), "--cameras", model, "--out", d / "renders"], "cameras.bin"


def _render_inf_scale(d: Path) -> tuple[list, str]:
    import plyfile

    gs = gaussian_ply(d / "g.ply")
    ply = plyfile.PlyData.read(str(gs), mmap=False)
    ply["vertex"].data["scale_0"][3] = np.inf
    ply.write(str(gs))
    return ["render", gs, "--cameras", colmap_model(d / "sparse"), "--out", d / "renders"], "g.ply"


def _report_metrics_wrong_types(d: Path) -> tuple[list, str]:
    (d / "project" / "eval").mkdir(parents=True)
    (d / "project" / "eval" / "metrics.json").write_text('{"products": {"mvs": {"c2c": {"mean": "big"}}}}')
    return ["report", d / "project"], "metrics.json"


def _project(d: Path) -> Path:
    """A project folder as `hybridsplat run` leaves it after sfm: config.toml, photos, sparse/ (2 cameras, 4 images)."""
    import pycolmap

    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.layout import ProjectLayout

    layout = ProjectLayout(d / "project")
    model = colmap_model(layout.sparse)
    for image in pycolmap.Reconstruction(str(model)).images.values():
        png(d / "photos" / image.name, h=48, w=64)
    config = ProjectConfig(input=InputOptions(path=str(d / "photos"), holdout=0))
    layout.config.write_text(config.to_toml())
    return layout.root


def _mvs_truncated_images_bin(d: Path) -> tuple[list, str]:
    from hybridsplat.layout import ProjectLayout

    project = _project(d)
    images = ProjectLayout(project).sparse / "images.bin"
    truncate(images, images.stat().st_size // 2)
    return ["mvs", project, "--backend", "cpu"], "images.bin"


def _train_bad_config(d: Path) -> tuple[list, str]:
    from hybridsplat.layout import ProjectLayout

    config = ProjectLayout(_project(d)).config
    config.write_text(config.read_text() + "\n[train]\niterations = 'many'\n")
    return ["train", config.parent], config.name


def _train_truncated_dense_cameras(d: Path) -> tuple[list, str]:
    """A classified cloud and a region mask exist (training is due), the dense model's cameras.bin is cut."""
    from hybridsplat.layout import ProjectLayout

    layout = ProjectLayout(_project(d))
    cloud_ply(layout.classified_points)
    png(layout.masks_dir / "mask.png", h=48, w=64)
    dense_model = colmap_model(layout.dense_workspace.sparse)
    truncate(dense_model / "cameras.bin", (dense_model / "cameras.bin").stat().st_size - 1)
    return ["train", layout.root], "cameras.bin"


def _run_photo_folder_without_photos(d: Path) -> tuple[list, str]:
    """`run` on a folder that holds no photo: refused before any stage (or torch) is loaded; nothing written."""
    (d / "photos").mkdir()
    (d / "photos" / "notes.txt").write_text("no photos here")
    return ["run", d / "photos", "--out", d / "project"], "photos"


def _view_truncated_ply(d: Path) -> tuple[list, str]:
    gs = gaussian_ply(d / "g.ply")
    truncate(gs, gs.stat().st_size // 2)
    return ["view", gs, "--port", "0", "--seconds", "0.1"], "g.ply"


CASES = {
    "eval-images-truncated-photo": _eval_images_truncated_photo,
    "eval-images-truncated-photo-with-lpips": _eval_images_truncated_photo_with_lpips,
    "eval-images-mask-wrong-size": _eval_images_mask_wrong_size,
    "eval-images-truncated-weights": _eval_images_truncated_weights,
    "eval-images-nan-weights": _eval_images_nan_weights,
    "eval-render-truncated-gaussians": _eval_render_truncated_gaussians,
    "eval-render-truncated-cameras": _eval_render_truncated_cameras,
    "eval-render-bad-weights": _eval_render_bad_weights,
    "render-unknown-camera-model": _render_unknown_camera_model,
    "render-inf-scale": _render_inf_scale,
    "report-metrics-wrong-types": _report_metrics_wrong_types,
    "mvs-truncated-images-bin": _mvs_truncated_images_bin,
    "train-bad-config": _train_bad_config,
    "train-truncated-dense-cameras": _train_truncated_dense_cameras,
    "run-folder-without-photos": _run_photo_folder_without_photos,
    "view-truncated-ply": _view_truncated_ply,
}


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_refused_before_torch_is_imported(name: str, tmp_path: Path) -> None:
    argv, culprit = CASES[name](tmp_path)
    code, err, modules = _run(argv, tmp_path)
    errors = [line for line in err.splitlines() if line.startswith("hybridsplat: error: ")]
    assert "Traceback" not in err and "internal error" not in err, err
    assert code == 2, f"exit {code}:\n{err}"
    assert len(errors) == 1 and culprit in errors[0], err  # (`run` prints its "INPUT -> PROJECT" line first)
    assert _torch_modules(modules) == [], f"torch was imported before the bad input was found:\n{err}"


def test_the_module_record_sees_torch_when_a_command_computes_with_it(tmp_path: Path) -> None:
    """Positive control: valid renders, photos and LPIPS weights → exit 0, LPIPS computed in torch."""
    renders, photos = image_pair(tmp_path)
    out = tmp_path / "out.json"
    code, err, modules = _run(
        ["eval", "images", renders, photos, "--lpips-weights", _lpips_weights(tmp_path / "w.npz"), "--json", out],
        tmp_path,
    )
    assert code == 0, err
    lpips = json.loads(out.read_text())["per_view"][0]["full"]["lpips"]
    assert lpips is not None and np.isfinite(lpips) and lpips > 0
    assert "torch" in modules and "eval.lpips" in modules


@pytest.mark.parametrize(
    ("code", "heavy"),
    [
        # the per-stage commands are built from every stage's options: those come from light options modules
        ("import hybridsplat.cli", ("torch", "open3d", "numba", "cv2", "sklearn")),
        ("from hybridsplat.pipeline import load_config", ("torch", "open3d")),
        ("from hybridsplat.stages import STAGES", ("torch", "open3d")),
        ("import eval.lpips", ("torch",)),
        ("import fusion.render, fusion.train, fusion.train.init", ("torch",)),
    ],
    ids=["cli", "pipeline", "stages", "eval.lpips", "fusion-packages"],
)
def test_imports_do_not_load_torch(code: str, heavy: tuple[str, ...], tmp_path: Path) -> None:
    """The CLI, the pipeline with every stage module, and eval.lpips import without torch (nor open3d).

    Run in an empty folder: ``python -c`` puts the working directory first on ``sys.path``."""
    probe = f"{code}\nimport sys\nprint(sorted({{m.split('.')[0] for m in sys.modules}} & set({heavy!r})))"
    out = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    assert out.strip() == "[]", out


def test_lazy_stage_package_offers_the_same_stages() -> None:
    """``STAGES`` keeps the pipeline order; :func:`stage_named` returns those same objects, by their names."""
    import hybridsplat.stages as stages

    names = [s.name for s in stages.STAGES]
    order = "sfm control tiles mvs classify masks convert train clean background appearance merge mesh baseline eval"
    order += " report"
    assert names == order.split()
    for stage in stages.STAGES:
        assert stages.stage_named(stage.name) is stage
        assert type(stage).__module__ == f"hybridsplat.stages.{type(stage).__module__.rsplit('.', 1)[-1]}"
    with pytest.raises(KeyError):
        stages.stage_named("frobnicate")


@pytest.mark.parametrize("package", ["fusion.mesh", "fusion.render", "fusion.train", "hybridsplat.stages"])
def test_lazy_packages_resolve_every_exported_name(package: str) -> None:
    """Each name of ``__all__`` resolves, to the object its defining submodule holds; unknown names still fail."""
    import importlib

    module = importlib.import_module(package)
    for name in module.__all__:
        value = getattr(module, name)
        assert value is not None
        origin = getattr(value, "__module__", None)
        if origin is not None and origin.startswith(package + "."):
            assert getattr(importlib.import_module(origin), name) is value
    with pytest.raises(AttributeError):
        module.no_such_name  # noqa: B018
