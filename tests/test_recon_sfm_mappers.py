"""recon.sfm mappers (issue 34): incremental, global (GLOMAP) and hierarchical mapping of the same matches, and auto.

The scene is data_synth's ``tiny`` preset (10 training views of 160×120, true cameras known): each mapper must
register every view and, after a similarity alignment, put the camera centres where the true ones are.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from core.errors import ConfigError
from recon.align import align_reconstruction_to_centers
from recon.model import from_reconstruction, read_reconstruction
from recon.sfm import (
    EXHAUSTIVE_MAX_PHOTOS,
    GLOBAL_MAPPER_MIN_PHOTOS,
    Mapper,
    Matcher,
    SfmOptions,
    resolve_mapper,
    resolve_matcher,
    run_sfm,
)


@pytest.fixture(scope="module")
def scene_root(tmp_path_factory) -> Path:
    from data_synth import generate_scene

    return generate_scene("tiny", tmp_path_factory.mktemp("synth") / "tiny", seed=0)


def _true_centres(scene_root: Path) -> dict[str, np.ndarray]:
    cameras = from_reconstruction(read_reconstruction(scene_root / "sparse" / "0"))
    return {v.name: v.center for v in cameras}


def test_auto_is_incremental_below_the_threshold_and_global_from_it():
    assert resolve_mapper("auto", GLOBAL_MAPPER_MIN_PHOTOS - 1) is Mapper.INCREMENTAL
    assert resolve_mapper(Mapper.AUTO, GLOBAL_MAPPER_MIN_PHOTOS) is Mapper.GLOBAL
    assert resolve_mapper("hierarchical", 3) is Mapper.HIERARCHICAL
    with pytest.raises(ConfigError, match="mapper"):
        SfmOptions(mapper="glomap2")


@pytest.mark.parametrize("mapper", ["incremental", "global", "hierarchical"])
def test_every_mapper_registers_all_views_where_the_true_cameras_are(scene_root: Path, tmp_path: Path, mapper: str):
    options = SfmOptions(mapper=mapper)
    rec, report = run_sfm(scene_root / "images", tmp_path / "sparse", options, log_path=tmp_path / "log")
    assert report.mapper == mapper
    assert len(report.registered) == 10 and report.num_points > 50
    assert report.mean_reprojection_error < 1.0
    truth = _true_centres(scene_root)
    extent = np.ptp(np.stack(list(truth.values())), axis=0).max()
    result = align_reconstruction_to_centers(rec, truth, threshold=0.05 * extent)
    assert result.num_inliers == 10
    assert result.rms_inliers < 0.01 * extent, f"{mapper}: centre rms {result.rms_inliers:.4g} (extent {extent:.3g})"


def test_global_mapping_is_deterministic(scene_root: Path, tmp_path: Path):
    options = SfmOptions(mapper="global", seed=5)
    digests = []
    for run in ("a", "b"):
        run_sfm(scene_root / "images", tmp_path / run, options, log_path=tmp_path / "log")
        digests.append({p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in (tmp_path / run).glob("*.bin")})
    assert digests[0] == digests[1] and "points3D.bin" in digests[0]


# -- matchers: auto and spatial matching on position priors ---------------------------------------------------------
def test_auto_matcher_by_photo_count_priors_and_vocabulary_tree():
    assert resolve_matcher("auto", EXHAUSTIVE_MAX_PHOTOS, 0, False)[0] is Matcher.EXHAUSTIVE
    n = EXHAUSTIVE_MAX_PHOTOS + 1
    assert resolve_matcher("auto", n, n, False)[0] is Matcher.SPATIAL
    assert resolve_matcher("auto", n, int(0.9 * n) - 1, True)[0] is Matcher.VOCABTREE
    matcher, why = resolve_matcher("auto", n, 0, False)
    assert matcher is Matcher.SEQUENTIAL and "name order" in why
    assert resolve_matcher("exhaustive", 10_000, 0, False) == (Matcher.EXHAUSTIVE, "chosen")
    with pytest.raises(ConfigError, match="spatial_neighbours"):
        SfmOptions(spatial_neighbours=0)


def _matched_pairs(db: Path) -> set[frozenset[str]]:
    """The photo pairs the matcher tried (every pair with a matches row, verified or not)."""
    import pycolmap

    with pycolmap.Database.open(str(db)) as database:
        names = {im.image_id: im.name for im in database.read_all_images()}
        pair_ids, _ = database.read_num_matches()
    return {frozenset(names[int(i)] for i in pycolmap.pair_id_to_image_pair(int(p))) for p in pair_ids}


def _nearest_pairs(centres: dict[str, np.ndarray], k: int) -> set[frozenset[str]]:
    """Brute force: each photo with its k nearest others (3D distance between centres); no tie at the k-th."""
    names = sorted(centres)
    pos = np.stack([centres[n] for n in names])
    pairs = set()
    for i, name in enumerate(names):
        d = np.linalg.norm(pos - pos[i], axis=1)
        d[i] = np.inf
        order = np.argsort(d)
        assert d[order[k]] - d[order[k - 1]] > 1e-3, "a tie at the k-th neighbour: the expected pairs are ambiguous"
        pairs |= {frozenset((name, names[j])) for j in order[:k]}
    return pairs


def _priors(scene_root: Path) -> dict[str, np.ndarray]:
    """Position priors: the true centres moved by up to 3 cm (the orbit's equal spacing gives equal distances)."""
    rng = np.random.default_rng(0)
    return {n: c + rng.uniform(-0.03, 0.03, 3) for n, c in sorted(_true_centres(scene_root).items())}


def test_spatial_matching_on_reference_priors_matches_the_nearest_photos(scene_root: Path, tmp_path: Path):
    priors = _priors(scene_root)
    db = tmp_path / "db" / "database.db"
    options = SfmOptions(matcher="spatial", spatial_neighbours=3, database_path=str(db))
    big = {n: c + np.array([2.6e6, 1.2e6, 400.0]) for n, c in priors.items()}  # UTM-sized: distances unchanged
    _, report = run_sfm(
        scene_root / "images", tmp_path / "sparse", options, log_path=tmp_path / "log", position_priors=big
    )
    assert report.position_priors == "reference" and report.matcher.startswith("spatial")
    assert _matched_pairs(db) == _nearest_pairs(priors, 3)
    assert len(report.registered) == 10


def test_spatial_matching_without_priors_is_refused(scene_root: Path, tmp_path: Path):
    with pytest.raises(ConfigError, match="spatial matching needs position priors"):
        run_sfm(scene_root / "images", tmp_path / "sparse", SfmOptions(matcher="spatial"), log_path=tmp_path / "log")


def test_spatial_matching_on_exif_gps(scene_root: Path, tmp_path: Path):
    """Photos with EXIF GPS (the priors as latitude/longitude offsets): COLMAP reads them as priors."""
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational

    truth = _priors(scene_root)
    photos = tmp_path / "photos"
    photos.mkdir()
    metres_per_degree = 111_320.0  # near the equator: latitude and longitude alike
    for name, centre in truth.items():
        exif = Image.Exif()
        lat, lon = centre[1] / metres_per_degree, centre[0] / metres_per_degree

        def dms(value: float) -> tuple[IFDRational, ...]:
            seconds = round(abs(value) * 3600 * 1e6)
            return (
                IFDRational(seconds // 3_600_000_000),
                IFDRational((seconds // 60_000_000) % 60),
                IFDRational(seconds % 60_000_000, 1_000_000),
            )

        exif[0x8825] = {1: "N" if lat >= 0 else "S", 2: dms(lat), 3: "E" if lon >= 0 else "W", 4: dms(lon), 5: 0,
                        6: IFDRational(round(100 + centre[2] * 1000), 1000)}  # fmt: skip
        Image.open(scene_root / "images" / name).convert("RGB").save(photos / f"{Path(name).stem}.jpg", exif=exif)
    db = tmp_path / "db" / "database.db"
    options = SfmOptions(matcher="spatial", spatial_neighbours=3, database_path=str(db))
    _, report = run_sfm(photos, tmp_path / "sparse", options, log_path=tmp_path / "log")
    assert report.position_priors == "exif"
    stem = {f"{Path(n).stem}.jpg": c for n, c in truth.items()}
    flat = {n: c * np.array([1.0, 1.0, 0.0]) for n, c in stem.items()}  # GPS priors: heights ignored
    assert _matched_pairs(db) == _nearest_pairs(flat, 3)
    assert len(report.registered) == 10


def test_cli_sfm_spatial_on_the_reference_then_global_mapping(scene_root: Path, tmp_path: Path, capsys):
    """``hybridsplat sfm`` on the scene's photos without its cameras (``--full-sfm``): ``--reference`` centres are
    the spatial matcher's priors and the alignment's target; the record says which matcher and mapper ran."""
    import json

    from hybridsplat.cli import main
    from hybridsplat.layout import ProjectLayout

    reference = tmp_path / "centres.txt"
    reference.write_text("".join(f"{n} {c[0]:.6f} {c[1]:.6f} {c[2]:.6f}\n" for n, c in _priors(scene_root).items()))
    project = tmp_path / "project"
    args = ["sfm", str(scene_root), "--out", str(project), "--full-sfm", "--reference", str(reference)]
    main([*args, "--matcher", "spatial", "--mapper", "global"])
    report = json.loads(ProjectLayout(project).record("sfm").read_text())["report"]
    assert report["matcher"].startswith("spatial") and report["position_priors"] == "reference"
    assert report["mapper"] == "global" and len(report["registered"]) == 10
    assert "10/10 photos registered" in capsys.readouterr().err
