"""Classes, labels, the random forest with skops persistence, and the fallback."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from classify.classes import UNLABELLED, ClassSet, load_classes
from classify.fallback import FALLBACK_FEATURES, fallback_predict
from classify.features import FeatureGroup, FeatureOptions, FeatureTable
from classify.labels import labels_from_field, labels_from_masks, point_truth, transfer_labels
from classify.model import ForestOptions, load_model, predict, same_forest, save_model, train
from core.cameras import Camera, Cameras, View
from core.errors import ConfigError, DataError, FormatError, InputFileError


def test_default_classes_and_kind_mapping(tmp_path):
    c = load_classes()
    assert c.names == ("collaborative", "reflective", "transparent", "textureless", "thin")
    kinds = {"textured": "collaborative", "mirror": "reflective", "metal": "reflective", "glass": "transparent",
             "textureless": "textureless", "thin": "thin"}  # fmt: skip
    for kind, name in kinds.items():
        assert c.by_code(c.code_of_kind(kind)).name == name
    assert list(c.needs_splats_of(np.array([0, 1, 2, 3, 4, 200]))) == [False, True, True, True, True, True]
    bad = tmp_path / "c.toml"
    bad.write_text('[[class]]\nname = "a"\n', encoding="utf-8")
    with pytest.raises(FormatError):
        load_classes(bad)
    with pytest.raises(InputFileError):
        load_classes(tmp_path / "missing.toml")
    bad.write_text('[[class]]\nname = "a"\ncode = 0\nneeds_splats = true\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="needs_splats = false"):
        load_classes(bad)


def test_point_truth_on_two_triangles():
    """A textured square at z = 0 and a mirror square at z = 1; τ = 0.05 m."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    mat = np.array([3, 3, 7, 7])
    kinds = {3: "textured", 7: "mirror"}
    pts = np.array([[0.5, 0.5, 0.01], [0.5, 0.5, 0.98], [0.5, 0.5, 0.3], [0.5, 0.5, 0.8]])
    t = point_truth(pts, v, f, mat, kinds, load_classes(), tau=0.05)
    assert list(t.codes[:2]) == [0, 1] and list(t.needs_splats) == [False, True, True, True]
    assert list(t.far) == [False, False, True, True]
    assert t.distance[2] == pytest.approx(0.3, abs=1e-6)
    # Far points take the class of the nearest non-collaborative surface (the mirror).
    assert list(t.codes[2:]) == [1, 1]


