"""COLMAP dense workspace: layout, depth/normal map files, setup from a sparse model and import.

Layout (what ``pycolmap.stereo_fusion`` reads and ``pycolmap.undistort_images`` writes)::

    dense/
      images/NAME                      undistorted (pinhole) images, possibly downscaled
      sparse/                          the undistorted model: cameras, images AND 3D points with tracks
      stereo/patch-match.cfg           PatchMatch's problems: per reference photo a line with its name, then a line
                                       with its source photos (comma-separated names, or ``__auto__, N``)
      stereo/fusion.cfg                one image name per line: the photos that have depth maps and are fused
      stereo/depth_maps/NAME.{geometric,photometric}.bin
      stereo/normal_maps/NAME.{geometric,photometric}.bin
      fused.ply, fused.ply.vis         the fused cloud and, per point, the images that see it

Map files: ASCII header ``W&H&C&`` then little-endian float32, one channel after another (planar).
Depth maps hold z-depth along the optical axis (<= 0 invalid); normal maps hold camera-frame unit normals
facing the camera. COLMAP's dense stage back-projects array element (row, col) along ``K⁻¹·(col, row, 1)``
(no +0.5): writers of depth maps must follow that convention (see :mod:`recon.mvs_cpu`).
"""

from __future__ import annotations

import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from core.errors import FormatError, InputFileError, ReconstructionError
from core.io import colmap_vis
from core.io.atomic import atomic_path
from core.io.colmap_scan import scan_model
from core.pointcloud import PointCloud

if TYPE_CHECKING:
    from collections.abc import Iterator

    from core.io.point_stream import PointSource

MAP_SUFFIXES = ("geometric", "photometric")
# Source-list keywords of COLMAP's patch-match.cfg (src/colmap/mvs/patch_match.cc, PatchMatchController::ReadProblems).
PATCH_MATCH_KEYWORDS = ("__all__", "__auto__")
_SPACE = " \t\n\r\f\v"  # what COLMAP's StringTrim removes (std::isspace in the C locale)


# -- map files --------------------------------------------------------------------------------------
def write_array(path: str | PathLike[str], array: np.ndarray) -> None:
    """Write an (H, W) or (H, W, C) array as a COLMAP map file (float32, planar channels), atomically."""
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise FormatError(f"map must be (H, W) or (H, W, C), got shape {a.shape}", path)
    h, w, c = a.shape
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(f"{w}&{h}&{c}&".encode("ascii"))
        f.write(np.ascontiguousarray(a.transpose(2, 0, 1)).astype("<f4").tobytes())


