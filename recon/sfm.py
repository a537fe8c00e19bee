"""Structure from motion with pycolmap: SIFT features, matching, mapping (incremental, global or hierarchical) or
known-pose triangulation.

``run_sfm(image_dir, out_dir, options)`` → the largest COLMAP model written to ``out_dir`` plus an
:class:`SfmReport`. ``triangulate_known_poses(cameras, image_dir, out_dir, options)`` keeps the given cameras
fixed and only matches and triangulates, so dense fusion gets sparse points with tracks.

Bad input: unreadable/corrupt images are listed and skipped (warning), fewer than two usable images or
images that do not overlap raise :class:`core.errors` errors; images of different sizes get one camera each.

Determinism (``SfmOptions.deterministic``, on by default): two runs with the same images, options and seed write
byte-identical models. What varied before, measured on the ``tiny`` preset (bench/bench_sfm_determinism.py):

- multi-threaded feature extraction gives image (and per-image camera) ids in completion order, not name order;
  every later step depends on ids (known-pose runs too: their frames/images/points files differed) → extraction
  runs on one thread;
- two-view geometry RANSAC draws from thread-local generators when unseeded → its seed is set, and matching runs
  on one thread too: with two matching threads, one CI run (of many that passed) gave 167 points against 168 in
  the second of two identical runs in one process (not reproduced in 40 runs here, whole or stage by stage, so
  the cause is not pinned down; one thread removes the last multi-threaded COLMAP step, at some cost in time:
  docs/experiments/2026-11-27-pipeline-defaults.md, "SfM stage: determinism and the robust refinement");
- the mapper's, the triangulator's and the global generator's seeds are set; the mapper and the bundle
  adjustments run on one thread. This last part is a precaution, not a measurement: Ceres multi-threads only
  problems above 50 000 residuals (``min_num_residuals_for_cpu_multi_threading``), which ``tiny`` never reaches,
  and its Schur-complement updates from several threads may sum in a different order run to run.

``bench/bench_sfm_determinism.py`` checks it (repeated full and known-pose runs on ``tiny`` and fountain-P11; what it
found: docs/experiments/2026-11-27-pipeline-defaults.md, "SfM stage: determinism and the robust refinement").

COLMAP's output goes to ``log_path`` (see :mod:`recon.colmap_log`) when given; its warnings land in
``SfmReport.warnings`` as one line each.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import ClassVar

import numpy as np

from core.cameras import Cameras
from core.constraints import Choice, Constrained, Constraints, Interval, NoneOr
from core.errors import ConfigError, InputFileError, ReconstructionError
from core.options import enum_choice, runtime_field
from recon.colmap_log import native_output_to
from recon.inputs import IMAGE_SUFFIXES

Progress = Callable[[str, int, int], None]


class Matcher(str, Enum):
    """Which photo pairs are matched. exhaustive: every pair; sequential: neighbours in name order (capture order);
    spatial: the nearest photos by position prior (EXIF GPS, or ``--reference`` centres when given); vocabtree:
    retrieval with a COLMAP vocabulary tree file; auto: :func:`resolve_matcher`."""

    AUTO = "auto"
    EXHAUSTIVE = "exhaustive"
    SEQUENTIAL = "sequential"
    SPATIAL = "spatial"
    VOCABTREE = "vocabtree"


# auto matches every pair up to this many photos (11 175 pairs; COLMAP's documentation advises exhaustive matching
# up to a few hundred photos); beyond it, spatial where priors cover PRIOR_COVERAGE of the photos.
EXHAUSTIVE_MAX_PHOTOS = 150
PRIOR_COVERAGE = 0.9


def resolve_matcher(
    matcher: Matcher | str, num_photos: int, num_with_priors: int, has_vocab_tree: bool
) -> tuple[Matcher, str]:
    """The concrete matcher and why. ``auto``: exhaustive up to :data:`EXHAUSTIVE_MAX_PHOTOS` photos; above, spatial
    when position priors cover :data:`PRIOR_COVERAGE` of them, else vocabtree when a tree file is given, else
    sequential (the photos' name order taken as capture order, which the reason says)."""
    chosen = enum_choice(Matcher, matcher, "matcher")
    if chosen is not Matcher.AUTO:
        return chosen, "chosen"
    if num_photos <= EXHAUSTIVE_MAX_PHOTOS:
        return Matcher.EXHAUSTIVE, f"{num_photos} photos <= {EXHAUSTIVE_MAX_PHOTOS}"
    if num_with_priors >= PRIOR_COVERAGE * num_photos:
        return Matcher.SPATIAL, f"{num_with_priors}/{num_photos} photos with position priors"
    if has_vocab_tree:
        return Matcher.VOCABTREE, f"{num_photos} photos, few position priors, a vocabulary tree given"
    return Matcher.SEQUENTIAL, (
        f"{num_photos} photos, position priors for {num_with_priors} and no vocabulary tree: matched in name order "
        "(give --reference or photos with GPS for spatial matching)"
    )


class Mapper(str, Enum):
    """How poses and points are recovered from the matches (COLMAP 4.2 through pycolmap).

    incremental: COLMAP's incremental mapper (``incremental_mapping``): registers one photo at a time, with bundle
    adjustments in between; robust, and its cost grows faster than linearly with the photos. global: GLOMAP
    (``global_mapping``): rotation averaging and global positioning of every photo at once, then one bundle
    adjustment; one to two orders of magnitude faster on large sets (Pan et al., ECCV 2024). hierarchical:
    ``hierarchical_mapping``: the scene partitioned into overlapping clusters, each mapped incrementally, merged.
    auto: :func:`resolve_mapper`.
    """

    AUTO = "auto"
    INCREMENTAL = "incremental"
    GLOBAL = "global"
    HIERARCHICAL = "hierarchical"


# auto picks the global mapper from this many photos: below it incremental mapping takes seconds to a few minutes
# (fountain-P11's 11 photos: see docs/experiments/2026-11-27-sfm-mappers.md) and registers photos one by one with
# checks a global solve does not make; above it its cost dominates SfM.
GLOBAL_MAPPER_MIN_PHOTOS = 200


def resolve_mapper(mapper: Mapper | str, num_photos: int) -> Mapper:
    """The concrete mapper: ``auto`` is incremental below :data:`GLOBAL_MAPPER_MIN_PHOTOS` photos, global from there."""
    chosen = enum_choice(Mapper, mapper, "mapper")
    if chosen is Mapper.AUTO:
        return Mapper.GLOBAL if num_photos >= GLOBAL_MAPPER_MIN_PHOTOS else Mapper.INCREMENTAL
    return chosen


@dataclass(frozen=True)
class SfmOptions(Constrained):
    """Options of :func:`run_sfm` and :func:`triangulate_known_poses`, and of the pipeline's ``sfm`` stage (defaults
    suit a set of photos from one camera: one shared SIMPLE_RADIAL camera, exhaustive matching, features at 1600 px,
    deterministic). ``seed`` and ``mask_dir`` are set by the pipeline (its seed, ``--feature-masks``).

    deterministic: byte-identical models run to run (COLMAP on one thread, see the module docstring); False uses
    ``num_threads`` for feature extraction and matching (faster). align_threshold_m: RANSAC inlier threshold of the
    alignment to reference camera centres (metres); None = 2 % of their extent (:func:`recon.align.align_to_reference`).
    """

    matcher: Matcher = Matcher.AUTO  # see Matcher and resolve_matcher
    mapper: Mapper = Mapper.AUTO  # see Mapper and resolve_mapper
    spatial_neighbours: int = 50  # spatial matcher: nearest photos by prior matched with each (COLMAP's default)
    max_image_size: int = 1600  # feature extraction works on images downscaled to this longer side (px)
    max_num_features: int = 8192
    camera_model: str = "SIMPLE_RADIAL"  # COLMAP model for unknown cameras (e.g. OPENCV for strong distortion)
    single_camera: bool = True  # one camera shared by all photos (when they all have the same size)
    num_threads: int = -1  # COLMAP threads (-1 = all cores) when deterministic=False; one thread otherwise
    seed: int = runtime_field(0)  # RANSAC / mapper initialisation / triangulation seed
    deterministic: bool = True  # byte-identical models run to run (see the module docstring); False = faster
    vocab_tree_path: str | None = None  # needed by the vocabtree matcher
    mask_dir: str | None = runtime_field(None)  # PNG masks NAME.png (0 = ignore features there), as COLMAP expects
    database_path: str | None = None  # keep the feature database here (default: a temporary folder)
    # Final robust refinement of the full SfM model (see _refine_model): Cauchy loss scale in px (0 = off) and the
    # reprojection error above which observations are dropped between the two robust bundle adjustments.
    refine_loss_px: float = 1.0
    refine_filter_px: float = 2.0
    align_threshold_m: float | None = None

    constraints: ClassVar[Constraints] = {
        "matcher": Choice(Matcher),
        "mapper": Choice(Mapper),
        "spatial_neighbours": Interval(int, 1, None),
        "align_threshold_m": NoneOr(Interval(float, 0, math.inf, closed="right")),  # none: 2 % of the extent
    }


@dataclass
class ImageCheck:
    """Images found in a folder: usable names, skipped names with the reason, and sizes (W, H)."""

    valid: list[str]
    skipped: dict[str, str]
    sizes: dict[str, tuple[int, int]]

    @property
    def mixed_sizes(self) -> bool:
        return len(set(self.sizes.values())) > 1


@dataclass
class SfmReport:
    """What SfM did. Times in seconds, reprojection error in pixels."""

    num_images: int
    registered: list[str]
    unregistered: dict[str, str]  # name -> reason
    skipped: dict[str, str]  # unreadable images -> reason
    num_points: int = 0
    mean_reprojection_error: float = 0.0
    mean_track_length: float = 0.0
    num_models: int = 1
    mapper: str = ""  # the mapper that ran (auto resolved); empty for known-pose triangulation
    matcher: str = ""  # the matcher that ran (auto resolved) and why
    position_priors: str = ""  # where the spatial matcher's priors came from: "", "exif" or "reference"
    seconds_features: float = 0.0
    seconds_matching: float = 0.0
    seconds_mapping: float = 0.0
    seconds_refinement: float = 0.0
    alignment: object | None = None  # recon.align.AlignmentResult when aligned
    warnings: list[str] = field(default_factory=list)


def check_images(image_dir: str | Path, names: list[str] | None = None) -> ImageCheck:
    """Open every image fully; corrupt/unreadable ones are skipped with a reason (and a warning).

    Raises :class:`InputFileError` when the folder is missing or fewer than two images are usable.
    """
    from PIL import Image, UnidentifiedImageError

    image_dir = Path(image_dir)
    if not image_dir.is_dir():
        raise InputFileError("image folder does not exist", image_dir)
    if names is None:
        # top level only: a masks/ or test/ subfolder must not be taken for photos
        names = sorted(p.name for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    valid, skipped, sizes = [], {}, {}
    for name in names:
        try:
            with Image.open(image_dir / name) as im:
                im.load()
                sizes[name] = (int(im.width), int(im.height))
            valid.append(name)
        except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as err:
            skipped[name] = f"unreadable image ({type(err).__name__}: {err})"
    for name, why in skipped.items():
        warnings.warn(f"{image_dir / name}: skipped, {why}", stacklevel=2)
    if len(valid) < 2:
        raise InputFileError(
            f"SfM needs at least 2 readable images, found {len(valid)}"
            + (f" ({len(skipped)} unreadable: {', '.join(sorted(skipped))})" if skipped else ""),
            image_dir,
        )
    if len(set(sizes.values())) > 1:
        warnings.warn(
            f"{image_dir}: images have {len(set(sizes.values()))} different sizes; using one camera per image",
            stacklevel=2,
        )
    return ImageCheck(valid, skipped, sizes)


def _extract_and_match(
    db: Path,
    image_dir: Path,
    check: ImageCheck,
    options: SfmOptions,
    per_image: bool,
    report: SfmReport,
    priors: Mapping[str, np.ndarray] | None = None,
):
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = _camera_model(options.camera_model)
    if options.mask_dir:
        mask_dir = Path(options.mask_dir)
        if not mask_dir.is_dir():
            raise InputFileError("mask folder does not exist", mask_dir)
        reader.mask_path = str(mask_dir)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = int(options.max_image_size)
    extraction.num_threads = _colmap_threads(options)
    extraction.sift.max_num_features = int(options.max_num_features)
    mode = pycolmap.CameraMode.PER_IMAGE if per_image else pycolmap.CameraMode.SINGLE
    t0 = time.perf_counter()
    pycolmap.extract_features(
        db, image_dir, image_names=check.valid, camera_mode=mode, reader_options=reader, extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )  # fmt: skip
    report.seconds_features = time.perf_counter() - t0
    t1 = time.perf_counter()
    m, why = _choose_matcher(db, check, options, priors, report)
    report.matcher = f"{m.value} ({why})"
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = _colmap_threads(options)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(options.seed)  # unseeded: thread-local generators, order-dependent
    kw = {"matching_options": matching, "verification_options": verification, "device": pycolmap.Device.cpu}
    if m is Matcher.EXHAUSTIVE:
        pycolmap.match_exhaustive(db, **kw)
    elif m is Matcher.SEQUENTIAL:
        pycolmap.match_sequential(db, **kw)
    elif m is Matcher.SPATIAL:
        pairing = pycolmap.SpatialPairingOptions()
        pairing.max_num_neighbors = int(options.spatial_neighbours)
        pairing.ignore_z = report.position_priors == "exif"  # GPS heights are poor; a reference's are not
        pycolmap.match_spatial(db, pairing_options=pairing, **kw)
    else:
        if not options.vocab_tree_path:
            raise ConfigError("the vocabtree matcher needs vocab_tree_path (a COLMAP vocabulary tree file)")
        pairing = pycolmap.VocabTreePairingOptions()
        pairing.vocab_tree_path = str(options.vocab_tree_path)
        pycolmap.match_vocabtree(db, pairing_options=pairing, **kw)
    report.seconds_matching = time.perf_counter() - t1


def _choose_matcher(
    db: Path, check: ImageCheck, options: SfmOptions, priors: Mapping[str, np.ndarray] | None, report: SfmReport
) -> tuple[Matcher, str]:
    """Resolve the matcher from the photos and their priors; for spatial matching, make the priors consistent.

    COLMAP reads EXIF GPS into the database as WGS84 priors at extraction. Given ``priors`` (``--reference``
    centres, metres) replace them when they cover :data:`PRIOR_COVERAGE` of the photos: one coordinate system for
    every photo, and a surveyed reference is the better prior. Raises :class:`ConfigError` for spatial matching
    without priors.
    """
    import pycolmap

    names = set(check.valid)
    given = {n: np.asarray(c, np.float64) for n, c in (priors or {}).items() if n in names}
    use_given = len(given) >= PRIOR_COVERAGE * len(names)
    with pycolmap.Database.open(str(db)) as database:
        exif = database.num_pose_priors()
        m, why = resolve_matcher(
            options.matcher, len(names), len(given) if use_given else exif, bool(options.vocab_tree_path)
        )
        if m is not Matcher.SPATIAL:
            return m, why
        if use_given:
            database.clear_pose_priors()
            local = np.mean(np.stack(list(given.values())), axis=0)  # priors near 0: UTM-sized values lose nothing
            for im in database.read_all_images():
                if im.name in given:
                    prior = pycolmap.PosePrior(
                        position=given[im.name] - local,
                        coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
                        corr_data_id=im.data_id,
                    )
                    database.write_pose_prior(prior)
            report.position_priors = "reference"
        elif exif:
            report.position_priors = "exif"
        else:
            raise ConfigError(
                "spatial matching needs position priors: photos with EXIF GPS, or camera centres (--reference)"
            )
    return m, why


def _unregistered_reasons(
    db: Path, names: list[str], registered: set[str], other_models: dict[str, int]
) -> dict[str, str]:
    """Why images did not register, from the database (features, verified matches) and the other models."""
    import pycolmap

    reasons: dict[str, str] = {}
    with pycolmap.Database.open(str(db)) as database:
        images = {im.name: im for im in database.read_all_images()}
        pair_ids, counts = database.read_two_view_geometry_num_inliers()
        inliers: dict[int, int] = {}
        for pair_id, n in zip(pair_ids, counts, strict=True):
            for i in pycolmap.pair_id_to_image_pair(int(pair_id)):
                inliers[int(i)] = max(inliers.get(int(i), 0), int(n))
        for name in names:
            if name in registered:
                continue
            im = images.get(name)
            if im is None:
                reasons[name] = "not imported into the feature database"
                continue
            nk = database.num_keypoints_for_image(im.image_id)
            best = inliers.get(int(im.image_id), 0)
            if nk == 0:
                reasons[name] = "no features detected (textureless or blank image)"
            elif best == 0:
                reasons[name] = f"{nk} features but no geometrically verified matches with any other image (no overlap)"
            elif name in other_models:
                reasons[name] = (
                    f"registered in a separate model of {other_models[name]} images "
                    "that does not connect to the largest"
                )
            else:
                reasons[name] = f"at most {best} verified matches with another image; pose estimation failed"
    return reasons


def _fill_report(rec, report: SfmReport) -> None:
    report.num_points = int(rec.num_points3D())
    report.mean_reprojection_error = float(rec.compute_mean_reprojection_error()) if report.num_points else 0.0
    report.mean_track_length = float(rec.compute_mean_track_length()) if report.num_points else 0.0


def _camera_model(name: str) -> str:
    """A COLMAP camera model name, checked (ConfigError listing the valid ones otherwise)."""
    import pycolmap

    valid = [m for m in pycolmap.CameraModelId.__members__ if m != "INVALID"]
    if str(name).upper() not in valid:
        raise ConfigError(f"unknown camera model {name!r} (COLMAP models: {', '.join(valid)})")
    return str(name).upper()


def _colmap_threads(options: SfmOptions) -> int:
    """Threads of every COLMAP step: one when deterministic (see the module docstring), else ``num_threads``."""
    return 1 if options.deterministic else int(options.num_threads)


def _mapper_options(options: SfmOptions):
    """Incremental pipeline options with every seed set and, when deterministic, single-threaded solves."""
    import pycolmap

    pycolmap.set_random_seed(int(options.seed))  # the global generator some COLMAP code paths draw from
    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.num_threads = _colmap_threads(options)
    mapper.random_seed = int(options.seed)
    mapper.mapper.random_seed = int(options.seed)
    mapper.triangulation.random_seed = int(options.seed)
    return mapper


def _global_options(options: SfmOptions):
    """GLOMAP pipeline options with every seed set and, when deterministic, one thread."""
    import pycolmap

    pycolmap.set_random_seed(int(options.seed))
    opts = pycolmap.GlobalPipelineOptions()
    opts.num_threads = _colmap_threads(options)
    opts.random_seed = int(options.seed)
    opts.mapper.num_threads = _colmap_threads(options)
    opts.mapper.random_seed = int(options.seed)
    opts.min_model_size = 2
    return opts


def _hierarchical_options(options: SfmOptions):
    """Hierarchical pipeline options: incremental mapping per cluster (seeded), one worker when deterministic."""
    import pycolmap

    opts = pycolmap.HierarchicalPipelineOptions()
    opts.incremental_options = _mapper_options(options)
    opts.incremental_options.min_model_size = 2
    opts.num_threads = _colmap_threads(options)
    opts.num_workers = 1 if options.deterministic else -1
    return opts


def _map(mapper: Mapper, db: Path, image_dir: Path, out: Path, options: SfmOptions) -> dict:
    """Run one of COLMAP's mappers on a matched database; the models it built, by index."""
    import pycolmap

    out.mkdir(parents=True, exist_ok=True)
    if mapper is Mapper.GLOBAL:
        return pycolmap.global_mapping(db, image_dir, out, options=_global_options(options))
    if mapper is Mapper.HIERARCHICAL:
        return pycolmap.hierarchical_mapping(db, image_dir, out, options=_hierarchical_options(options))
    incremental = _mapper_options(options)
    incremental.min_model_size = 2
    return pycolmap.incremental_mapping(db, image_dir, out, options=incremental)


def _robust_bundle_adjustment(rec, loss_px: float, deterministic: bool = True) -> None:
    import pycolmap

    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_principal_point = False  # as in the mapper: the principal point is poorly constrained
    ba.print_summary = False
    ba.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    ba.ceres.loss_function_scale = float(loss_px)
    solver = ba.ceres.solver_options
    solver.max_num_iterations = 200
    solver.function_tolerance = 1e-10
    solver.gradient_tolerance = 1e-10
    solver.parameter_tolerance = 1e-10
    if deterministic:  # multi-threaded Ceres sums in thread order: last bits differ run to run
        solver.num_threads = 1
    pycolmap.bundle_adjustment(rec, ba)


def _refine_model(rec, options: SfmOptions) -> None:
    """Robust global bundle adjustment of the mapped model, in place.

    The mapper's global BA uses a squared (non-robust) loss and keeps observations up to
    ``filter_max_reproj_error`` (4 px). Matches on view-dependent surfaces (mirror, glass, specular highlights)
    and on grazing, affinely distorted texture sit at 1-4 px; cameras that see few points (low, oblique rings)
    are then pulled by them (the tabletop scene's figures: docs/experiments/2026-11-27-pipeline-defaults.md,
    "SfM stage: determinism and the robust refinement"). A Cauchy loss of about 1 px downweights them,
    observations still above ``refine_filter_px`` are dropped, and a second robust BA settles the poses.
    """
    import pycolmap

    if options.refine_loss_px <= 0 or rec.num_points3D() == 0:
        return
    _robust_bundle_adjustment(rec, options.refine_loss_px, options.deterministic)
    if options.refine_filter_px > 0:
        pycolmap.ObservationManager(rec).filter_all_points3D(float(options.refine_filter_px), 1.5)
        _robust_bundle_adjustment(rec, options.refine_loss_px, options.deterministic)


def _write_model(rec, out_dir: Path) -> None:
    """Write a model into ``out_dir`` atomically (temporary sibling folder, then rename)."""
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        rec.write(str(tmp))
        if out_dir.exists():
            shutil.rmtree(out_dir)
        tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _db_path(options: SfmOptions, tmp: Path) -> Path:
    db = Path(options.database_path) if options.database_path else tmp / "database.db"
    db.parent.mkdir(parents=True, exist_ok=True)
    if db.exists():
        db.unlink()
    return db


def run_sfm(
    image_dir: str | Path,
    out_dir: str | Path,
    options: SfmOptions = SfmOptions(),
    log_path: str | Path | None = None,
    image_names: list[str] | None = None,
    position_priors: Mapping[str, np.ndarray] | None = None,
):
    """Full SfM; writes the largest model to ``out_dir``. Returns (``pycolmap.Reconstruction``, :class:`SfmReport`).

    image_names: the photos of ``image_dir`` to use (default: every photo at its top level). log_path: append
    COLMAP's output there instead of the terminal. position_priors: image name → camera centre (metres, any
    Cartesian frame, e.g. ``--reference``): the spatial matcher's priors (see :func:`_choose_matcher`); they do not
    constrain the mapping. Raises :class:`ReconstructionError` when no model can be built (images do not overlap).
    """
    image_dir, out_dir = Path(image_dir), Path(out_dir)
    _camera_model(options.camera_model)
    check = check_images(image_dir, image_names)
    report = SfmReport(len(check.valid) + len(check.skipped), [], {}, dict(check.skipped))
    if check.mixed_sizes:
        report.warnings.append("images have different sizes: one camera per image")
    with native_output_to(log_path) as log:
        try:
            rec = _run_sfm(image_dir, out_dir, options, check, report, position_priors)
        finally:
            if log is not None:
                report.warnings.extend(log.warnings)
    return rec, report


def _run_sfm(
    image_dir: Path,
    out_dir: Path,
    options: SfmOptions,
    check: ImageCheck,
    report: SfmReport,
    priors: Mapping[str, np.ndarray] | None,
):

    with tempfile.TemporaryDirectory(prefix="hybridsplat_sfm_") as tmpname:
        tmp = Path(tmpname)
        db = _db_path(options, tmp)
        per_image = check.mixed_sizes or not options.single_camera
        _extract_and_match(db, image_dir, check, options, per_image, report, priors)
        mapper = resolve_mapper(options.mapper, len(check.valid))
        report.mapper = mapper.value
        t0 = time.perf_counter()
        models = _map(mapper, db, image_dir, tmp / "models", options)
        report.seconds_mapping = time.perf_counter() - t0
        if not models:
            report.unregistered = _unregistered_reasons(db, check.valid, set(), {})
            raise ReconstructionError(
                "SfM built no model: the images do not overlap enough "
                f"({sum('no geometrically verified' in r for r in report.unregistered.values())} of {len(check.valid)} "
                "images have no verified match)",
                image_dir,
            )
        order = sorted(models, key=lambda k: -models[k].num_reg_images())
        rec = models[order[0]]
        registered = {rec.image(i).name for i in rec.reg_image_ids()}
        others = {}
        for k in order[1:]:
            for i in models[k].reg_image_ids():
                others.setdefault(models[k].image(i).name, models[k].num_reg_images())
        report.num_models = len(models)
        report.registered = sorted(registered)
        report.unregistered = _unregistered_reasons(db, check.valid, registered, others)
        t1 = time.perf_counter()
        _refine_model(rec, options)
        report.seconds_refinement = time.perf_counter() - t1
        _fill_report(rec, report)
        _write_model(rec, out_dir)
    return rec


def triangulate_known_poses(
    cameras: Cameras,
    image_dir: str | Path,
    out_dir: str | Path,
    options: SfmOptions = SfmOptions(),
    log_path: str | Path | None = None,
):
    """Match features and triangulate with the given cameras fixed. Returns (Reconstruction, :class:`SfmReport`).

    Images of ``cameras`` missing from or unreadable in ``image_dir`` are skipped with a reason; poses and
    intrinsics are not refined. log_path: append COLMAP's output there instead of the terminal.
    """
    with native_output_to(log_path) as log:
        report = SfmReport(len(cameras), [], {}, {})
        try:
            rec = _triangulate_known_poses(cameras, Path(image_dir), Path(out_dir), options, report)
        finally:
            if log is not None:
                report.warnings.extend(log.warnings)
    return rec, report


def _triangulate_known_poses(cameras: Cameras, image_dir: Path, out_dir: Path, options: SfmOptions, report):
    import pycolmap

    from core.io.colmap import camera_to_pycolmap

    names = [v.name for v in cameras]
    missing = {
        n: "listed in the model but not found in the image folder" for n in names if not (image_dir / n).is_file()
    }
    check = check_images(image_dir, [n for n in names if n not in missing])
    check.skipped.update(missing)
    report.skipped = dict(check.skipped)
    with tempfile.TemporaryDirectory(prefix="hybridsplat_tri_") as tmpname:
        tmp = Path(tmpname)
        db = _db_path(options, tmp)
        centres = {v.name: v.center for v in cameras}  # the spatial matcher's priors, when auto picks it
        _extract_and_match(db, image_dir, check, options, True, report, centres)
        rec = pycolmap.Reconstruction()
        with pycolmap.Database.open(str(db)) as database:
            db_images = {im.name: im for im in database.read_all_images()}
            for name in check.valid:  # one database camera per image (PER_IMAGE): give it the true intrinsics
                im = db_images[name]
                pc = camera_to_pycolmap(cameras.camera_of(cameras.by_name(name)))
                pc.camera_id = int(im.camera_id)
                pc.has_prior_focal_length = True
                database.update_camera(pc)
        for name in check.valid:
            im = db_images[name]
            view = cameras.by_name(name)
            pc = camera_to_pycolmap(cameras.camera_of(view))
            pc.camera_id = int(im.camera_id)
            rec.add_camera_with_trivial_rig(pc)
            image = pycolmap.Image(name=name, camera_id=int(im.camera_id), image_id=int(im.image_id))
            rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(view.cam_from_world))
        mapper = _mapper_options(options)
        t0 = time.perf_counter()
        rec = pycolmap.triangulate_points(rec, db, image_dir, tmp / "tri", options=mapper)
        report.seconds_mapping = time.perf_counter() - t0
        report.registered = sorted(rec.image(i).name for i in rec.reg_image_ids())
        _fill_report(rec, report)
        if report.num_points == 0:
            raise ReconstructionError("no 3D point could be triangulated from the known poses (no overlap?)", image_dir)
        _write_model(rec, out_dir)
    return rec


def centers_by_name(cameras: Cameras) -> dict[str, np.ndarray]:
    """Camera centres (3,) float64 in the Cameras' local frame, by image name."""
    return {v.name: v.center for v in cameras}
