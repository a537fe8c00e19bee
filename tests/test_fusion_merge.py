"""fusion.merge: class filter, duplicate resolution against brute force, provenance fields and origins."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import ConfigError, DataError
from core.gaussians import GaussianSet
from fusion.convert import Source
from fusion.merge import (
    MergeOptions,
    MergeWarning,
    Prefer,
    first_within_tolerance,
    merge_gaussians,
    merge_hybrid,
    near_any,
)


def _set(means, origin=(0.0, 0.0, 0.0), degree=0, classes=None, seed=0) -> GaussianSet:
    rng = np.random.default_rng(seed)
    means = np.asarray(means, float)
    n = len(means)
    fields = {} if classes is None else {"classification": np.asarray(classes, np.uint8)}
    return GaussianSet(
        means,
        rng.uniform(-5, -2, (n, 3)),
        np.tile([1.0, 0, 0, 0], (n, 1)),
        rng.uniform(-1, 3, n),
        rng.normal(size=(n, 3)),
        rng.normal(size=(n, (degree + 1) ** 2 - 1, 3)),
        np.asarray(origin, float),
        fields,
    )


def _brute_first_within(points, tol):
    keep = np.ones(len(points), bool)
    for j in range(len(points)):
        for i in range(j):
            if np.linalg.norm(points[i] - points[j]) <= tol:
                keep[j] = False
                break
    return keep


def test_first_within_tolerance_and_near_any_match_brute_force():
    rng = np.random.default_rng(0)
    pts = np.round(rng.random((300, 3)) * 4) / 4  # many exact duplicates and pairs at 0.25
    pts[::7] += rng.normal(scale=1e-4, size=(len(pts[::7]), 3))
    for tol in (0.0, 1e-3, 0.25, 0.3):
        np.testing.assert_array_equal(first_within_tolerance(pts, tol), _brute_first_within(pts, tol))
        kept = pts[first_within_tolerance(pts, tol)]
        d = np.linalg.norm(kept[:, None] - kept[None], axis=2)
        np.fill_diagonal(d, np.inf)
        assert d.min() > tol
    q = rng.random((100, 3)) * 4
    for tol in (0.0, 0.25, 0.5):
        brute = (np.linalg.norm(q[:, None] - pts[None], axis=2) <= tol).any(axis=1)
        np.testing.assert_array_equal(near_any(q, pts, tol), brute)
    assert near_any(np.array([[0.0, 0, 0]]), np.array([[0.25, 0, 0]]), 0.25)[0]  # inclusive bound


def test_merge_drops_classes_and_duplicates_and_keeps_provenance():
    mvs_means = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 0, 0.0005], [3, 0, 0], [4, 0, 0]], float)
    mvs = _set(mvs_means, classes=[1, 1, 5, 1, 7, 1])
    splat_means = np.array([[4.0, 0, 0.0002], [10, 0, 0], [10, 0, 0]], float)  # 1st duplicates MVS #5
    splats = _set(splat_means, degree=2, seed=1)
    res = merge_gaussians(splats, mvs, MergeOptions(non_collaborative_classes=(5, 7), duplicate_tolerance=1e-3))
    s = res.stats
    assert (s.dropped_non_collaborative, s.dropped_mvs_duplicates, s.dropped_cross_duplicates) == (2, 0, 1)
    assert (s.mvs_kept, s.splats_kept, s.total) == (4, 2, 6)
    g = res.gaussians
    np.testing.assert_array_equal(g.means, np.r_[mvs_means[[0, 1, 3, 5]], splat_means[1:]])
    np.testing.assert_array_equal(g.fields["source"], [Source.MVS] * 4 + [Source.SPLAT] * 2)
    np.testing.assert_array_equal(g.fields["classification"], [1, 1, 1, 1, 0, 0])
    assert g.fields["source"].dtype == np.uint8 and g.sh_degree == 2
    np.testing.assert_array_equal(g.sh_rest[:4], 0.0)  # MVS: zero higher-order SH
    np.testing.assert_array_equal(g.sh_rest[4:], splats.sh_rest[1:])
    np.testing.assert_array_equal(g.logit_opacities[:4], mvs.logit_opacities[[0, 1, 3, 5]])


def test_mvs_self_duplicates_and_prefer_splat():
    mvs = _set([[0, 0, 0], [0, 0, 0], [1, 0, 0]], classes=[1, 1, 1])
    splats = _set([[1.0, 0.0, 0.0]], seed=3)
    res = merge_gaussians(splats, mvs, MergeOptions(duplicate_tolerance=0.0, prefer="splat"))
    assert res.stats.dropped_mvs_duplicates == 1 and res.stats.dropped_cross_duplicates == 1
    np.testing.assert_array_equal(res.gaussians.fields["source"], [Source.MVS, Source.SPLAT])
    np.testing.assert_array_equal(res.gaussians.sh_dc[1], splats.sh_dc[0])
    assert res.stats.total == 2


def test_merge_across_origins_keeps_world_positions_in_the_mvs_origin():
    mvs = _set([[0.5, 0.25, 0.0]], origin=(500000.0, 4000000.0, 100.0), classes=[1])
    splats = _set([[0.125, 0.0, 0.0], [0.0, 0.0, 0.0]], origin=(500001.0, 4000000.0, 100.0))
    g = merge_gaussians(splats, mvs).gaussians
    np.testing.assert_array_equal(g.origin, mvs.origin)
    np.testing.assert_array_equal(g.world_means, np.r_[mvs.world_means, splats.world_means])


def test_merge_with_one_side_missing_or_empty():
    mvs = _set([[0, 0, 0], [1, 1, 1]], classes=[3, 4])
    only = merge_gaussians(None, mvs, MergeOptions(non_collaborative_classes=(3,)))
    assert only.stats.total == 1 and only.gaussians.fields["classification"].tolist() == [4]
    splats = _set([[0, 0, 0]])
    only = merge_gaussians(splats, None)
    assert only.stats.splats_kept == 1 and only.gaussians.fields["source"].tolist() == [Source.SPLAT]
    all_dropped = merge_gaussians(None, mvs, MergeOptions(non_collaborative_classes=(3, 4)))
    assert len(all_dropped.gaussians) == 0
    with pytest.raises(DataError):
        merge_gaussians(None, None)
    with pytest.warns(MergeWarning, match="no 'classification'"):
        res = merge_gaussians(None, _set([[0, 0, 0]]), MergeOptions(non_collaborative_classes=(3,)))
    assert res.stats.mvs_kept == 1
    with pytest.raises(ConfigError):
        MergeOptions(duplicate_tolerance=-1.0)
    with pytest.raises(ValueError):
        MergeOptions(prefer="both")
    assert MergeOptions(prefer="splat").prefer is Prefer.SPLAT


def test_merge_hybrid_leaves_needs_splats_points_out_by_default():
    mvs = _set(np.array([[0.0, 0, 0], [0.0, 0, 0.0005], [1.0, 0, 0], [2.0, 0, 0]]))
    needs = np.array([False, False, True, False])
    splats = _set(np.array([[1.0, 0.1, 0], [5.0, 0, 0], [2.0, 0, 0]]))
    res = merge_hybrid(mvs, splats, needs)
    src = res.gaussians.fields["source"]
    # trusted MVS kept as they are (no dedupe of the two MVS points 0.5 mm apart), the needs_splats one left out,
    # the splat exactly on an MVS Gaussian dropped, the others kept
    assert (int((src == Source.MVS).sum()), int((src == Source.SPLAT).sum())) == (3, 2)
    np.testing.assert_array_equal(res.gaussians.means[src == Source.MVS], mvs.means[~needs])
    kept = merge_hybrid(mvs, splats, needs, keep_needs_splats=True)
    assert int((kept.gaussians.fields["source"] == Source.MVS).sum()) == 4
    with pytest.raises(DataError):
        merge_hybrid(mvs, splats, needs[:3])
