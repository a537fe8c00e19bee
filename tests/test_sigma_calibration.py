"""eval.sigma_calibration: distances to a reference surface and the share of points their σ holds, per material."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.pointcloud import PointCloud
from eval.sigma_calibration import Z95, calibration_per_material, calibration_row, local_plane_distances


def _tilted_plane(spacing: float = 0.01, half: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(reference points, unit normal, in-plane axes (2, 3)) of a grid on a plane tilted 30° about x."""
    t = np.radians(30.0)
    u, v = np.array([1.0, 0.0, 0.0]), np.array([0.0, np.cos(t), np.sin(t)])
    g = np.arange(-half, half + 1e-12, spacing)
    a, b = np.meshgrid(g, g)
    pts = a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    return pts, np.cross(u, v), np.stack([u, v])


def test_a_point_off_a_sampled_plane_is_at_its_offset_not_at_its_nearest_sample() -> None:
    ref, normal, axes = _tilted_plane()
    rng = np.random.default_rng(0)
    lateral = rng.uniform(-0.3, 0.3, (500, 2)) @ axes  # anywhere between the samples
    offset = rng.uniform(-4e-3, 4e-3, 500)
    pts = lateral + offset[:, None] * normal
    d, nearest = local_plane_distances(pts, ref)
    np.testing.assert_allclose(d, np.abs(offset), atol=1e-12)
    brute_nearest = np.argmin(((pts[:, None] - ref[None]) ** 2).sum(-1), axis=1)
    np.testing.assert_array_equal(nearest, brute_nearest)
    # the nearest-sample distance would add up to half the grid's diagonal
    d_nearest = np.linalg.norm(pts - ref[nearest], axis=1)
    assert (d_nearest - np.abs(offset)).max() > 2e-3


def test_georeferenced_coordinates_keep_micrometres() -> None:
    ref, normal, axes = _tilted_plane()
    utm = np.array([512_345.678, 5_412_345.678, 312.5])
    pts = np.array([[0.1, 0.05], [-0.2, 0.3]]) @ axes + np.array([[1e-3], [-2.5e-3]]) * normal
    sigma = np.array([1.2e-3, 1.2e-3])
    table = calibration_per_material(pts + utm, sigma, ref + utm, np.zeros(len(ref), int), {0: "a"})
    # σ = 1.2 mm: the 1 mm offset is within 1σ, the 2.5 mm one beyond 1.96σ (2.35 mm)
    assert table["a"]["within_1sigma"] == 0.5 and table["a"]["within_95"] == 0.5
    assert table["a"]["median_distance_m"] == pytest.approx(1.75e-3, abs=1e-9)


def test_distances_match_a_brute_force_local_plane_on_a_random_cloud() -> None:
    rng = np.random.default_rng(3)
    ref = rng.normal(size=(60, 3)) * [1.0, 1.0, 0.1]
    pts = rng.normal(size=(40, 3))
    k = 8
    d, _ = local_plane_distances(pts, ref, k=k)
    for p, got in zip(pts, d, strict=True):
        order = np.argsort(np.linalg.norm(ref - p, axis=1))
        patch = ref[order[:k]]
        centred = patch - patch.mean(axis=0)
        normal = np.linalg.svd(centred)[2][-1]  # the direction of least spread
        expected = min(abs(normal @ (p - patch.mean(axis=0))), np.linalg.norm(ref[order[0]] - p))
        assert got == pytest.approx(expected, abs=1e-12)


def test_a_calibrated_normal_error_holds_68_and_95_percent() -> None:
    rng = np.random.default_rng(1)
    sigma = rng.uniform(1e-3, 5e-3, 200_000)
    distances = np.abs(rng.normal(size=sigma.size) * sigma)
    row = calibration_row(distances, sigma)
    assert row["within_1sigma"] == pytest.approx(0.6827, abs=0.005)
    assert row["within_95"] == pytest.approx(0.95, abs=0.003)
    too_small = calibration_row(distances, sigma / 3)  # an overconfident σ
    assert too_small["within_95"] < 0.55


def test_rows_count_exactly_and_an_invalid_sigma_is_a_miss() -> None:
    row = calibration_row(np.array([0.5, 1.5, 2.5, 0.1]), np.array([1.0, 1.0, 1.0, np.nan]))
    assert row["points"] == 4 and row["within_1sigma"] == 0.25 and row["within_95"] == 0.5
    assert row["median_distance_m"] == 1.0
    empty = calibration_row(np.zeros(0), np.zeros(0))
    assert empty["points"] == 0 and empty["within_95"] is None
    with pytest.raises(ValueError, match="2 distances but 1 sigmas"):
        calibration_row(np.zeros(2), np.zeros(1))
    assert Z95 == pytest.approx(1.96, abs=1e-3)