def read_array(path: str | PathLike[str]) -> np.ndarray:
    """Read a COLMAP map file as (H, W) float32 (one channel) or (H, W, C) float32."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("map file does not exist", path)
    data = path.read_bytes()
    parts = data.split(b"&", 3)
    try:
        w, h, c = (int(p) for p in parts[:3])
    except (ValueError, IndexError) as err:
        raise FormatError("not a COLMAP map file (header 'W&H&C&' missing)", path) from err
    payload = parts[3] if len(parts) > 3 else b""
    if w <= 0 or h <= 0 or c <= 0 or len(payload) != 4 * w * h * c:
        raise FormatError(f"map payload has {len(payload)} bytes, header {w}x{h}x{c} needs {4 * w * h * c}", path)
    a = np.frombuffer(payload, dtype="<f4").reshape(c, h, w).transpose(1, 2, 0).astype(np.float32)
    return a[:, :, 0] if c == 1 else a


# -- workspace layout -------------------------------------------------------------------------------
@dataclass(frozen=True)
class DenseWorkspace:
    """Paths of a COLMAP dense workspace rooted at ``root``."""

    root: Path

    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def sparse(self) -> Path:
        return self.root / "sparse"

    @property
    def stereo(self) -> Path:
        return self.root / "stereo"

    @property
    def fused_ply(self) -> Path:
        return self.root / "fused.ply"

    @property
    def fused_vis(self) -> Path:
        return self.root / "fused.ply.vis"

    def depth_map(self, name: str, kind: str = "geometric") -> Path:
        return self.stereo / "depth_maps" / f"{name}.{kind}.bin"

    def normal_map(self, name: str, kind: str = "geometric") -> Path:
        return self.stereo / "normal_maps" / f"{name}.{kind}.bin"

    def make_dirs(self) -> None:
        for sub in (self.images, self.sparse, self.stereo / "depth_maps", self.stereo / "normal_maps"):
            sub.mkdir(parents=True, exist_ok=True)

    @property
    def fusion_cfg(self) -> Path:
        return self.stereo / "fusion.cfg"

    @property
    def patch_match_cfg(self) -> Path:
        return self.stereo / "patch-match.cfg"

    def write_fusion_cfg(self, names: Sequence[str]) -> None:
        """``stereo/fusion.cfg``: the images to fuse, one per line."""
        for name in names:
            check_cfg_name(name, self.fusion_cfg)
        with atomic_path(self.fusion_cfg) as tmp:
            tmp.write_text("".join(f"{n}\n" for n in names), encoding="utf-8")

    def fused_names(self) -> list[str] | None:
        """The image names of ``stereo/fusion.cfg`` (the photos the dense reconstruction used), None when absent."""
        return read_fusion_cfg(self.fusion_cfg) if self.fusion_cfg.is_file() else None

    def write_patch_match_cfg(self, problems: Mapping[str, Sequence[str]]) -> None:
        """``stereo/patch-match.cfg`` for COLMAP PatchMatch: per reference image name (in the mapping's order) its
        explicit, non-empty list of source image names.

        Only the listed references get depth maps and only the listed sources are read for them. Raises
        :class:`FormatError` for an empty source list (COLMAP's reader would take the next reference's name as the
        sources) and for names COLMAP's reader would change (see :func:`check_cfg_name`).
        """
        lines: list[str] = []
        for ref, sources in problems.items():
            check_cfg_name(ref, self.patch_match_cfg, in_list=True)
            if not sources:
                raise FormatError(f"reference image {ref!r} has no source images", self.patch_match_cfg)
            for src in sources:
                check_cfg_name(src, self.patch_match_cfg, in_list=True)
                if src in PATCH_MATCH_KEYWORDS:
                    raise FormatError(
                        f"image name {src!r} is a keyword of COLMAP's patch-match.cfg", self.patch_match_cfg
                    )
            lines += [ref, ", ".join(sources)]
        with atomic_path(self.patch_match_cfg) as tmp:
            tmp.write_text("".join(f"{line}\n" for line in lines), encoding="utf-8")

    def map_kind(self, name: str) -> str | None:
        """'geometric' or 'photometric' when both maps of ``name`` exist (geometric preferred), else None."""
        for kind in MAP_SUFFIXES:
            if self.depth_map(name, kind).is_file() and self.normal_map(name, kind).is_file():
                return kind
        return None


# -- COLMAP's configuration files (stereo/fusion.cfg, stereo/patch-match.cfg) --------------------------------
def check_cfg_name(name: str, path: str | PathLike[str] | None = None, in_list: bool = False) -> None:
    """Raise :class:`FormatError` for an image name that COLMAP's cfg readers would not read back as written.

    COLMAP trims each line and drops empty ones; in patch-match.cfg (``in_list``) it also skips lines starting with
    '#' and splits source lists at ',' and ';'. So no name may be empty, hold a line break or surrounding white
    space, and a patch-match.cfg name may not start with '#' nor hold ',' or ';'.
    """
    bad = not name or name != name.strip(_SPACE) or "\n" in name or "\r" in name
    if in_list:
        bad = bad or name.startswith("#") or "," in name or ";" in name
    if bad:
        what = "patch-match.cfg (no ',', ';', leading '#'," if in_list else "fusion.cfg (no"
        raise FormatError(
            f"image name {name!r} cannot be written to COLMAP's {what} line breaks or surrounding white space): "
            "rename the photo",
            path,
        )


def read_fusion_cfg(path: str | PathLike[str]) -> list[str]:
    """Image names of a ``fusion.cfg`` as COLMAP reads them: each line trimmed, empty lines skipped."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("fusion.cfg does not exist", path)
    lines = (line.strip(_SPACE) for line in path.read_text(encoding="utf-8").split("\n"))
    return [line for line in lines if line]


def read_patch_match_cfg(path: str | PathLike[str]) -> list[tuple[str, list[str]]]:
    """The problems of a ``patch-match.cfg`` as COLMAP's ``PatchMatchController::ReadProblems`` parses them.

    Returns (reference name, source names) in file order; keywords are kept as written (``["__auto__", "20"]``,
    ``["__all__"]``). Lines are trimmed; empty lines and lines starting with '#' are skipped; the remaining lines
    pair up as reference, sources; sources split at ',' and ';', each trimmed, empty elements dropped. A trailing
    reference without a sources line is ignored, as COLMAP does.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError("patch-match.cfg does not exist", path)
    lines = [line.strip(_SPACE) for line in path.read_text(encoding="utf-8").split("\n")]
    lines = [line for line in lines if line and not line.startswith("#")]
    problems = []
    for ref, sources in zip(lines[0::2], lines[1::2], strict=False):
        names = [e.strip(_SPACE) for e in sources.replace(";", ",").split(",")]
        problems.append((ref, [n for n in names if n]))
    return problems


def setup_dense_workspace(
    sparse_dir: str | PathLike[str],
    image_dir: str | PathLike[str],
    dense_dir: str | PathLike[str],
    max_image_size: int = -1,
) -> DenseWorkspace:
    """Undistort the images of a sparse model into a fresh dense workspace (``pycolmap.undistort_images``).

    ``max_image_size`` (pixels, -1 = keep) caps the longer side of the undistorted images; the dense model's
    cameras are scaled accordingly. Existing ``images/``, ``sparse/`` and ``stereo/`` under ``dense_dir`` are replaced.
    """
    import pycolmap

    sparse_dir, image_dir, dense = Path(sparse_dir), Path(image_dir), Path(dense_dir)
    if not (sparse_dir / "cameras.bin").is_file() and not (sparse_dir / "cameras.txt").is_file():
        raise InputFileError("no COLMAP sparse model (cameras.bin / cameras.txt) here", sparse_dir)
    scan_model(sparse_dir)  # declared counts against file sizes before pycolmap allocates anything
    ws = DenseWorkspace(dense)
    for sub in (ws.images, ws.sparse, ws.stereo):
        if sub.exists():
            shutil.rmtree(sub)
    dense.mkdir(parents=True, exist_ok=True)
    opts = pycolmap.UndistortCameraOptions()
    opts.max_image_size = int(max_image_size)
    pycolmap.undistort_images(
        output_path=str(dense), input_path=str(sparse_dir), image_path=str(image_dir), undistort_options=opts
    )
    ws.make_dirs()
    return ws


# -- import -----------------------------------------------------------------------------------------
def read_vis(path: str | PathLike[str], num_points: int | None = None) -> list[np.ndarray]:
    """Read ``fused.ply.vis``: per point, positions (int64) into the model's ``reg_image_ids()`` order.

    Thin wrapper of :func:`core.io.colmap_vis.read_vis` (the one reader of this file).
    """
    return colmap_vis.read_vis(path, num_points)


def write_vis(path: str | PathLike[str], visibility: list[np.ndarray]) -> None:
    """Write ``fused.ply.vis``; thin wrapper of :func:`core.io.colmap_vis.write_vis`."""
    colmap_vis.write_vis(path, visibility)


def read_fused(dense_dir: str | PathLike[str]) -> PointCloud:
    """The fused cloud of a dense workspace, with ``visibility`` as COLMAP image ids (not vis-file positions)."""
    import pycolmap

    from core.io.ply import read_ply

    ws = DenseWorkspace(Path(dense_dir))
    if not ws.fused_ply.is_file():
        raise InputFileError("dense workspace has no fused.ply", ws.root)
    cloud = read_ply(ws.fused_ply)
    if ws.fused_vis.is_file():
        vis = read_vis(ws.fused_vis, len(cloud))
        rec = pycolmap.Reconstruction(str(ws.sparse))
        cloud.visibility = colmap_vis.positions_to_image_ids(vis, rec.reg_image_ids(), ws.fused_vis)
    return cloud


def fused_source(dense_dir: str | PathLike[str], chunk: int = 2_000_000) -> PointSource:
    """The fused cloud of a dense workspace as a chunk stream, as :func:`recon.workspace.read_fused` reads it whole:
    ``fused.ply`` and, when present, ``fused.ply.vis`` with ``visibility`` as COLMAP image ids (the positions checked
    against the sparse model's registered images chunk by chunk: the same :class:`FormatError`); ``chunk`` points a
    chunk at most."""
    from core.io.colmap_vis import positions_to_image_ids
    from core.io.point_stream import PointSource, ply_source  # noqa: F811 (the annotation's name, at run time)

    ws = DenseWorkspace(Path(dense_dir))
    if not ws.fused_ply.is_file():
        raise InputFileError("dense workspace has no fused.ply", ws.root)
    if not ws.fused_vis.is_file():
        return ply_source(ws.fused_ply, chunk=chunk)
    import pycolmap

    base = ply_source(ws.fused_ply, ws.fused_vis, chunk=chunk)
    image_ids = pycolmap.Reconstruction(str(ws.sparse)).reg_image_ids()

    def chunks() -> Iterator[PointCloud]:
        for chunk in base.chunks():
            chunk.visibility = positions_to_image_ids(chunk.visibility, image_ids, ws.fused_vis)
            yield chunk

    return PointSource(chunks, ws.fused_ply)


def import_dense_workspace(source: str | PathLike[str], dense_dir: str | PathLike[str]) -> DenseWorkspace:
    """Copy an existing COLMAP dense workspace (e.g. from COLMAP's GUI) into ``dense_dir`` and validate it.

    Accepts a workspace with ``sparse/`` and ``images/`` plus either ``fused.ply`` (+ ``.vis``) or depth and
    normal maps to fuse (run :func:`recon.mvs.fuse` afterwards). Raises :class:`InputFileError` when neither exists.
    """
    src, dst = Path(source), Path(dense_dir)
    src_ws = DenseWorkspace(src)
    if not src_ws.sparse.is_dir() or not src_ws.images.is_dir():
        raise InputFileError("not a COLMAP dense workspace (needs sparse/ and images/)", src)
    has_maps = any((src_ws.stereo / "depth_maps").glob("*.bin")) if (src_ws.stereo / "depth_maps").is_dir() else False
    if not src_ws.fused_ply.is_file() and not has_maps:
        raise InputFileError("dense workspace has neither fused.ply nor stereo/depth_maps/*.bin", src)
    if src.resolve() != dst.resolve():
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(src, dst)
    ws = DenseWorkspace(dst)
    if ws.fused_ply.is_file():
        read_fused(dst)  # validates ply + vis against the model
    return ws


def check_fused_nonempty(ws: DenseWorkspace) -> None:
    """Raise :class:`ReconstructionError` when fusion produced no points."""
    if not ws.fused_ply.is_file():
        raise ReconstructionError("fusion wrote no fused.ply", ws.root)
