"""The random forest: training with a held-out report, prediction, and persistence with skops (never pickle).

A saved model is one ``.skops`` file holding the forest, the feature names it was trained on (in column
order), the feature options that define those features (scales, k), and the class set. Loading checks that
the file is a hybridsplat classifier and contains only trusted types; predicting checks the features.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import ClassVar

import numpy as np

from classify.classes import UNLABELLED, ClassSet
from classify.features import FeatureOptions, FeatureTable
from classify.features.geometric import GeometricOptions
from classify.features.multiview import MultiViewOptions
from core.constraints import Choice, Constrained, Constraints, Interval, NoneOr
from core.errors import ConfigError, DataError, FormatError, InputFileError
from core.io.atomic import atomic_path

MODEL_FORMAT = "hybridsplat-classifier"
MODEL_VERSION = 1


@dataclass(frozen=True)
class ForestOptions(Constrained):
    """Random-forest hyper-parameters (scikit-learn names). Defaults keep a model under 5 MB.

    n_estimators: trees (32). max_depth: depth limit (14). min_samples_leaf: 5 (the better leave-one-scene-out F1 on the
    default model's training scenes; see docs/experiments/2026-11-27-domain-defaults.md). class_weight: "balanced"
    (classes weighted by inverse frequency; None = unweighted). max_samples_per_class: points per class drawn (seeded)
    for training, bounding time and size (50 000). n_jobs: threads (-1: all). seed: every random choice.
    smooth_passes: passes of averaging the class probabilities over each point's finest neighbourhood before
    the decision (1; 0 = none). Needs-splats regions are contiguous surfaces: averaging removes isolated false
    positives and fills gaps (chosen on held-out scenes; see docs/experiments/2026-11-27-domain-defaults.md). Used
    only when training has spatial groups and neighbours (else 0 is recorded).
    folds: grouped folds of the out-of-fold predictions that choose the threshold and make the report (3).
    """

    n_estimators: int = 32
    max_depth: int | None = 14
    min_samples_leaf: int = 5
    class_weight: str | None = "balanced"
    max_samples_per_class: int = 50_000
    n_jobs: int = -1
    seed: int = 0
    smooth_passes: int = 1
    folds: int = 3

    constraints: ClassVar[Constraints] = {
        "n_estimators": Interval(int, 1, None),
        "min_samples_leaf": Interval(int, 1, None),
        "class_weight": NoneOr(Choice(("balanced", "balanced_subsample"))),
        "max_samples_per_class": Interval(int, 1, None),
        "smooth_passes": Interval(int, 0, None),
        "folds": Interval(int, 2, None),
    }


@dataclass
class ClassifierModel:
    """A trained forest with what defines its input and output.

    forest: sklearn RandomForestClassifier. feature_names: the columns it expects, in order. feature_options:
    the options that define those features (geometric scales, k, multi-view tolerance). classes: the class set.
    info: free provenance (training scenes, seeds, report summary).
    """

    forest: object
    feature_names: tuple[str, ...]
    feature_options: FeatureOptions
    classes: ClassSet
    info: dict[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class ClassScores:
    """Held-out scores of one class: precision, recall, F1 and support (points)."""

    name: str
    precision: float
    recall: float
    f1: float
    support: int


@dataclass(frozen=True)
class TrainingReport:
    """Held-out evaluation of a training run.

    per_class: scores per class. binary: scores of "needs splats" as the positive class. confusion: (C, C) int64,
    rows true, columns predicted, in ``class_names`` order. importances: feature name → mean decrease in impurity.
    n_train / n_test: points. out_of_fold_needs: (N,) float32 needs-splats probability of every row of the training
    table from a forest that did not see its group (smoothed as the model will smooth), when training had grouped
    folds, else None: per-scene held-out scores of a recipe (:func:`classify.training.scene_scores_out_of_fold`).
    """

    per_class: tuple[ClassScores, ...]
    binary: ClassScores
    confusion: np.ndarray
    class_names: tuple[str, ...]
    importances: dict[str, float]
    n_train: int
    n_test: int
    out_of_fold_needs: np.ndarray | None = None

    def to_dict(self) -> dict[str, object]:
        return {
            "per_class": [asdict(c) for c in self.per_class],
            "needs_splats": asdict(self.binary),
            "confusion": self.confusion.tolist(),
            "class_names": list(self.class_names),
            "importances": self.importances,
            "n_train": self.n_train,
            "n_test": self.n_test,
        }


def _balanced_sample(labels: np.ndarray, per_class: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    picked = []
    for code in np.unique(labels):
        idx = np.flatnonzero(labels == code)
        picked.append(idx if len(idx) <= per_class else rng.choice(idx, per_class, replace=False))
    return np.sort(np.concatenate(picked)) if picked else np.zeros(0, np.int64)


def scores(truth: np.ndarray, pred: np.ndarray, name: str) -> ClassScores:
    """Precision / recall / F1 of a boolean prediction (N,) against boolean truth (N,)."""
    t, p = np.asarray(truth, bool), np.asarray(pred, bool)
    tp = int(np.count_nonzero(t & p))
    prec = tp / max(int(p.sum()), 1)
    rec = tp / max(int(t.sum()), 1)
    f1 = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
    return ClassScores(name, prec, rec, f1, int(t.sum()))


def _best_threshold(p_needs: np.ndarray, truth: np.ndarray, groups: np.ndarray | None = None) -> float:
    """The needs-splats probability threshold (0.05..0.95, step 0.025) with the best binary F1 of held-out points
    drawn with the data's own class frequencies (not the balanced training sample: balanced class weights favour
    the rare needs-splats classes, and this moves the decision back to the data's prior).

    groups: (N,) project of each point: the threshold maximises the mean of the projects' F1 (each project counts
    once, however many points or positives it has), else the F1 of all points pooled."""
    if len(p_needs) == 0 or not truth.any():
        return 0.5
    grid = np.round(np.arange(0.05, 0.951, 0.025), 3)
    if groups is None:
        f1 = [scores(truth, p_needs >= t, "t").f1 for t in grid]
    else:
        members = [groups == g for g in np.unique(groups) if truth[groups == g].any()]
        f1 = [float(np.mean([scores(truth[m], p_needs[m] >= t, "t").f1 for m in members])) for t in grid]
    return float(grid[int(np.argmax(f1))])


def _forest(options: ForestOptions) -> object:
    from sklearn.ensemble import RandomForestClassifier

    return RandomForestClassifier(
        n_estimators=options.n_estimators,
        max_depth=options.max_depth,
        min_samples_leaf=options.min_samples_leaf,
        class_weight=options.class_weight,
        n_jobs=options.n_jobs,
        random_state=options.seed,
    )


def smooth_probabilities(proba: np.ndarray, neighbours: np.ndarray, passes: int = 1) -> np.ndarray:
    """Each row of ``proba`` (N, C) float replaced by the mean over the point and its ``neighbours`` ((N, m) int64,
    the point's nearest others), ``passes`` times: (N, C) float32. Written by hand (numba) because the gather of
    N × m rows would otherwise need an (N, m, C) temporary."""
    out = np.ascontiguousarray(proba, dtype=np.float32)
    nb = np.ascontiguousarray(neighbours, dtype=np.int64)
    if len(nb) != len(out):
        raise DataError(f"{len(nb)} neighbour rows for {len(out)} probability rows")
    for _ in range(passes):
        out = _smooth_kernel(out, nb)
    return out


def _smooth_kernel(p: np.ndarray, nb: np.ndarray) -> np.ndarray:
    from classify.features.eigen_numba import smooth_rows

    return smooth_rows(p, nb)


def _decide(
    proba: np.ndarray, trained: np.ndarray, classes: ClassSet, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """classification (N,) uint8, its probability (N,) float32, needs_splats (N,) bool, p_needs (N,) float32."""
    best = proba.argmax(axis=1)
    cls = trained[best].astype(np.uint8)
    prob = proba[np.arange(len(best)), best].astype(np.float32)
    pns = proba[:, classes.needs_splats_of(trained)].sum(axis=1).astype(np.float32)
    return cls, prob, pns >= threshold, pns


def train(
    table: FeatureTable,
    labels: np.ndarray,
    classes: ClassSet,
    feature_options: FeatureOptions,
    options: ForestOptions = ForestOptions(),
    test_fraction: float = 0.25,
    info: dict[str, object] | None = None,
    groups: np.ndarray | None = None,
    groups_are_projects: bool | None = None,
) -> tuple[ClassifierModel, TrainingReport]:
    """Train a forest on the labelled rows of ``table`` (labels (N,) uint8 codes, UNLABELLED ignored), seeded.

    The forest is fitted on a class-balanced sample (at most ``max_samples_per_class`` per class). The report
    and the needs-splats threshold come from held-out points that keep the data's class frequencies:
    groups: (N,) int64 group of each row: spatial blocks (:func:`spatial_groups`) or whole scenes (a fold per
    scene when ``options.folds`` ≥ their number: each scene is predicted by a forest that never saw it, as a new
    project will be). ``min(options.folds, groups)`` grouped folds give every row an out-of-fold prediction
    (whole blocks held out, so neighbouring points, which share their
    neighbourhoods, are never on both sides); with ``table.neighbours`` the out-of-fold probabilities are smoothed
    as :func:`predict` will smooth them (``smooth_passes``). groups_are_projects: the threshold maximises the mean
    of the groups' F1 (each project counts once) — by default when there is a fold per group. Without groups: one
    held-out split by point
    (``test_fraction``, stratified, optimistic) and no smoothing. Score across scenes
    (``bench/bench_classify.py``) for the honest figure.
    """
    y = np.asarray(labels, dtype=np.uint8)
    rows = _labelled_rows(table, y, classes, groups)
    x = table.values
    n_groups = len(np.unique(np.asarray(groups)[rows])) if groups is not None else 0
    grouped = n_groups >= 2
    folds = min(options.folds, n_groups)
    smooth = options.smooth_passes if grouped and table.neighbours is not None else 0
    oof_needs = None
    if grouped:
        proba = _out_of_fold_proba(x, y, rows, np.asarray(groups), folds, classes, options)
        if smooth:
            proba = smooth_probabilities(proba, table.neighbours, smooth)  # type: ignore[arg-type]
        oof_needs = proba[:, classes.needs_splats_of(classes.codes)].sum(axis=1).astype(np.float32)
        test = rows
        p_test = proba[test]
        n_train = len(rows)
    else:
        test, p_test, n_train = _held_out_split(x, y, rows, classes, options, test_fraction)
    # Leave-one-group-out (a fold per group: the groups are projects): each project counts once in the threshold.
    if groups_are_projects is None:
        groups_are_projects = folds == n_groups
    per_project = np.asarray(groups)[test] if grouped and groups_are_projects else None
    threshold, per_class, binary, conf = _held_out_scores(y[test], p_test, classes, per_project)
    every = rows[_balanced_sample(y[rows], options.max_samples_per_class, options.seed)]
    final = _forest(options)
    final.fit(x[every], y[every])  # type: ignore[attr-defined]
    imp = dict(zip(table.names, (float(v) for v in final.feature_importances_), strict=True))  # type: ignore[attr-defined]
    report = TrainingReport(per_class, binary, conf, classes.names, imp, n_train, len(test), oof_needs)
    model = ClassifierModel(final, table.names, feature_options, classes, dict(info or {}))
    model.info["forest_options"] = asdict(options)
    model.info["held_out"] = {"needs_splats_f1": binary.f1, "n_test": len(test), "grouped": bool(grouped)}
    model.info["threshold"] = threshold
    model.info["smooth_passes"] = int(smooth)
    return model, report


def _labelled_rows(table: FeatureTable, y: np.ndarray, classes: ClassSet, groups: np.ndarray | None) -> np.ndarray:
    """Indices (int64) of the rows with a label, after checking the labels (N,) uint8 and groups against the table."""
    if len(y) != len(table.values):
        raise DataError(f"{len(y)} labels for {len(table.values)} points")
    if groups is not None and len(groups) != len(y):
        raise DataError(f"{len(groups)} groups for {len(y)} points")
    unknown = set(np.unique(y).tolist()) - set(classes.codes.tolist()) - {UNLABELLED}
    if unknown:
        raise DataError(f"labels use codes {sorted(unknown)} that the class set does not define")
    rows = np.flatnonzero(y != UNLABELLED)
    if len(rows) < 10:
        raise DataError(f"training needs at least 10 labelled points, got {len(rows)}")
    return rows


def _out_of_fold_proba(
    x: np.ndarray,
    y: np.ndarray,
    rows: np.ndarray,
    groups: np.ndarray,
    folds: int,
    classes: ClassSet,
    options: ForestOptions,
) -> np.ndarray:
    """(N, C) float32 out-of-fold probabilities of every row (labelled or not: smoothing reads the neighbours' too),
    columns in ``classes.codes`` order: groups are dealt to ``folds`` folds (seeded), and each fold is predicted by
    a forest fitted on a balanced sample of the other folds' labelled ``rows``."""
    ids = np.unique(groups, return_inverse=True)[1].reshape(-1)
    rng = np.random.default_rng(options.seed)
    fold_of_group = rng.permutation(np.arange(ids.max() + 1) % folds)
    fold = fold_of_group[ids]
    proba = np.zeros((len(y), len(classes.codes)), dtype=np.float32)
    col_of = {int(c): i for i, c in enumerate(classes.codes)}
    for f in range(folds):
        fit_rows = rows[fold[rows] != f]
        fit_rows = fit_rows[_balanced_sample(y[fit_rows], options.max_samples_per_class, options.seed)]
        forest = _forest(options)
        forest.fit(x[fit_rows], y[fit_rows])  # type: ignore[attr-defined]
        out = np.flatnonzero(fold == f)
        if len(out):
            cols = [col_of[int(c)] for c in forest.classes_]  # type: ignore[attr-defined]
            proba[np.ix_(out, cols)] = forest.predict_proba(x[out])  # type: ignore[attr-defined]
    return proba


def _held_out_split(
    x: np.ndarray, y: np.ndarray, rows: np.ndarray, classes: ClassSet, options: ForestOptions, test_fraction: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """One split of the labelled ``rows`` by point (stratified when every class has 2 rows): the held-out rows, their
    (M, C) float32 probabilities from a forest fitted on a balanced sample of the rest, and that sample's size."""
    from sklearn.model_selection import train_test_split

    present, counts = np.unique(y[rows], return_counts=True)
    stratify = y[rows] if counts.min() >= 2 and len(present) > 1 else None
    tr, te = train_test_split(rows, test_size=test_fraction, random_state=options.seed, stratify=stratify)
    tr = tr[_balanced_sample(y[tr], options.max_samples_per_class, options.seed)]
    forest = _forest(options)
    forest.fit(x[tr], y[tr])  # type: ignore[attr-defined]
    col_of = {int(c): i for i, c in enumerate(classes.codes)}
    p_test = np.zeros((len(te), len(classes.codes)), dtype=np.float32)
    cols = [col_of[int(c)] for c in forest.classes_]  # type: ignore[attr-defined]
    p_test[:, cols] = forest.predict_proba(x[te])  # type: ignore[attr-defined]
    return te, p_test, len(tr)


def _held_out_scores(
    yte: np.ndarray, p_test: np.ndarray, classes: ClassSet, per_project: np.ndarray | None
) -> tuple[float, tuple[ClassScores, ...], ClassScores, np.ndarray]:
    """From held-out labels (M,) and probabilities (M, C): the needs-splats threshold, the per-class scores, the
    binary needs-splats scores at that threshold, and the (C, C) int64 confusion (rows true, columns predicted)."""
    truth_needs = classes.needs_splats_of(yte)
    p_needs = p_test[:, classes.needs_splats_of(classes.codes)].sum(axis=1)
    threshold = _best_threshold(p_needs, truth_needs, per_project)
    pred = classes.codes[p_test.argmax(axis=1)].astype(np.uint8)
    per_class = tuple(scores(yte == c.code, pred == c.code, c.name) for c in classes.classes)
    binary = scores(truth_needs, p_needs >= threshold, "needs_splats")
    pos = {int(c): i for i, c in enumerate(classes.codes)}
    conf = np.zeros((len(classes.codes), len(classes.codes)), dtype=np.int64)
    np.add.at(conf, (np.array([pos[int(t)] for t in yte], dtype=np.int64),
                     np.array([pos[int(q)] for q in pred], dtype=np.int64)), 1)  # fmt: skip
    return threshold, per_class, binary, conf


def spatial_groups(positions: np.ndarray, block: float, offset: int = 0) -> np.ndarray:
    """(N,) int64 id of the cubic block of side ``block`` metres holding each point (positions (N, 3) float64),
    plus ``offset`` (give each scene its own range when several are stacked), for :func:`train`'s ``groups``."""
    if not (block > 0 and np.isfinite(block)):
        raise ConfigError(f"block must be a positive length in metres, got {block}")
    pts = np.asarray(positions, dtype=np.float64)
    if len(pts) == 0:
        return np.zeros(0, np.int64)
    keys = np.floor((pts - pts.min(axis=0)) / block).astype(np.int64)
    _, ids = np.unique(keys, axis=0, return_inverse=True)
    return ids.reshape(-1).astype(np.int64) + int(offset)


@dataclass(frozen=True)
class Prediction:
    """Per point: classification (N,) uint8 code, probability (N,) float32 of that class, needs_splats (N,) bool,
    p_needs_splats (N,) float32 (summed probability of the needs-splats classes)."""

    classification: np.ndarray
    probability: np.ndarray
    needs_splats: np.ndarray
    p_needs_splats: np.ndarray


def predict(
    model: ClassifierModel,
    table: FeatureTable,
    chunk_size: int = 500_000,
    threshold: float = 0.5,
    smooth_passes: int | None = None,
) -> Prediction:
    """Classify every row of ``table``; its feature names must be the model's (else :class:`FormatError`).

    The class probabilities are smoothed over each point's neighbours (``table.neighbours``) ``smooth_passes``
    times (None: the model's own setting, ``info["smooth_passes"]``); a model that smooths and a table without
    neighbours raise :class:`DataError`. needs_splats = summed probability of the needs-splats classes ≥
    ``threshold`` (the binary decision the masks use); classification = the most probable class.
    """
    if tuple(table.names) != tuple(model.feature_names):
        missing = [n for n in model.feature_names if n not in table.names]
        extra = [n for n in table.names if n not in model.feature_names]
        raise FormatError(
            f"the model expects {len(model.feature_names)} features, the data has {len(table.names)} "
            f"(missing: {', '.join(missing) or 'none'}; extra: {', '.join(extra) or 'none'}; or another order)"
        )
    passes = int(model.info.get("smooth_passes", 0)) if smooth_passes is None else int(smooth_passes)  # type: ignore[call-overload]
    if passes and table.neighbours is None:
        raise DataError("this model smooths its probabilities over neighbours, but the feature table has none")
    forest = model.forest
    trained = np.asarray(forest.classes_, dtype=np.uint8)  # type: ignore[attr-defined]
    n = len(table.values)
    proba = np.empty((n, len(trained)), dtype=np.float32)
    for start in range(0, n, chunk_size):
        sl = slice(start, min(n, start + chunk_size))
        proba[sl] = forest.predict_proba(table.values[sl])  # type: ignore[attr-defined]
    if passes:
        proba = smooth_probabilities(proba, table.neighbours, passes)  # type: ignore[arg-type]
    return Prediction(*_decide(proba, trained, model.classes, threshold))


# -- persistence ------------------------------------------------------------------------------------------------
def _options_to_dict(o: FeatureOptions) -> dict[str, object]:
    return {
        "names": list(o.names) if o.names is not None else None,
        "groups": [g.value for g in o.groups],
        "geometric": asdict(o.geometric) | {"voxel_factors": list(o.geometric.voxel_factors)},
        "multiview": asdict(o.multiview),
    }


def _options_from_dict(d: dict[str, object]) -> FeatureOptions:
    from classify.features import FeatureGroup

    g = dict(d["geometric"])  # type: ignore[arg-type]
    g["voxel_factors"] = tuple(g["voxel_factors"])
    names = d.get("names")
    return FeatureOptions(
        names=tuple(names) if names is not None else None,  # type: ignore[arg-type]
        groups=tuple(FeatureGroup(x) for x in d["groups"]),  # type: ignore[union-attr]
        geometric=GeometricOptions(**g),
        multiview=MultiViewOptions(**d["multiview"]),  # type: ignore[arg-type]
    )


def _refuse_removed_groups(names: tuple[str, ...], options: object, path: Path) -> None:
    """A :class:`FormatError` naming the removed feature groups (:data:`classify.features.registry.REMOVED_GROUPS`)
    that a model's features or options use: it cannot be given its features any more."""
    from classify.features.registry import REMOVED_WHY, removed_groups

    listed = [*names]
    if isinstance(options, dict):
        for key in ("groups", "names"):
            if isinstance(options.get(key), list):
                listed += [str(x) for x in options[key]]  # type: ignore[union-attr]
    gone = removed_groups(listed)
    if gone:
        raise FormatError(
            f"the model was trained with the feature group(s) {', '.join(gone)}, {REMOVED_WHY}; train it again "
            "without them (hybridsplat classify train)",
            path,
        )


def same_forest(a: ClassifierModel, b: ClassifierModel) -> bool:
    """True when the two models' forests have the same trees node for node (structure, split features, thresholds,
    leaf values), the same features and classes. Two skops files of one forest differ in bytes (member names are
    object ids, entries carry timestamps), so reproducibility is checked on the trees."""
    fa, fb = a.forest, b.forest
    if a.feature_names != b.feature_names or len(fa.estimators_) != len(fb.estimators_):  # type: ignore[attr-defined]
        return False
    if not np.array_equal(fa.classes_, fb.classes_):  # type: ignore[attr-defined]
        return False
    fields = ("children_left", "children_right", "feature", "threshold", "value")
    for ta, tb in zip(fa.estimators_, fb.estimators_, strict=True):  # type: ignore[attr-defined]
        if not all(np.array_equal(getattr(ta.tree_, f), getattr(tb.tree_, f)) for f in fields):
            return False
    return True


def save_model(model: ClassifierModel, path: str | PathLike[str]) -> Path:
    """Write the model as a skops file, atomically. The feature list, options and classes travel as JSON."""
    import skops.io as sio

    path = Path(path)
    payload = {
        "format": MODEL_FORMAT,
        "version": MODEL_VERSION,
        "forest": model.forest,
        "meta": json.dumps(
            {
                "feature_names": list(model.feature_names),
                "feature_options": _options_to_dict(model.feature_options),
                "classes": model.classes.to_dict(),
                "info": model.info,
            }
        ),
    }
    with atomic_path(path) as tmp:
        sio.dump(payload, tmp, compression=8)  # zipfile.ZIP_DEFLATED
    return path


def load_model(path: str | PathLike[str]) -> ClassifierModel:
    """Read a model written by :func:`save_model`.

    A missing file raises :class:`InputFileError`; a file that is not a skops archive, holds types other than
    scikit-learn's forest (a tampered or foreign file: nothing untrusted is ever instantiated), or is not a
    hybridsplat classifier raises :class:`FormatError`.
    """
    import skops.io as sio

    path = Path(path)
    if not path.is_file():
        raise InputFileError("model file does not exist", path)
    try:
        untrusted = sio.get_untrusted_types(file=path)
    except Exception as err:  # skops raises zipfile / json / key errors for foreign files
        raise FormatError(f"not a skops model file ({type(err).__name__}: {err})", path) from err
    allowed = {
        "sklearn.ensemble._forest.RandomForestClassifier",
        "sklearn.tree._classes.DecisionTreeClassifier",
        "sklearn.tree._tree.Tree",
    }
    foreign = sorted(set(untrusted) - allowed)
    if foreign:
        raise FormatError(f"model file holds untrusted types {foreign}: refusing to load it", path)
    try:
        payload = sio.load(path, trusted=sorted(set(untrusted)))
    except Exception as err:
        raise FormatError(f"model file is damaged ({type(err).__name__}: {err})", path) from err
    if not isinstance(payload, dict) or payload.get("format") != MODEL_FORMAT:
        raise FormatError("not a hybridsplat classifier (format tag missing)", path)
    if payload.get("version") != MODEL_VERSION:
        got = payload.get("version")
        raise FormatError(f"classifier version {got} is not supported (expected {MODEL_VERSION})", path)
    from sklearn.ensemble import RandomForestClassifier

    forest = payload.get("forest")
    if not isinstance(forest, RandomForestClassifier):
        raise FormatError(f"model holds {type(forest).__name__}, not a RandomForestClassifier", path)
    try:
        meta = json.loads(payload["meta"])
        names = tuple(str(n) for n in meta["feature_names"])
        _refuse_removed_groups(names, meta["feature_options"], path)
        options = _options_from_dict(meta["feature_options"])
        classes = ClassSet.from_dict(meta["classes"], path)
    except (KeyError, TypeError, ValueError) as err:
        raise FormatError(f"model metadata is incomplete ({err})", path) from err
    if getattr(forest, "n_features_in_", len(names)) != len(names):
        raise FormatError(f"forest expects {forest.n_features_in_} features, the metadata lists {len(names)}", path)
    return ClassifierModel(forest, names, options, classes, dict(meta.get("info", {})))
