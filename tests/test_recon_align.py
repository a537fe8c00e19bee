"""Robust similarity alignment against synthetic exact transforms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.errors import DataError, ReconstructionError
from recon.align import Similarity, ransac_similarity, transform_reconstruction, umeyama


def _random_similarity(seed: int) -> Similarity:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    return Similarity(float(rng.uniform(0.1, 10.0)), R, rng.normal(0, 100.0, 3))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_umeyama_recovers_exact_transform(seed: int):
    T = _random_similarity(seed)
    src = np.random.default_rng(seed + 10).normal(size=(20, 3))
    est = umeyama(src, T.apply(src))
    assert est.scale == pytest.approx(T.scale, rel=1e-10)
    np.testing.assert_allclose(est.rotation, T.rotation, atol=1e-10)
    np.testing.assert_allclose(est.translation, T.translation, atol=1e-8)
    np.testing.assert_allclose(est.inverse().apply(T.apply(src)), src, atol=1e-8)


def test_umeyama_reflection_is_not_returned():
    src = np.random.default_rng(0).normal(size=(10, 3))
    dst = src * np.array([1.0, 1.0, -1.0])  # a mirror image: best proper rotation, det = +1
    est = umeyama(src, dst)
    assert np.linalg.det(est.rotation) == pytest.approx(1.0)


def test_ransac_rejects_outliers_and_reports_residuals():
    rng = np.random.default_rng(3)
    T = _random_similarity(3)
    src = rng.uniform(-50, 50, (40, 3))
    dst = T.apply(src) + rng.normal(0, 0.01, (40, 3))
    bad = np.arange(0, 40, 5)  # 8 gross outliers (20 %)
    dst[bad] += rng.normal(0, 50.0, (len(bad), 3))
    res = ransac_similarity(src, dst, threshold=0.1, seed=0)
    assert set(np.flatnonzero(~res.inliers)) == set(bad)
    assert res.rms_inliers < 0.03  # noise sigma 0.01 per axis -> ~0.017 rms distance
    assert res.transform.scale == pytest.approx(T.scale, rel=1e-3)
    assert np.all(res.residuals[bad] > 0.1)
    # plain least squares on all points is far worse: the robust step matters
    ls = umeyama(src, dst)
    assert (
        np.sqrt(np.mean(np.linalg.norm(ls.apply(src) - dst, axis=1)[~np.isin(np.arange(40), bad)] ** 2))
        > 10 * res.rms_inliers
    )


def test_ransac_bad_input():
    with pytest.raises(DataError):
        ransac_similarity(np.zeros((2, 3)), np.zeros((2, 3)), 1.0)
    with pytest.raises(DataError):
        ransac_similarity(np.full((4, 3), np.nan), np.zeros((4, 3)), 1.0)
    rng = np.random.default_rng(0)
    with pytest.raises(ReconstructionError):  # unrelated point sets: nothing fits within 1 mm
        ransac_similarity(rng.normal(size=(10, 3)), rng.normal(size=(10, 3)) * 100, 1e-3, iterations=200)


def test_transform_reconstruction_moves_camera_centres():
    import pycolmap

    from core.cameras import Camera, Cameras, View
    from recon.model import to_reconstruction

    cams = Cameras({1: Camera.pinhole(100, 100, 50, 40, 100, 80)}, {})
    rng = np.random.default_rng(1)
    for i in range(1, 5):
        R = Rotation.random(random_state=i).as_matrix()
        cams.views[i] = View.from_matrix(i, f"{i}.png", 1, np.concatenate([R, rng.normal(size=(3, 1))], axis=1))
    rec = to_reconstruction(cams)
    T = _random_similarity(7)
    transform_reconstruction(rec, T)
    for v in cams:
        got = np.asarray(rec.image(v.image_id).projection_center())
        np.testing.assert_allclose(got, T.apply(v.center[None])[0], rtol=1e-9, atol=1e-7)
    assert isinstance(rec, pycolmap.Reconstruction)