def test_point_truth_ambiguous_band_is_within_tau_of_both_kinds():
    """A textured floor (z = 0, x in [0, 1]) meets a mirror wall (x = 1, standing on the floor); τ = 0.05 m.
    Points within τ of both surfaces are ambiguous, whichever is nearest; the others are not."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1], [1, 0, 1]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    mat = np.array([3, 3, 7, 7])
    kinds = {3: "textured", 7: "mirror"}
    pts = np.array(
        [
            [0.97, 0.5, 0.01],  # nearest the floor (0.01), wall 0.03: ambiguous
            [0.99, 0.5, 0.04],  # nearest the wall (0.01), floor 0.04: ambiguous
            [0.90, 0.5, 0.01],  # floor 0.01, wall 0.10: not
            [0.99, 0.5, 0.50],  # wall 0.01, floor 0.50: not
            [0.94, 0.5, 0.04],  # floor 0.04, wall 0.06: not (the band is τ from each, not 2τ)
            [0.50, 0.5, 0.30],  # far from both: needs splats, not ambiguous
        ]
    )
    t = point_truth(pts, v, f, mat, kinds, load_classes(), tau=0.05)
    assert list(t.ambiguous) == [True, True, False, False, False, False]
    assert list(t.scored) == [False, False, True, True, True, True]
    assert list(t.needs_splats) == [False, True, False, True, False, True]
    # A scene with one kind of surface has no band.
    one = point_truth(pts, v, f, np.array([3, 3, 3, 3]), {3: "textured"}, load_classes(), tau=0.05)
    assert not one.ambiguous.any()


def test_labels_from_field_transfer_and_masks():
    c = load_classes()
    assert list(labels_from_field(np.array([2, 64, 65, 14, 99]), c)) == [0, 1, 2, 4, UNLABELLED]
    assert list(labels_from_field(np.array([0.0, 3.0, 9.0]), c, las_codes=False)) == [0, 3, UNLABELLED]
    src = np.array([[0.0, 0, 0], [1, 0, 0]])
    out = transfer_labels(src, np.array([1, 3], np.uint8), np.array([[0.1, 0, 0], [0.9, 0, 0], [5, 0, 0]]), 0.5)
    assert list(out) == [1, 3, UNLABELLED]
    # One camera looking down at z = 0; the left half of its label image is class 3, the right half class 0.
    cam = Camera.pinhole(40.0, 40.0, 20.0, 15.0, 40, 30)
    down = np.diag([1.0, -1.0, -1.0])
    cams = Cameras({1: cam}, {1: View.from_matrix(1, "a.png", 1, np.c_[down, -down @ np.array([0, 0, 1.0])])})
    mask = np.zeros((30, 40), np.uint8)
    mask[:, :20] = 3
    mask[:5] = UNLABELLED
    pts = np.array([[-0.2, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.36, 0.0], [3.0, 0, 0]])
    assert list(labels_from_masks(pts, cams, {"a.png": mask})) == [3, 0, UNLABELLED, UNLABELLED]
    vis = [np.array([1]), np.array([], np.int64), np.array([1]), np.array([1])]
    assert list(labels_from_masks(pts, cams, {"a.png": mask}, visibility=vis)) == [3, UNLABELLED, UNLABELLED, 255]


def _toy_table(n: int = 1500, seed: int = 0) -> tuple[FeatureTable, np.ndarray]:
    """Three separable classes in two features (feature a decides reflective, b textureless)."""
    rng = np.random.default_rng(seed)
    y = rng.choice(np.array([0, 1, 3], np.uint8), n, p=[0.7, 0.2, 0.1])
    a = (y == 1) + rng.normal(0, 0.1, n)
    b = (y == 3) + rng.normal(0, 0.1, n)
    return FeatureTable(("planarity_s0", "ncc_views"), np.c_[a, b].astype(np.float32), 0.01), y


def test_train_report_predict_and_roundtrip(tmp_path):
    table, y = _toy_table()
    y_lab = y.copy()
    y_lab[:50] = UNLABELLED
    opts = FeatureOptions(names=("planarity_s0", "ncc_views"))
    model, report = train(table, y_lab, load_classes(), opts, ForestOptions(n_estimators=8, seed=1, n_jobs=1))
    assert report.binary.f1 > 0.97 and report.n_train + report.n_test == len(y) - 50
    assert report.confusion.sum() == report.n_test and report.confusion.shape == (5, 5)
    assert abs(sum(report.importances.values()) - 1) < 1e-9
    path = save_model(model, tmp_path / "m.skops")
    loaded = load_model(path)
    assert loaded.feature_names == model.feature_names and loaded.classes == model.classes
    assert loaded.feature_options == opts
    p1, p2 = predict(model, table), predict(loaded, table)
    assert np.array_equal(p1.classification, p2.classification) and np.array_equal(p1.probability, p2.probability)
    assert (p1.classification == y).mean() > 0.97
    assert np.array_equal(p1.needs_splats, p1.classification != 0)
    # Same seed, same forest.
    model2, _ = train(table, y_lab, load_classes(), opts, ForestOptions(n_estimators=8, seed=1, n_jobs=2))
    assert np.array_equal(predict(model2, table).probability, p1.probability)
    assert same_forest(model, model2) and same_forest(model, loaded)
    other, _ = train(table, y_lab, load_classes(), opts, ForestOptions(n_estimators=8, seed=2, n_jobs=1))
    assert not same_forest(model, other)


def test_model_refuses_mismatched_features_and_bad_files(tmp_path):
    table, y = _toy_table(300)
    model, _ = train(table, y, load_classes(), FeatureOptions(), ForestOptions(n_estimators=2, n_jobs=1))
    swapped = FeatureTable(table.names[::-1], table.values[:, ::-1], 0.01)
    with pytest.raises(FormatError, match="another order"):
        predict(model, swapped)
    with pytest.raises(FormatError, match="missing: ncc_views"):
        predict(model, table.select(("planarity_s0",)))
    path = save_model(model, tmp_path / "m.skops")
    # A foreign file, a truncated one, a pickle, and an archive with a foreign type inside.
    (tmp_path / "text.skops").write_text("hello", encoding="utf-8")
    (tmp_path / "cut.skops").write_bytes(path.read_bytes()[:200])
    import pickle

    (tmp_path / "p.skops").write_bytes(pickle.dumps({"format": "hybridsplat-classifier"}))
    for bad in ("text.skops", "cut.skops", "p.skops"):
        with pytest.raises(FormatError):
            load_model(tmp_path / bad)
    import skops.io as sio

    sio.dump({"format": "hybridsplat-classifier", "version": 1, "forest": np.zeros(3), "meta": "{}"},
             tmp_path / "np.skops")  # fmt: skip
    with pytest.raises(FormatError):
        load_model(tmp_path / "np.skops")
    import datetime

    sio.dump({"format": "hybridsplat-classifier", "x": datetime.timedelta(1)}, tmp_path / "foreign.skops")
    with pytest.raises(FormatError, match="untrusted"):
        load_model(tmp_path / "foreign.skops")
    # Tampering with the stored schema is refused, not executed.
    with zipfile.ZipFile(path) as z:
        schema = z.read("schema.json").decode()
    tampered = tmp_path / "t.skops"
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(tampered, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "schema.json":
                data = schema.replace("sklearn.tree._classes", "os").encode()
            zout.writestr(item, data)
    with pytest.raises(FormatError):
        load_model(tampered)
    with pytest.raises(InputFileError):
        load_model(tmp_path / "none.skops")


def test_a_model_trained_with_a_removed_group_is_refused_naming_the_group(tmp_path):
    """A model file whose features or options name a feature group removed in 0.4 (written by an earlier version:
    here the metadata of a saved model rewritten) does not load: a FormatError naming the file and the group."""
    import json

    import skops.io as sio

    table, y = _toy_table(300)
    model, _ = train(table, y, load_classes(), FeatureOptions(), ForestOptions(n_estimators=2, n_jobs=1))
    path = save_model(model, tmp_path / "m.skops")
    payload = sio.load(path, trusted=sio.get_untrusted_types(file=path))
    meta = json.loads(payload["meta"])
    for where, change in (
        ("feature names", lambda m: m.update(feature_names=["planarity_s0", "texture_std_views"])),
        ("groups", lambda m: m["feature_options"].update(groups=["geometric", "image_texture"])),
    ):
        old = json.loads(json.dumps(meta))
        change(old)
        sio.dump({**payload, "meta": json.dumps(old)}, tmp_path / "old.skops")
        with pytest.raises(FormatError, match="feature group.s. image_texture, removed in 0.4") as err:
            load_model(tmp_path / "old.skops")
        assert "old.skops" in err.value.one_line(), where
    assert load_model(path).feature_names == model.feature_names  # the unchanged file still loads


def test_fallback_rules():
    names = FALLBACK_FEATURES
    rows = np.array(
        [
            [0.0, 0.01, 0.8, 6, 0.001, 0.1],  # good
            [0.5, 0.01, 0.8, 6, 0.001, 0.1],  # sees-past -> reflective
            [0.0, 0.01, 0.1, 6, 0.001, 0.1],  # flat patches -> textureless
            [0.0, 0.01, 0.8, 2, 0.001, 0.95],  # weak and linear -> thin
        ],
        np.float32,
    )
    c = load_classes()
    p = fallback_predict(FeatureTable(names, rows, 0.01), c)
    assert list(p.needs_splats) == [False, True, True, True]
    assert [c.by_code(x).name for x in p.classification] == ["collaborative", "reflective", "textureless", "thin"]
    with pytest.raises(ConfigError, match="fallback needs"):
        fallback_predict(FeatureTable(("red",), rows[:, :1], 0.01), c)
    assert FeatureOptions(groups=(FeatureGroup.MULTIVIEW,)).selected()[0] == "n_views"


def test_class_set_validation():
    with pytest.raises(ConfigError):
        ClassSet(())


def test_threshold_is_the_f1_optimum_on_held_out_points():
    """Truth = p ≥ 0.7 exactly: the best F1 threshold on the grid is 0.7 (F1 = 1); no positives → 0.5."""
    from classify.model import _best_threshold

    p = np.linspace(0, 1, 2001)
    assert _best_threshold(p, p >= 0.7) == pytest.approx(0.7)
    assert _best_threshold(p, np.zeros_like(p, dtype=bool)) == 0.5


def test_spatial_groups_are_blocks():
    from classify.model import spatial_groups

    pts = np.array([[0.0, 0, 0], [0.4, 0.4, 0.4], [1.2, 0, 0], [0, 1.1, 0], [1.9, 0.1, 0.2]])
    g = spatial_groups(pts, 1.0, offset=10)
    assert g[0] == g[1] and g[2] == g[4] and len({g[0], g[2], g[3]}) == 3 and g.min() >= 10
    with pytest.raises(ConfigError):
        spatial_groups(pts, 0.0)


def test_grouped_out_of_fold_report_and_smoothing():
    """With groups every labelled row gets an out-of-fold prediction (the report covers them all); with
    neighbours the model smooths, and predicting without neighbours is refused."""
    from dataclasses import replace

    from scipy.spatial import cKDTree

    from classify.model import spatial_groups

    table, y = _toy_table(2000)
    rng = np.random.default_rng(3)
    pos = rng.uniform(0, 10, (len(y), 3))
    groups = spatial_groups(pos, 2.5)
    opts = FeatureOptions(names=("planarity_s0", "ncc_views"))
    forest = ForestOptions(n_estimators=8, n_jobs=1)
    model, report = train(table, y, load_classes(), opts, forest, groups=groups)
    assert report.n_test == len(y) and model.info["held_out"]["grouped"] and model.info["smooth_passes"] == 0
    assert report.binary.f1 > 0.9 and 0.05 <= model.info["threshold"] <= 0.95
    nb = cKDTree(pos).query(pos, k=5)[1][:, 1:]
    with_nb = replace(table, neighbours=nb)
    smoothed, _ = train(with_nb, y, load_classes(), opts, forest, groups=groups)
    assert smoothed.info["smooth_passes"] == 1
    assert len(predict(smoothed, with_nb).classification) == len(y)
    with pytest.raises(DataError):
        predict(smoothed, table)
    assert predict(smoothed, table, smooth_passes=0).classification.shape == (len(y),)


def test_smoothing_is_the_neighbourhood_mean():
    from classify.model import smooth_probabilities

    p = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 1.0], [1.0, 0.0]], np.float32)
    nb = np.array([[1], [2], [1], [0]])
    one = smooth_probabilities(p, nb, 1)
    np.testing.assert_allclose(one, [[0.5, 0.5], [0, 1], [0, 1], [1, 0]])
    np.testing.assert_allclose(smooth_probabilities(p, nb, 2), smooth_probabilities(one, nb, 1))


def test_threshold_per_project_counts_each_project_once():
    """Project A (10 001 points, truth p ≥ 0.7) dominates the pooled F1: best cut 0.7. Project B (200 points:
    negatives at p = 0.1, positives at 0.35) has F1 1 only for cuts in (0.1, 0.35]; the mean of the two projects'
    F1 is best at 0.35 (A keeps F1 0.63 there, B drops to 0 above it)."""
    from classify.model import _best_threshold

    pa = np.linspace(0, 1, 10001)
    p = np.r_[pa, np.full(100, 0.1), np.full(100, 0.35)]
    truth = np.r_[pa >= 0.7, np.zeros(100, bool), np.ones(100, bool)]
    groups = np.r_[np.zeros(len(pa), int), np.ones(200, int)]
    assert _best_threshold(p, truth) == pytest.approx(0.7)
    assert _best_threshold(p, truth, groups) == pytest.approx(0.35)


def test_scene_scores_out_of_fold_never_see_their_own_scene():
    """Four scenes: in A, B and C feature a marks the reflective points (b is 0); in D feature b does (a is 0).
    Scored out of fold, D is predicted by forests that never saw b vary and so finds none (F1 0; in-sample it
    would be 1), while A–C, predicted by forests that saw two scenes of their rule, stay near 1. Ambiguous points
    are left out of the support."""
    from types import SimpleNamespace

    from classify.training import scene_scores_out_of_fold, train_on_scenes

    classes = load_classes()
    rng = np.random.default_rng(5)
    datas = []
    for by_b in (False, False, False, True):
        n = 600
        y = rng.choice(np.array([0, 1], np.uint8), n, p=[0.7, 0.3])
        marked = (y == 1) + rng.normal(0, 0.05, n)
        a, b = (np.zeros(n), marked) if by_b else (marked, np.zeros(n))
        table = FeatureTable(("planarity_s0", "ncc_views"), np.c_[a, b].astype(np.float32), 0.01)
        ambiguous = np.zeros(n, bool)
        ambiguous[:50] = True
        truth = SimpleNamespace(codes=y, needs_splats=y == 1, ambiguous=ambiguous, scored=~ambiguous)
        datas.append(SimpleNamespace(table=table, truth=truth))
    opts = FeatureOptions(names=("planarity_s0", "ncc_views"))
    model, report = train_on_scenes(datas, classes, opts, ForestOptions(n_estimators=8, n_jobs=1))
    assert report.out_of_fold_needs is not None and len(report.out_of_fold_needs) == 4 * 600
    per_scene = scene_scores_out_of_fold(datas, report, float(model.info["threshold"]))
    assert [s.f1 > 0.95 for s in per_scene] == [True, True, True, False]
    assert per_scene[3].f1 < 0.1
    for d, s in zip(datas, per_scene, strict=True):
        assert s.support == int((d.truth.needs_splats & ~d.truth.ambiguous).sum())
    with pytest.raises(DataError):
        scene_scores_out_of_fold(datas[:3], report, 0.5)


def test_shipped_model_matches_its_recipe():
    """The shipped default model was trained by scripts/train_default_classifier.py on the listed scenes with the
    recipe the code states (so that the script reproduces it), and stays within the 5 MB the issue allows."""
    from dataclasses import asdict, replace

    from classify.run import DEFAULT_MODEL
    from classify.training import DEFAULT_FOREST, DEFAULT_TRAINING_SCENES, SCENE_FOLDS

    assert DEFAULT_MODEL.stat().st_size <= 5_000_000
    model = load_model(DEFAULT_MODEL)
    assert model.info["trained_by"] == "scripts/train_default_classifier.py"
    assert model.info["scenes"] == [s.to_dict() for s in DEFAULT_TRAINING_SCENES]
    assert model.info["forest_options"] == asdict(replace(DEFAULT_FOREST, folds=SCENE_FOLDS))
    assert model.feature_names == FeatureOptions().selected()
    assert model.info["ignore_band"] is False and 0.05 <= model.info["threshold"] <= 0.95
