"""Per-material scores against brute force (geometry) and hand-computed PSNR (images)."""

from __future__ import annotations

import numpy as np
import pytest

from eval.per_material import as_table, geometry_per_material, psnr_per_material


def _brute_force(compared: np.ndarray, reference: np.ndarray, material: np.ndarray, tau: float) -> dict:
    d = np.linalg.norm(compared[:, None, :] - reference[None, :, :], axis=2)  # (N, M)
    owner = material[d.argmin(axis=1)]
    nearest = d.min(axis=1)
    covered = d.min(axis=0) <= tau
    out = {}
    for m in np.unique(material):
        on = owner == m
        precision = (nearest[on] <= tau).mean() if on.any() else None
        mean = nearest[on].mean() if on.any() else None
        out[int(m)] = (mean, int(on.sum()), covered[material == m].mean(), precision)
    return out


@pytest.mark.parametrize("offset", [0.0, 5.0e6])
def test_geometry_matches_brute_force_at_any_offset(offset: float) -> None:
    rng = np.random.default_rng(3)
    reference = rng.uniform(0, 2, (300, 3)) + offset
    material = rng.integers(0, 4, 300)
    compared = reference[rng.choice(300, 120, replace=False)] + rng.normal(0, 0.05, (120, 3))
    got = geometry_per_material(compared, reference, material, tau=0.08)
    want = _brute_force(compared - offset, reference - offset, material, 0.08)
    assert set(got) == set(want)
    for m, (mean, count, completeness, precision) in want.items():
        assert got[m].accuracy_points == count
        assert got[m].reference_points == int((material == m).sum())
        assert got[m].completeness == pytest.approx(completeness, abs=1e-12)
        if mean is None:
            assert got[m].accuracy_mean is None and got[m].precision is None
            assert got[m].fscore == 0.0
        else:
            assert got[m].accuracy_mean == pytest.approx(mean, rel=1e-6)
            assert got[m].precision == pytest.approx(precision, abs=1e-12)
            f = 2 * precision * completeness / (precision + completeness) if precision + completeness else 0.0
            assert got[m].fscore == pytest.approx(f, abs=1e-12)
    assert any(0 < got[m].precision < 1 for m in got)  # the case exercises both sides of tau


def test_geometry_of_an_empty_product_is_zero_complete() -> None:
    reference = np.array([[0.0, 0, 0], [1, 0, 0]])
    got = geometry_per_material(np.zeros((0, 3)), reference, np.array([2, 5]), tau=0.1)
    assert got[2].completeness == 0.0 and got[5].completeness == 0.0
    assert got[2].accuracy_mean is None and got[2].accuracy_points == 0


def test_psnr_per_material_pools_pixels_over_views() -> None:
    photo = np.zeros((4, 4, 3))
    labels = np.array([[1, 1, 2, 2]] * 4)
    first = photo.copy()
    first[:, :2] = 0.1  # material 1: squared error 0.01 on 8 pixels
    second = photo.copy()
    second[:, 2:] = 0.5  # material 2: squared error 0.25 on 8 pixels; material 1 exact on 8 more
    got = psnr_per_material([(first, photo, labels), (second, photo, labels)])
    assert got[1].pixels == 16 and got[2].pixels == 16
    assert got[1].psnr == pytest.approx(10 * np.log10(1 / (8 * 0.01 / 16)))
    assert got[2].psnr == pytest.approx(10 * np.log10(1 / (8 * 0.25 / 16)))
    table = as_table({}, got, {1: "wood", 2: "mirror", 7: "glass"})
    assert table["mirror"]["psnr"] == pytest.approx(got[2].psnr) and table["wood"]["accuracy_mean_m"] is None
    assert set(table) == {"wood", "mirror"}  # only measured materials, and only named ones
    assert set(as_table({}, got, {2: "mirror"})) == {"mirror"}
