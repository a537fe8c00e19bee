"""Upper estimates of file sizes, in bytes: the shared arithmetic of the stages' ``expected_bytes``.

Sizes come from counts (Gaussians, points, pixels, triangles) and from what is cheap to read of the files already
there: PLY headers (vertex count and properties), the headers of a COLMAP model's binary files, image headers.
Every reader returns an empty answer (0, ``()``, ``[]``) for a missing or unreadable file instead of raising: an
estimate must never be the reason a stage fails.
"""

from __future__ import annotations

import math
import struct
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

from core.errors import HybridSplatError

KIB = 1 << 10
MIB = 1 << 20
LOG_BYTES = 64 * KIB
"""A stage's log when only Python warnings and prints reach it (bytes)."""
JSON_BYTES = 64 * KIB
"""A small JSON record of fixed shape (a report, the options, a few counts) (bytes)."""
SIDECAR_BYTES = 4 * KIB
"""An ``<name>.origin.json`` sidecar (bytes)."""
PLY_HEADER_BYTES = 1 * KIB
"""A PLY header besides its property lines (bytes)."""
PLY_PROPERTY_BYTES = 32
"""One ``property <type> <name>`` line of a PLY header (bytes)."""
JPEG_BYTES_PER_PIXEL = 1.5
"""JPEG at quality ≤ 90 with 4:2:0 chroma (OpenCV's and Pillow's default): white noise takes about 1 (bytes)."""

_GAUSSIAN_BASE = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                  "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")  # fmt: skip
_STANDARD = frozenset((*_GAUSSIAN_BASE, "red", "green", "blue", "alpha"))


def gaussian_properties(sh_degree: int, extra_fields: int = 0) -> int:
    """Float32 properties per Gaussian of a 3DGS PLY: position, normal, SH (3 × (d + 1)² coefficients), opacity,
    scale, rotation, and ``extra_fields`` appended fields."""
    return len(_GAUSSIAN_BASE) + 3 * ((sh_degree + 1) ** 2 - 1) + extra_fields


def gaussian_ply_bytes(count: int, sh_degree: int, extra_fields: int = 0) -> int:
    """Bytes of a 3DGS PLY of ``count`` Gaussians: 4 bytes per property per Gaussian, plus the header."""
    props = gaussian_properties(sh_degree, extra_fields)
    return PLY_HEADER_BYTES + PLY_PROPERTY_BYTES * props + 4 * props * max(count, 0)


def point_ply_bytes(count: int, fields: int) -> int:
    """Upper bytes of a binary point PLY: float64 positions (24), float32 normals (12), RGB (3) and ``fields``
    scalar fields of at most 8 bytes each, per point, plus the header."""
    return PLY_HEADER_BYTES + PLY_PROPERTY_BYTES * (fields + 9) + max(count, 0) * (39 + 8 * fields)


def las_bytes(count: int, fields: int) -> int:
    """Upper bytes of a LAS 1.4 file (point format 7: 36 bytes) with ``fields`` extra dimensions of at most 8 bytes
    each, per point, plus the header, the extra-bytes descriptors (192 bytes each) and a CRS record."""
    return 4 * KIB + 192 * fields + max(count, 0) * (36 + 8 * fields)


def png_bytes(width: int, height: int, channels: int) -> int:
    """Upper bytes of a PNG of ``width`` × ``height`` 8-bit pixels: the raw rows (a filter byte each) plus deflate's
    stored-block and the chunks' overhead (< 1/512 of it) and the signature, header and metadata chunks."""
    raw = max(height, 0) * (1 + max(width, 0) * channels)
    return raw + raw // 512 + KIB


def sparse_png_bytes(width: int, height: int, marked: int, channels: int = 3) -> int:
    """Upper bytes of a PNG of one background colour with at most ``marked`` other pixels (a scatter of points):
    deflate codes a background run in a few bytes, each marked pixel and the filtered neighbours it changes in at
    most 32, and a row in at most 16 more; never more than :func:`png_bytes`."""
    return min(png_bytes(width, height, channels), 32 * max(marked, 0) + 16 * max(height, 0) + KIB)


def figure_png_bytes(width_in: float, height_in: float, dpi: int = 100, pad_in: float = 0.1) -> int:
    """Upper bytes of a matplotlib RGBA PNG of a ``width_in`` × ``height_in`` inch figure saved at ``dpi`` with a
    tight bounding box: what is drawn plus matplotlib's 0.1 in padding; ``pad_in`` more when labels may reach past
    the figure's edges."""
    width = math.ceil((width_in + 2 * pad_in) * dpi)
    height = math.ceil((height_in + 2 * pad_in) * dpi)
    return png_bytes(width, height, 4)


def jpeg_bytes(width: int, height: int) -> int:
    """Upper bytes of a JPEG of ``width`` × ``height`` pixels (:data:`JPEG_BYTES_PER_PIXEL`, plus headers)."""
    return math.ceil(JPEG_BYTES_PER_PIXEL * max(width, 0) * max(height, 0)) + 2 * KIB


def svg_bytes(bars: int) -> int:
    """Upper bytes of a matplotlib SVG bar chart of ``bars`` bars (axes, glyphs and labels, plus 1 KiB a bar)."""
    return 64 * KIB + KIB * max(bars, 0)


def thumbnail_size(size: tuple[int, int], max_side: int) -> tuple[int, int]:
    """``size`` (width, height, px) scaled down (never up) so that its longer side is at most ``max_side``."""
    width, height = size
    scale = min(1.0, max_side / max(width, height, 1))
    return max(1, round(width * scale)), max(1, round(height * scale))


