"""Dense MVS: backend dispatch (our CPU MVS or COLMAP PatchMatch) and COLMAP CPU fusion.

``run_mvs(sparse_dir, image_dir, dense_dir, options)`` undistorts the images into a COLMAP dense workspace,
computes depth + normal maps with the chosen backend and fuses them with ``pycolmap.stereo_fusion`` into
``dense/fused.ply`` + ``dense/fused.ply.vis``.

Held-out photos (``MvsOptions.held_out``) are undistorted with the others (evaluation renders at their poses) but on
every backend they are no reference (no depth or normal map), no source (their pixels are never read for another
photo's depth) and not fused: both backends take their sources from :func:`recon.view_selection.select_views` with
the held-out photos excluded (COLMAP through an explicit ``stereo/patch-match.cfg``), and ``stereo/fusion.cfg`` lists
only the photos that got maps.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import ClassVar

import numpy as np

from core.constraints import AnyOf, Choice, Constrained, Constraints, Interval
from core.errors import ConfigError, EmptyFusionError, InputFileError, ReconstructionError
from core.options import runtime_factory
from recon.colmap_log import native_output_to
from recon.mvs_colmap import COLMAP_NUM_SOURCES, colmap_available, patch_match_problems, run_patch_match
from recon.mvs_cpu_options import CpuMvsOptions
from recon.view_selection import select_views
from recon.workspace import DenseWorkspace, read_array, setup_dense_workspace, write_array

Progress = Callable[[str, int, int], None]  # (stage, done, total)


class MvsBackend(str, Enum):
    AUTO = "auto"
    CPU = "cpu"
    COLMAP = "colmap"


@dataclass(frozen=True)
class FusionOptions:
    """``pycolmap.StereoFusionOptions`` we expose; ``deterministic`` runs fusion single-threaded."""

    min_num_pixels: int = 3
    max_reproj_error: float = 2.0
    max_depth_error: float = 0.01
    max_normal_error: float = 10.0
    deterministic: bool = True


@dataclass(frozen=True)
class MvsOptions(Constrained):
    """Options of :func:`run_mvs` and of the pipeline's ``mvs`` stage.

    backend: auto (COLMAP PatchMatch on CUDA, else the CPU MVS) | cpu | colmap. max_image_size: longer side of the
    dense images in pixels, -1 = full resolution; 1000 keeps a CPU run of a few dozen photos in minutes (a
    6-megapixel photo at full size takes over an hour per view on 2 cores). num_threads: torch threads of the CPU
    backend (None = torch's default, all cores). map_cache: depth maps held in memory during the geometric pass
    (bounds memory). held_out: image names never used for depth (as reference or source) nor fusion (set by the
    pipeline from its held-out photos).
    """

    backend: MvsBackend = MvsBackend.AUTO
    max_image_size: int = 1000
    cpu: CpuMvsOptions = field(default_factory=CpuMvsOptions)
    fusion: FusionOptions = field(default_factory=FusionOptions)
    num_threads: int | None = None
    map_cache: int = 16
    held_out: frozenset[str] = runtime_factory(frozenset)

    constraints: ClassVar[Constraints] = {
        "backend": Choice(MvsBackend),
        "max_image_size": AnyOf(Interval(int, 1, None), Choice((-1,))),  # -1: full size
    }


@dataclass
class MvsReport:
    """What a dense run did: backend, sizes, timings (seconds) and counts."""

    backend: str
    num_views: int
    image_sizes: list[tuple[int, int]]
    seconds_undistort: float = 0.0
    seconds_depth: float = 0.0
    seconds_geometric: float = 0.0
    seconds_fusion: float = 0.0
    valid_fraction: dict[str, float] = field(default_factory=dict)  # per image, after the geometric filter
    num_points: int = 0
    # COLMAP's warnings (one line each) when a log was kept, and photos the COLMAP backend left without a depth map
    warnings: list[str] = field(default_factory=list)

    @property
    def megapixels(self) -> float:
        return sum(w * h for w, h in self.image_sizes) / 1e6

    @property
    def seconds_per_view(self) -> float:
        return (self.seconds_depth + self.seconds_geometric) / max(self.num_views, 1)

    @property
    def seconds_per_megapixel(self) -> float:
        return (self.seconds_depth + self.seconds_geometric) / max(self.megapixels, 1e-9)


def resolve_backend(backend: MvsBackend | str) -> MvsBackend:
    """AUTO → COLMAP when pycolmap has CUDA, else CPU; COLMAP without CUDA raises :class:`ConfigError`."""
    b = MvsBackend(backend)
    if b is MvsBackend.AUTO:
        return MvsBackend.COLMAP if colmap_available() else MvsBackend.CPU
    if b is MvsBackend.COLMAP and not colmap_available():
        raise ConfigError(
            "backend 'colmap' needs pycolmap built with CUDA (pycolmap.has_cuda is False); use --backend cpu"
        )
    return b


def run_mvs(
    sparse_dir: str | Path,
    image_dir: str | Path,
    dense_dir: str | Path,
    options: MvsOptions = MvsOptions(),
    progress: Progress | None = None,
    log_path: str | Path | None = None,
) -> MvsReport:
    """Undistort, estimate depth/normal maps, fuse. Returns an :class:`MvsReport`.

    log_path: COLMAP's output (undistortion, PatchMatch, fusion) is appended there instead of reaching the terminal;
    its warnings are in ``MvsReport.warnings``. ``progress`` callbacks still reach the terminal.
    """
    backend = resolve_backend(options.backend)
    warnings: list[str] = []
    t0 = time.perf_counter()
    with native_output_to(log_path) as log:
        ws = setup_dense_workspace(sparse_dir, image_dir, dense_dir, options.max_image_size)
    warnings += log.warnings if log else []
    t_undistort = time.perf_counter() - t0
    if backend is MvsBackend.COLMAP:
        with native_output_to(log_path) as log:
            report = compute_depth_maps_colmap(ws, options)
        warnings += (log.warnings if log else []) + report.warnings
    else:
        report = compute_depth_maps_cpu(ws, options, progress)
    report.seconds_undistort = t_undistort
    t2 = time.perf_counter()
    report.num_points = fuse(ws, options.fusion, log_path=log_path, warnings=warnings)
    report.seconds_fusion = time.perf_counter() - t2
    report.warnings = warnings
    return report


def compute_depth_maps_colmap(ws: DenseWorkspace, options: MvsOptions = MvsOptions()) -> MvsReport:
    """Run COLMAP PatchMatch (CUDA) on an undistorted workspace: photometric, then geometric maps + normals.

    Writes ``stereo/patch-match.cfg`` first (see :func:`recon.mvs_colmap.patch_match_problems`: no held-out photo is
    a reference or a source), then ``stereo/fusion.cfg`` with the references. Photos left without a source get no
    map; each is named in ``MvsReport.warnings``. Raises :class:`ReconstructionError` when fewer than 2 photos have
    sources, :class:`ConfigError` when pycolmap has no CUDA.
    """
    import pycolmap

    rec = pycolmap.Reconstruction(str(ws.sparse))
    problems = patch_match_problems(rec, options.held_out, COLMAP_NUM_SOURCES)
    if len(problems) < 2:
        raise ReconstructionError(
            f"dense reconstruction needs at least 2 photos with source photos (shared sparse points), got "
            f"{len(problems)} ({len(options.held_out)} held out)",
            ws.sparse,
        )
    ws.write_patch_match_cfg(problems)
    t0 = time.perf_counter()
    run_patch_match(ws.root, options.max_image_size)
    seconds = time.perf_counter() - t0
    ws.write_fusion_cfg(list(problems))
    by_name = {rec.image(i).name: rec.image(i) for i in rec.reg_image_ids()}
    sizes = [(int(by_name[n].camera.width), int(by_name[n].camera.height)) for n in problems]
    report = MvsReport(backend=MvsBackend.COLMAP.value, num_views=len(problems), image_sizes=sizes)
    report.seconds_depth = seconds
    report.warnings = [
        f"{name}: no depth map (no source photo shares sparse points with it at a usable angle)"
        for name in sorted(set(by_name) - set(problems) - set(options.held_out))
    ]
    return report


def _load_gray(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputFileError("cannot read image (corrupt or unsupported format)", path)
    return img.astype(np.float32) / 255.0


class _LRU:
    """A small least-recently-used cache of per-image arrays (keeps memory bounded)."""

    def __init__(self, loader: Callable[[int], np.ndarray], size: int) -> None:
        self.loader, self.size, self.items = loader, max(1, size), OrderedDict()

    def __call__(self, key: int) -> np.ndarray:
        if key in self.items:
            self.items.move_to_end(key)
            return self.items[key]
        value = self.loader(key)
        self.items[key] = value
        if len(self.items) > self.size:
            self.items.popitem(last=False)
        return value


def compute_depth_maps_cpu(
    ws: DenseWorkspace, options: MvsOptions = MvsOptions(), progress: Progress | None = None
) -> MvsReport:
    """Run the CPU MVS on an undistorted workspace: photometric maps, then geometric (filtered) maps + normals."""
    import pycolmap
    import torch

    from recon.mvs_cpu import estimate_depth, geometric_filter, normals_from_depth  # torch: only when it runs

    if options.num_threads:
        torch.set_num_threads(int(options.num_threads))
    rec = pycolmap.Reconstruction(str(ws.sparse))
    ids = sorted(int(i) for i in rec.reg_image_ids() if rec.image(i).name not in options.held_out)
    if len(ids) < 2:
        raise ReconstructionError(
            f"dense reconstruction needs at least 2 registered images, the model has {len(ids)}", ws.sparse
        )
    held_out_ids = frozenset(int(i) for i in rec.reg_image_ids() if rec.image(i).name in options.held_out)
    sel = select_views(rec, num_sources=options.cpu.num_sources, exclude=held_out_ids)
    names = {i: rec.image(i).name for i in ids}
    Ks = {i: np.asarray(rec.image(i).camera.calibration_matrix(), dtype=np.float64) for i in ids}
    poses = {}
    for i in ids:
        m = np.eye(4)
        m[:3] = np.asarray(rec.image(i).cam_from_world().matrix())
        poses[i] = m
    images = _LRU(lambda i: _load_gray(ws.images / names[i]), options.map_cache)
    report = MvsReport(backend="cpu", num_views=len(ids), image_sizes=[])
    fusion_names: list[str] = []

    def rel(src: int, ref: int) -> np.ndarray:
        return poses[src] @ np.linalg.inv(poses[ref])

    t0 = time.perf_counter()
    for n, ref in enumerate(ids):
        srcs = sel.sources.get(ref, [])
        img = images(ref)
        report.image_sizes.append((img.shape[1], img.shape[0]))
        est = estimate_depth(
            img,
            [images(s) for s in srcs],
            Ks[ref],
            [Ks[s] for s in srcs],
            [rel(s, ref) for s in srcs],
            sel.depth_range[ref],
            options.cpu,
        )
        write_array(ws.depth_map(names[ref], "photometric"), est.depth)
        write_array(
            ws.normal_map(names[ref], "photometric"), normals_from_depth(est.depth, Ks[ref], options.cpu.normal_radius)
        )
        if progress:
            progress("depth", n + 1, len(ids))
    report.seconds_depth = time.perf_counter() - t0

    t1 = time.perf_counter()
    depths = _LRU(lambda i: read_array(ws.depth_map(names[i], "photometric")), options.map_cache)
    for n, ref in enumerate(ids):
        srcs = sel.sources.get(ref, [])
        depth, _ = geometric_filter(
            depths(ref),
            Ks[ref],
            [depths(s) for s in srcs],
            [Ks[s] for s in srcs],
            [rel(s, ref) for s in srcs],
            options.cpu.geom_max_reproj_px,
            options.cpu.geom_max_rel_depth,
            min(options.cpu.geom_min_consistent, max(len(srcs), 1)),
        )
        normals = normals_from_depth(depth, Ks[ref], options.cpu.normal_radius)
        depth = np.where(np.any(normals != 0, axis=-1), depth, 0.0).astype(np.float32)
        write_array(ws.depth_map(names[ref], "geometric"), depth)
        write_array(ws.normal_map(names[ref], "geometric"), normals)
        report.valid_fraction[names[ref]] = float((depth > 0).mean())
        fusion_names.append(names[ref])
        if progress:
            progress("geometric", n + 1, len(ids))
    report.seconds_geometric = time.perf_counter() - t1
    ws.write_fusion_cfg(fusion_names)
    return report


def fuse(
    ws: DenseWorkspace | str | Path,
    options: FusionOptions = FusionOptions(),
    log_path: str | Path | None = None,
    warnings: list[str] | None = None,
) -> int:
    """``pycolmap.stereo_fusion`` (CPU) of the workspace's geometric maps (photometric when those are absent).

    Writes ``fused.ply`` and ``fused.ply.vis``; returns the number of fused points. Raises
    :class:`EmptyFusionError` when fusion yields no point. log_path: COLMAP's output goes there (appended);
    its warnings are appended to ``warnings`` when a list is given.
    """
    import pycolmap

    ws = ws if isinstance(ws, DenseWorkspace) else DenseWorkspace(Path(ws))
    names = ws.fused_names()
    if names is None:
        rec = pycolmap.Reconstruction(str(ws.sparse))
        names = [rec.image(i).name for i in sorted(rec.reg_image_ids())]
        ws.write_fusion_cfg(names)
    kinds = {ws.map_kind(n) for n in names}
    if None in kinds:
        missing = [n for n in names if ws.map_kind(n) is None]
        raise InputFileError(f"depth/normal maps missing for {len(missing)} images (first: {missing[0]})", ws.stereo)
    kind = "geometric" if kinds == {"geometric"} else "photometric"
    opts = pycolmap.StereoFusionOptions()
    opts.min_num_pixels = int(options.min_num_pixels)
    opts.max_reproj_error = float(options.max_reproj_error)
    opts.max_depth_error = float(options.max_depth_error)
    opts.max_normal_error = float(options.max_normal_error)
    if options.deterministic:
        opts.num_threads = 1
    for p in (ws.fused_ply, ws.fused_vis):
        p.unlink(missing_ok=True)
    with native_output_to(log_path) as log:
        rec = pycolmap.stereo_fusion(str(ws.fused_ply), str(ws.root), input_type=kind, options=opts, output_type="PLY")
    if log is not None and warnings is not None:
        warnings.extend(log.warnings)
    n = int(rec.num_points3D()) if rec is not None else 0
    if n == 0 or not ws.fused_ply.is_file():
        raise EmptyFusionError(
            "fusion produced no points (depth maps empty or inconsistent, or the sparse model has no points)", ws.root
        )
    return n
