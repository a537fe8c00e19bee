"""The recon stages as the CLI (and the pipeline) run them: SfM into PROJECT/sparse, MVS into PROJECT/dense."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from core.errors import ReconstructionError
from core.io.origin import write_origin
from recon.align import align_reconstruction_to_centers
from recon.model import from_reconstruction, read_reconstruction
from recon.mvs import MvsOptions, MvsReport, Progress, run_mvs
from recon.project import ProjectPaths, read_sfm_record, resolve_input, write_record
from recon.sfm import SfmOptions, SfmReport, run_sfm, triangulate_known_poses


def sfm_stage(
    input_path: str | Path,
    project: str | Path,
    known_poses: bool = False,
    options: SfmOptions = SfmOptions(),
    reference_model: str | Path | None = None,
    align_threshold: float | None = None,
    progress: Progress | None = None,
) -> SfmReport:
    """SfM of INPUT into PROJECT/sparse.

    known_poses: triangulate with the reference cameras (a data_synth scene's ``sparse/0`` or ``reference_model``).
    Otherwise full SfM, then — when a reference model exists — a robust similarity alignment of the camera
    centres to it (threshold: ``align_threshold`` metres, default 2 % of the reference centres' extent).
    """
    paths = ProjectPaths(Path(project))
    scene = resolve_input(input_path)
    ref_dir = Path(reference_model) if reference_model else scene.reference_model
    reference = from_reconstruction(read_reconstruction(ref_dir)) if ref_dir else None
    t0 = time.perf_counter()
    if known_poses:
        if reference is None:
            raise ReconstructionError(
                "--known-poses needs known cameras: a data_synth scene (sparse/0) or --reference MODEL",
                Path(input_path),
            )
        if progress:
            progress("triangulate", 0, 1)
        rec, report = triangulate_known_poses(reference, scene.image_dir, paths.sparse, options)
    else:
        if progress:
            progress("sfm", 0, 1)
        rec, report = run_sfm(scene.image_dir, paths.sparse, options)
        if reference is not None:
            centers = {v.name: v.center for v in reference}
            c = np.stack(list(centers.values()))
            extent = float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))
            thr = align_threshold if align_threshold else max(0.02 * extent, 1e-6)
            report.alignment = align_reconstruction_to_centers(rec, centers, thr, seed=options.seed)
            rec.write(str(paths.sparse))
    if progress:
        progress("sfm", 1, 1)
    write_record(
        paths.sfm_record,
        {
            "image_dir": str(scene.image_dir.resolve()),
            "reference_model": str(ref_dir.resolve()) if ref_dir else None,
            "known_poses": known_poses,
            "gsd_m": scene.gsd_m,
            "origin": list(scene.origin),
            "seconds": time.perf_counter() - t0,
            "report": report,
        },
    )
    return report


def mvs_stage(
    project: str | Path,
    options: MvsOptions = MvsOptions(),
    image_dir: str | Path | None = None,
    progress: Progress | None = None,
) -> MvsReport:
    """Dense MVS of PROJECT/sparse into PROJECT/dense (images from the SfM record unless ``image_dir``)."""
    paths = ProjectPaths(Path(project))
    record = read_sfm_record(paths) if (paths.sfm_record.is_file() or not image_dir) else None
    images = Path(image_dir) if image_dir else Path(record["image_dir"])
    report = run_mvs(paths.sparse, images, paths.dense, options, progress)
    origin = np.asarray(record.get("origin", (0.0, 0.0, 0.0)) if record else (0.0, 0.0, 0.0), dtype=np.float64)
    if np.any(origin != 0):  # the model is in a local frame: fused.ply gets the offset sidecar (float32 payload)
        write_origin(paths.dense / "fused.ply", origin)
    write_record(
        paths.mvs_record,
        {
            "report": report,
            "seconds_per_view": report.seconds_per_view,
            "seconds_per_megapixel": report.seconds_per_megapixel,
            "options": options,
        },
    )
    return report