def capped_size(size: tuple[int, int], max_side: int) -> tuple[int, int]:
    """``size`` (width, height, px) scaled down so that its longer side is at most ``max_side`` (≤ 0: no cap),
    rounded up."""
    width, height = size
    if max_side <= 0 or max(width, height) <= max_side:
        return width, height
    scale = max_side / max(width, height)
    return math.ceil(width * scale), math.ceil(height * scale)


def largest(sizes: Sequence[tuple[int, int]], default: tuple[int, int] = (0, 0)) -> tuple[int, int]:
    """The (width, height) of largest area among ``sizes``, ``default`` when there is none."""
    return max(sizes, key=lambda s: s[0] * s[1], default=default)


@dataclass(frozen=True)
class PlyVertices:
    """What a PLY header says of its vertices: their count and property names (0 and () without a file)."""

    count: int = 0
    properties: tuple[str, ...] = ()

    @property
    def extras(self) -> tuple[str, ...]:
        """Properties besides position, normal, colour and the 3DGS parameters (``source``, ``c2c``...)."""
        return tuple(p for p in self.properties if p not in _STANDARD and not p.startswith("f_rest_"))

    @property
    def sh_degree(self) -> int:
        """The SH degree of a 3DGS PLY, from its ``f_rest_*`` properties (0 for a point cloud)."""
        rest = sum(p.startswith("f_rest_") for p in self.properties)
        return max(0, round(math.sqrt(rest / 3 + 1)) - 1)


def ply_vertices(path: str | PathLike[str]) -> PlyVertices:
    """The vertex count and properties of the PLY at ``path`` from its header (empty when missing or unreadable)."""
    from core.io.ply import scan_ply_header

    try:
        vertex = scan_ply_header(path).element("vertex")
    except (HybridSplatError, OSError):
        return PlyVertices()
    if vertex is None:
        return PlyVertices()
    return PlyVertices(vertex.count, tuple(name for name, _, _ in vertex.properties))


def camera_sizes(model: str | PathLike[str]) -> list[tuple[int, int]]:
    """(width, height) in pixels of each camera of the COLMAP model folder ``model`` (``cameras.bin`` or
    ``cameras.txt``); [] when it has none or it cannot be read."""
    folder = Path(model)
    try:
        if (folder / "cameras.bin").is_file():
            return _camera_sizes_bin((folder / "cameras.bin").read_bytes())
        if (folder / "cameras.txt").is_file():
            lines = (folder / "cameras.txt").read_text(encoding="utf-8").splitlines()
            rows = [s.split() for s in lines if s.strip() and not s.startswith("#")]
            return [(int(r[2]), int(r[3])) for r in rows]
    except (OSError, ValueError, IndexError, KeyError, struct.error):
        return []
    return []


def _camera_sizes_bin(data: bytes) -> list[tuple[int, int]]:
    """Camera sizes of a ``cameras.bin`` (u64 n; n × {u32 id, i32 model, u64 width, u64 height, f64 params})."""
    from core.io.colmap_scan import CAMERA_MODELS

    (n,) = struct.unpack_from("<Q", data, 0)
    pos, sizes = 8, []
    for _ in range(min(n, len(data) // 24)):
        _, model, width, height = struct.unpack_from("<IiQQ", data, pos)
        pos += 24 + 8 * CAMERA_MODELS[model][1]
        sizes.append((int(width), int(height)))
    return sizes


def model_count(model: str | PathLike[str], what: str) -> int:
    """How many ``what`` (``"images"`` or ``"points3D"``) the COLMAP model folder ``model`` declares: the count at
    the head of the binary file, or the records of the text file; 0 when there is none."""
    folder = Path(model)
    try:
        binary, text = folder / f"{what}.bin", folder / f"{what}.txt"
        if binary.is_file():
            with binary.open("rb") as f:
                head = f.read(8)
            return int.from_bytes(head, "little") if len(head) == 8 else 0
        if text.is_file():
            records = [s for s in text.read_text(encoding="utf-8").splitlines() if not s.startswith("#")]
            return (len(records) + 1) // 2 if what == "images" else len([s for s in records if s.strip()])
    except OSError:
        return 0
    return 0


def photo_sizes(folder: str | PathLike[str], names: Iterable[str]) -> list[tuple[int, int]]:
    """(width, height) in pixels of the photos ``names`` in ``folder``, from their headers (Pillow reads no pixel
    data); unreadable photos are left out."""
    from PIL import Image

    sizes = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a decompression-bomb warning: the size is all that is wanted
        for name in names:
            try:
                with Image.open(Path(folder) / name) as image:
                    sizes.append((int(image.width), int(image.height)))
            except (OSError, ValueError, Image.DecompressionBombError):
                continue
    return sizes


def snapshot_count(steps: Iterable[int], iterations: int) -> int:
    """How many distinct ``steps`` fall within a run of ``iterations`` steps (1 .. iterations)."""
    return len({int(s) for s in steps if 1 <= int(s) <= iterations})


def can_densify(strategy: Any, iterations: int) -> bool:
    """Whether a densification strategy (``refine_start``, ``refine_stop``, ``refine_every``) refines at all within
    ``iterations`` steps: when it does not, the trainer never holds more Gaussians than it started with."""
    every = max(int(strategy.refine_every), 1)
    first = -(-max(int(strategy.refine_start), 1) // every) * every
    return first <= iterations and first < int(strategy.refine_stop)
