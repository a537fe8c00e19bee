"""The adjustment held to control (recon.control) and the control stage: exact marks recover the cameras; the stage
on a tiny scene with hand-made marks; bad input named by file and line."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from core.cameras import Cameras, View
from core.errors import DataError
from core.io.control import ControlPoint, Mark, Role, write_gcp_csv, write_marks_csv
from data_synth.rig import look_at, pinhole_from_fov


def _block(rng: np.random.Generator) -> Cameras:
    """Nine nadir-ish cameras 30 m over a 60 m × 40 m site, looking at points near the ground."""
    camera = pinhole_from_fov(400, 300, 60.0)
    views = {}
    for k, (x, y) in enumerate([(x, y) for x in (-15.0, 0.0, 15.0) for y in (-10.0, 0.0, 10.0)]):
        centre = np.array([x, y, 30.0]) + rng.normal(0, 0.5, 3)
        target = np.array([x * 0.6, y * 0.6, 0.0])
        views[k + 1] = View.from_matrix(k + 1, f"v{k}.png", 1, look_at(centre, target, np.array([0.0, 1.0, 0.0])))
    return Cameras({1: camera}, views)


def _observed(cams: Cameras, x: np.ndarray, rng: np.random.Generator, noise_px: float):
    from recon.control import ImageMark

    out = []
    for v in cams:
        uv, z = cams.project(v, x[None])
        cam = cams.camera_of(v)
        if z[0] > 0 and 0 < uv[0, 0] < cam.width and 0 < uv[0, 1] < cam.height:
            out.append(ImageMark(v.image_id, uv[0] + rng.normal(0, noise_px, 2)))
    return out


def _model(truth: Cameras, rng: np.random.Generator):
    """A reconstruction of ``truth``'s scene in another frame (a similarity) with its cameras bent (centre noise
    0.3 m, rotations 2 mrad), 150 tie points triangulated in it from exact observations, 20 spare keypoints an
    image."""
    import pycolmap

    from recon.control import triangulate_marks
    from recon.model import to_reconstruction

    sim_r = pycolmap.Rotation3d(np.array([0.1, -0.05, 0.3])).matrix()
    views = {}
    for v in truth:
        c = 1.7 * sim_r @ v.center + np.array([5.0, -3.0, 2.0]) + rng.normal(0, 0.3, 3)
        r = pycolmap.Rotation3d(rng.normal(0, 0.002, 3)).matrix() @ v.rotation @ sim_r.T
        views[v.image_id] = View.from_matrix(v.image_id, v.name, 1, np.concatenate([r, (-r @ c)[:, None]], 1))
    rec = to_reconstruction(Cameras(truth.cameras, views))
    ties = np.concatenate([rng.uniform([-25, -18], [25, 18], (150, 2)), rng.uniform(0, 4, (150, 1))], axis=1)
    tracks = [_observed(truth, x, rng, 0.0) for x in ties]
    tracks = [t for t in tracks if len(t) >= 2]
    per_image: dict[int, list[tuple[int, np.ndarray]]] = {i: [] for i in rec.reg_image_ids()}
    for k, track in enumerate(tracks):
        for m in track:
            per_image[m.image_id].append((k, m.uv))
    for i, entries in per_image.items():
        pts = [pycolmap.Point2D(uv) for _, uv in entries] + [pycolmap.Point2D(np.zeros(2)) for _ in range(20)]
        rec.image(i).points2D = pycolmap.Point2DList(pts)
    for k, track in enumerate(tracks):
        point_id = rec.add_point3D(triangulate_marks(rec, track).xyz, pycolmap.Track(), np.zeros(3, np.uint8))
        for i, entries in per_image.items():
            for slot, (kk, _) in enumerate(entries):
                if kk == k:
                    rec.add_observation(point_id, pycolmap.TrackElement(i, slot))
    return rec


def test_adjustment_with_exact_marks_recovers_the_cameras_and_the_check_points():
    from recon.control import ControlOptions, adjust_to_control

    rng = np.random.default_rng(3)
    truth = _block(rng)
    rec = _model(truth, rng)
    points = {"C1": (-12, -8, 0.1), "C2": (12, -8, 0.2), "C3": (12, 8, 0.0), "C4": (-12, 8, 0.3),
              "K1": (0, 0, 0.1), "K2": (6, -4, 0.0), "K3": (-7, 5, 0.2)}  # fmt: skip
    survey = {pid: ("control" if pid[0] == "C" else "check", np.asarray(xyz, float)) for pid, xyz in points.items()}
    marks = {pid: _observed(truth, xyz, rng, 0.0) for pid, (_, xyz) in survey.items()}
    ties = rec.num_points3D()
    report = adjust_to_control(rec, marks, survey, ControlOptions(max_mark_error_px=100.0))
    assert report.adjusted and report.final_cost < report.initial_cost
    for p in report.points:
        # exact marks and exact ties: the bent block is straightened onto the truth (Ceres tolerance ~1e-12)
        assert np.linalg.norm(p.model - p.survey) < 2e-3, p
    centres = np.array([np.asarray(rec.image(i).projection_center()) for i in sorted(rec.reg_image_ids())])
    true_centres = np.array([truth.views[i].center for i in sorted(rec.reg_image_ids())])
    assert np.abs(centres - true_centres).max() < 5e-3
    assert rec.num_points3D() == ties  # the control points were taken out of the model again


def test_similarity_alone_leaves_the_bend_that_the_adjustment_removes():
    from recon.control import ControlOptions, adjust_to_control

    rng = np.random.default_rng(3)
    truth = _block(rng)
    survey = {"C1": ("control", np.array([-12.0, -8, 0.1])), "C2": ("control", np.array([12.0, -8, 0.2])),
              "C3": ("control", np.array([12.0, 8, 0.0])), "C4": ("control", np.array([-12.0, 8, 0.3])),
              "K1": ("check", np.array([0.0, 0, 0.1]))}  # fmt: skip
    marks = {pid: _observed(truth, xyz, rng, 0.0) for pid, (_, xyz) in survey.items()}
    errors = []
    for adjust in (False, True):
        rec = _model(truth, np.random.default_rng(5))
        report = adjust_to_control(rec, marks, survey, ControlOptions(adjust=adjust, max_mark_error_px=100.0))
        errors.append(max(np.linalg.norm(p.model - p.survey) for p in report.points))
    assert errors[0] > 0.05 and errors[1] < 2e-3  # 0.3 m camera noise bends the model by decimetres


def test_a_mark_far_from_the_others_is_dropped():
    from recon.control import triangulate_marks

    rng = np.random.default_rng(1)
    truth = _block(rng)
    from recon.model import to_reconstruction

    rec = to_reconstruction(truth)
    marks = _observed(truth, np.array([2.0, 1.0, 0.0]), rng, 0.05)
    marks[2] = type(marks[2])(marks[2].image_id, marks[2].uv + np.array([9.0, -4.0]))
    tri = triangulate_marks(rec, marks, max_error_px=3.0)
    assert 2 not in tri.used and len(tri.used) == len(marks) - 1
    assert np.linalg.norm(tri.xyz - [2.0, 1.0, 0.0]) < 0.05 and tri.reprojection_px < 0.2


# -- the stage on the tiny scene ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_project(tmp_path_factory):
    """The tiny scene, its sfm stage run (known cameras), and five points on its table with exact marks."""
    from data_synth import generate_scene, load_scene
    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named

    base = tmp_path_factory.mktemp("control")
    scene_root = generate_scene("tiny", base / "scene", seed=0)
    scene = load_scene(scene_root)
    project = base / "project"
    run_pipeline(project, ProjectConfig(input=InputOptions(path=str(scene_root))), stages=[stage_named("sfm")])
    xy = [(-0.15, -0.1), (0.15, -0.12), (0.12, 0.15), (-0.12, 0.12), (0.0, 0.0)]
    points = [ControlPoint(f"P{k}", np.array([x, y, 0.0]), Role.CHECK if k >= 3 else Role.CONTROL, 0.001, 0.002)
              for k, (x, y) in enumerate(xy)]  # fmt: skip
    marks = []
    for p in points:
        for v in scene.train:
            uv, z = scene.train.project(v, p.xyz_m[None])
            cam = scene.train.camera_of(v)
            if z[0] > 0 and 0 < uv[0, 0] < cam.width and 0 < uv[0, 1] < cam.height:
                marks.append(Mark(v.name, p.id, uv[0]))
    write_gcp_csv(base / "gcp.csv", points)
    write_marks_csv(base / "marks.csv", marks)
    return base, scene_root, project


def _run_control(base: Path, scene_root: Path, project: Path, **inputs):
    from hybridsplat.config import InputOptions, ProjectConfig
    from hybridsplat.pipeline import run_pipeline
    from hybridsplat.stages import stage_named

    work = base / f"p{len(list(base.iterdir()))}"
    shutil.copytree(project, work)
    config = ProjectConfig(input=InputOptions(path=str(scene_root), **inputs))
    return run_pipeline(work, config, stages=[stage_named("sfm"), stage_named("control")]), work


def test_control_stage_with_manual_marks_writes_the_adjusted_model_and_the_statement(tiny_project):
    import json

    from hybridsplat.layout import ProjectLayout
    from hybridsplat.project_io import sparse_model, stage_result
    from hybridsplat.stages.control import ControlStage

    base, scene_root, project = tiny_project
    inputs = {"control": str(base / "gcp.csv"), "marks": str(base / "marks.csv")}
    manifest, work = _run_control(base, scene_root, project, **inputs)
    layout = ProjectLayout(work)
    result = stage_result(manifest, ControlStage)
    assert result.control_points == 3 and result.check_points == 2 and result.manual > 0 and result.detected == 0
    assert result.adjusted and result.rmse_h_m is not None
    acc = json.loads(layout.control_accuracy.read_text())
    # exact marks on exact cameras: the check points agree to a fifth of the photos' ~9 mm pixel at the table (the
    # adjustment moves the cameras to the SIFT ties of 96 x 72 px photos too) ...
    assert acc["rmse_h_measured"] < 2e-3 and acc["rmse_v_measured"] < 2e-3
    # ... and the statement folds in the survey's 1 mm (per axis) and 2 mm
    assert result.rmse_h_m == pytest.approx(np.hypot(acc["rmse_h_measured"], np.sqrt(2) * 0.001))
    assert acc["rmse_h_survey"] == pytest.approx(np.sqrt(2) * 0.001) and acc["rmse_v_survey"] == pytest.approx(0.002)
    assert sparse_model(layout) == layout.control_sparse and layout.control_marks.is_file()


def _bad(base: Path, name: str, text: str) -> Path:
    path = base / name
    path.write_text(text)
    return path


def test_bad_control_input_names_the_file_and_the_line(tiny_project):
    base, scene_root, project = tiny_project
    gcp, marks = str(base / "gcp.csv"), base / "marks.csv"
    lines = marks.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ",P4," in ln)
    image = lines[k].split(",")[0]
    outside = [*lines[:k], f"{image},P4,500,10", *lines[k + 1 :]]
    cases = [
        (dict(marks=str(_bad(base, "m1.csv", "\n".join([*lines, "train_000.png,NOPE,10,10"]) + "\n"))),
         f"line {len(lines) + 1}: point 'NOPE' is not in the control file"),
        (dict(marks=str(_bad(base, "m2.csv", "\n".join(outside) + "\n"))),
         f"line {k + 1}: mark (500, 10) lies outside photo {image} (96 x 72 px)"),
        (dict(marks=str(_bad(base, "m3.csv", "\n".join(ln for ln in lines if ",P1," not in ln) + "\n"))),
         "line 4: point 'P1' has 0 mark(s) in the photos; it needs at least 2"),
        (dict(marks=str(marks), crs="EPSG:32632", control=str(_bad(base, "g.csv", "# crs: EPSG:25832\n"
                                                                     + (base / "gcp.csv").read_text()))),
         "line 1: the file's CRS EPSG:25832 disagrees with the run's CRS EPSG:32632"),
    ]  # fmt: skip
    for inputs, words in cases:
        inputs.setdefault("control", gcp)
        with pytest.raises(DataError) as info:
            _run_control(base, scene_root, project, **inputs)
        assert words in str(info.value)
        bad_file = inputs["marks"] if "NOPE" in words or "outside" in words else inputs["control"]
        assert str(bad_file) in str(info.value)