def test_per_material_rows_follow_the_nearest_reference_point() -> None:
    g = np.arange(-0.5, 0.5, 0.01) + 0.005
    x, y = np.meshgrid(g, g)
    ref = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    material = (ref[:, 0] > 0) + 1
    # above material 1: 2 mm off with σ 2 mm (inside 1σ); above material 2: 5 mm off with σ 2 mm (outside 1.96σ)
    left = np.c_[np.full(10, -0.2), np.linspace(-0.3, 0.3, 10), np.full(10, 2e-3)]
    right = np.c_[np.full(30, 0.2), np.linspace(-0.3, 0.3, 30), np.full(30, 5e-3)]
    table = calibration_per_material(np.r_[left, right], np.full(40, 2e-3), ref, material, {1: "wood", 2: "mirror"})
    assert table["wood"]["points"] == 10 and table["wood"]["within_1sigma"] == 1.0
    assert table["mirror"]["points"] == 30 and table["mirror"]["within_95"] == 0.0
    assert table["all"]["points"] == 40 and table["all"]["within_95"] == 0.25


def test_the_eval_stage_and_the_report_carry_the_calibration_of_the_points_that_carry_a_sigma() -> None:
    """Any product whose points carry a ``sigma`` field (0: no estimate, left out) gets Table 6; one without a σ
    field, or with none positive, gets none and its tables are as before."""
    from core.units import Units
    from eval.report import _per_material_tables
    from hybridsplat.stages.evaluate import _MaterialReference, _sigma_calibration

    g = np.arange(-0.5, 0.5, 0.01) + 0.005
    x, y = np.meshgrid(g, g)
    ref = PointCloud(np.c_[x.ravel(), y.ravel(), np.zeros(x.size)], fields={"material": (x.ravel() > 0) + 1})
    names = {1: "wood", 2: "mirror"}
    plain = ref.positions[ref.positions[:, 0] < 0]
    with_sigma = ref.positions[ref.positions[:, 0] > 0][::7] + [0.003, 0.002, 3e-3]  # 3 mm above the mirror
    n_plain, n_sigma = len(plain), len(with_sigma)
    sigma = np.r_[np.zeros(n_plain), np.full(n_sigma, 2e-3)].astype(np.float32)  # 1.5σ: in 95 %, not in 1σ
    reference = _MaterialReference(ref, None, Path("."))
    table = _sigma_calibration(PointCloud(np.r_[plain, with_sigma], fields={"sigma": sigma}), reference, names)
    assert table is not None and set(table) == {"all", "mirror"}
    assert table["mirror"]["points"] == n_sigma
    assert table["mirror"]["within_1sigma"] == 0.0 and table["mirror"]["within_95"] == 1.0
    assert table["mirror"]["median_distance_m"] == pytest.approx(3e-3, abs=1e-9)
    assert _sigma_calibration(PointCloud(np.r_[plain, with_sigma]), reference, names) is None
    zeros = PointCloud(np.r_[plain, with_sigma], fields={"sigma": np.zeros(n_plain + n_sigma, np.float32)})
    assert _sigma_calibration(zeros, reference, names) is None
    rows: dict = {"wood": {}, "mirror": {}}
    per_material = {"tau_m": 6e-3, "materials": {}, "products": {"merged": rows},
                    "sigma_calibration": {"merged": table}}  # fmt: skip
    tables = _per_material_tables(per_material, Units.MM)
    title, header, body = tables[-1]
    assert title.startswith("Table 6") and "`merged`" in title
    assert body[-1] == ["mirror", str(n_sigma), "0.000", "1.000", "2.0", "3.0"]
    without = _per_material_tables({k: v for k, v in per_material.items() if k != "sigma_calibration"}, Units.MM)
    assert not any(t[0].startswith("Table 6") for t in without) and len(without) == len(tables) - 1


def test_a_calibration_restored_from_the_evaluation_cache_comes_back_with_its_rows(tmp_path) -> None:
    from types import SimpleNamespace

    from hybridsplat.layout import ProjectLayout
    from hybridsplat.stages.evaluate import EvalStage, EvalStageOptions

    ref = PointCloud(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), fields={"material": np.array([1, 2])})
    materials = [SimpleNamespace(id=1, name="wood", kind="textured", collaborative=True),
                 SimpleNamespace(id=2, name="mirror", kind="mirror", collaborative=False)]  # fmt: skip
    spec = SimpleNamespace(description=SimpleNamespace(materials=materials), test_labels=None)
    ctx = SimpleNamespace(
        source=SimpleNamespace(spec=spec),
        options=lambda stage: EvalStageOptions(),
        layout=ProjectLayout(tmp_path),
    )
    rows = {"mirror": {"material_id": 2, "accuracy_mean_m": 0.003}}
    calibration = {"all": {"points": 3, "within_95": 1.0}}
    stored = {"merged": {"rows": rows, "sigma_calibration": calibration},
              "mvs": {"rows": rows, "sigma_calibration": None}}  # fmt: skip
    result = EvalStage()._per_material(ctx, {}, stored, ref, 6e-3, None)
    assert result["products"] == {"merged": rows, "mvs": rows}
    assert result["sigma_calibration"] == {"merged": calibration}
