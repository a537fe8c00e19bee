"""Stage ``sfm``: camera poses and a sparse model of the photos (PROJECT/sparse).

Known cameras (``--cameras MODEL``, or a data_synth scene's / COLMAP workspace's own) are kept as they are and only
matched and triangulated; otherwise full SfM with pycolmap, then a robust similarity alignment to the reference
camera centres when a reference is given (``--reference``; a data_synth scene's true cameras by default).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from core.io.json_io import write_json_atomic
from hybridsplat.stages import sizes
from hybridsplat.stages.base import CliOption, Stage, StageContext, StageResult, omitted_if_none
from recon.sfm import SfmOptions


@dataclass(frozen=True)
class SfmResult(StageResult):
    """What the sfm stage made: ``images`` photos given, ``registered`` of them posed, ``unregistered`` (name → why
    not), ``points`` sparse points and their mean reprojection error (px); the ``mapper`` that ran (None for
    known poses) and the ``matcher`` (how it was chosen); with a reference, the alignment's RMS over its inlier
    camera centres (m) and their number."""

    images: int = 0
    registered: int = 0
    unregistered: dict[str, str] = field(default_factory=dict)
    points: int = 0
    reprojection_error_px: float = 0.0
    mapper: str | None = omitted_if_none()
    matcher: str = ""
    alignment_rms_m: float | None = omitted_if_none()
    alignment_inliers: int | None = omitted_if_none()


class SfmStage(Stage):
    name = "sfm"
    Options = SfmOptions
    Result = SfmResult
    title = "camera poses and sparse model"
    uses_seed = True
    command_options = (
        CliOption("camera_model", help="COLMAP camera model for SfM."),
        CliOption(
            "single_camera", "--single-camera/--camera-per-photo", help="One camera for all photos, or one per photo."
        ),
        CliOption(
            "matcher",
            help="auto (exhaustive up to 150 photos; then spatial with GPS or --reference priors, else sequential) | "
            "exhaustive | sequential | spatial | vocabtree.",
        ),
        CliOption(
            "mapper", help="auto (incremental below 200 photos, else global) | incremental | global | hierarchical."
        ),
        CliOption("max_image_size", help="Features are extracted at this longer side (px)."),
    )
    run_options = command_options[:4]

    def inputs(self, ctx: StageContext) -> list[Path]:
        src = ctx.source
        extra = [
            p
            for p in (src.known_cameras, _path(ctx.config.input.reference), _path(ctx.config.input.feature_masks))
            if p
        ]
        return [src.image_dir, *extra]

    def outputs(self, ctx: StageContext) -> list[Path]:
        return [ctx.layout.sparse, ctx.layout.record(self.name)]

    def expected_bytes(self, ctx: StageContext) -> int:
        """Bytes of the sparse model, the record and COLMAP's log: per photo a fixed record (camera, image, frame,
        rig: 512 bytes and its name) and 58 bytes per feature (24 in images.bin; in points3D.bin 8 for its track
        entry and half of a 51-byte point, which has at least 2 observations); features per photo at most
        ``max_num_features`` and one per 4 pixels of the photo at the extraction size (SIFT finds about one per 40);
        the record 8 KiB + 256 bytes and the name per photo; the log 64 KiB + 16 KiB per photo."""
        opts: SfmOptions = ctx.options(self)
        names = ctx.source.spec.image_names
        found = _photo_sizes(ctx)
        features = sum(_feature_bound(size, opts) for size in found)
        features += opts.max_num_features * max(0, len(names) - len(found))  # photos whose size is unknown
        name_bytes = sum(len(n.encode()) for n in names)
        model = 40 + 512 * len(names) + name_bytes + 58 * features
        record = 8 * sizes.KIB + 256 * len(names) + name_bytes
        return model + record + sizes.LOG_BYTES + 16 * sizes.KIB * len(names)

    def run(self, ctx: StageContext) -> SfmResult:
        from recon.align import align_to_reference
        from recon.model import from_reconstruction, read_reconstruction
        from recon.sfm import run_sfm, triangulate_known_poses

        opts: SfmOptions = ctx.options(self)
        src, layout = ctx.source, ctx.layout
        origin = np.asarray(src.spec.origin, dtype=np.float64)
        sfm_options = replace(opts, seed=ctx.config.seed, mask_dir=ctx.config.input.feature_masks)
        ctx.progress("features, matching, " + ("triangulation" if src.known_cameras else "mapping"), 0, 1)
        if src.known_cameras is not None:
            cameras = from_reconstruction(read_reconstruction(src.known_cameras))
            rec, report = triangulate_known_poses(cameras, src.image_dir, layout.sparse, sfm_options)
        else:
            reference, reference_origin = _reference_centers(ctx)
            rec, report = run_sfm(
                src.image_dir,
                layout.sparse,
                sfm_options,
                image_names=list(src.spec.image_names),
                position_priors=reference or None,
            )
            if reference:
                aligned = align_to_reference(rec, reference, opts.align_threshold_m, seed=ctx.config.seed)
                report.alignment = aligned.result
                origin = reference_origin + aligned.origin  # world = origin + local model coordinates
                rec.write(str(layout.sparse))
        ctx.progress("features, matching, " + ("triangulation" if src.known_cameras else "mapping"), 1, 1)
        write_json_atomic(
            layout.record(self.name),
            {"image_dir": str(src.image_dir.resolve()), "origin": origin, "report": report},
        )
        aligned = report.alignment
        return SfmResult(
            images=report.num_images,
            registered=len(report.registered),
            unregistered=report.unregistered,
            points=report.num_points,
            reprojection_error_px=report.mean_reprojection_error,
            mapper=report.mapper or None,
            matcher=report.matcher,
            alignment_rms_m=aligned.rms_inliers if aligned is not None else None,
            alignment_inliers=aligned.num_inliers if aligned is not None else None,
        )

    def summary(self, result: SfmResult) -> str:
        text = (
            f"{result.registered}/{result.images} photos registered, {result.points} points, "
            f"{result.reprojection_error_px:.2f} px"
        )
        if result.alignment_rms_m is not None:
            text += f", aligned (centre rms {result.alignment_rms_m:.3g} m)"
        return text


def _photo_sizes(ctx: StageContext) -> list[tuple[int, int]]:
    """(width, height) of the photos: the known cameras' sizes (one per photo, the largest), else the photos'."""
    names = ctx.source.spec.image_names
    known = ctx.source.known_cameras
    cameras = sizes.camera_sizes(known) if known is not None else []
    if cameras:
        return [sizes.largest(cameras)] * len(names)
    return sizes.photo_sizes(ctx.source.image_dir, names)


def _feature_bound(size: tuple[int, int], opts: SfmOptions) -> int:
    """Most SIFT features of a photo of ``size`` (px): a quarter of its pixels at the extraction size, at most
    ``max_num_features``."""
    width, height = sizes.capped_size(size, opts.max_image_size)
    return min(opts.max_num_features, -(-width * height // 4))


def _path(value: str | None) -> Path | None:
    return Path(value) if value else None


def _reference_centers(ctx: StageContext) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Camera centres to align a full-SfM model to (metres) and the world origin of their frame: ``--reference``
    (world coordinates, origin 0), else the input's own cameras (in the scene's local frame, at its origin)."""
    from recon.model import from_reconstruction, read_reconstruction

    reference = ctx.config.input.reference
    if reference is None:
        known = ctx.source.spec.known_cameras
        if known is None:
            return {}, np.zeros(3)
        centers = {v.name: v.center for v in from_reconstruction(read_reconstruction(known))}
        return centers, np.asarray(ctx.source.spec.origin, dtype=np.float64)
    from recon.reference import read_reference_centers

    return read_reference_centers(reference, ctx.config.input.units), np.zeros(3)
