"""A pre-scan of COLMAP sparse model files, before they are handed to pycolmap.

pycolmap's readers trust the counts they read: a truncated ``points3D.bin`` of a few kilobytes made it run
for minutes and allocate tens of gigabytes, a truncated ``cameras.bin`` gave a PINHOLE camera with all
parameters 0 (renders black, exit 0). This module walks every record of the binary files (and parses the
text files line by line) and checks each declared count against the bytes that remain, every id against
the ids defined, and every number for finiteness — in Python, with nothing allocated from an unchecked
count. Written by hand because no library validates these files; the layouts are COLMAP's
(``src/colmap/scene/reconstruction_io_binary.cc``), pycolmap 4.x:

- ``cameras.bin``: u64 n; n × {u32 id, i32 model, u64 width, u64 height, f64 params[model]}
- ``images.bin``: u64 n; n × {u32 id, f64 qvec[4], f64 tvec[3], u32 camera_id, char name[] NUL,
  u64 m, m × {f64 x, f64 y, u64 point3D_id}}
- ``points3D.bin``: u64 n; n × {u64 id, f64 xyz[3], u8 rgb[3], f64 error, u64 t, t × {u32 image_id, u32 idx}}
- ``rigs.bin``: u64 n; n × {u32 id, u32 s, i32 ref_type, u32 ref_id, (s-1) × {i32 type, u32 id, u8 has_pose,
  [f64 q[4], f64 t[3]]}}
- ``frames.bin``: u64 n; n × {u32 id, u32 rig_id, f64 q[4], f64 t[3], u32 d, d × {i32 type, u32 id, u64 data_id}}
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from core.errors import FormatError, InputFileError

#: COLMAP camera model id -> (name, number of parameters).
CAMERA_MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
_MODEL_PARAMS_BY_NAME = {name: n for name, n in CAMERA_MODELS.values()}
#: The largest image side accepted (pixels); larger values are corrupt headers, not cameras.
MAX_IMAGE_SIDE = 1 << 20
_MAX_NAME = 4096


@dataclass(frozen=True)
class ModelSummary:
    """What the pre-scan found: counts per file (they match what pycolmap will read)."""

    cameras: int
    images: int
    points: int
    observations: int


class _Reader:
    """Bounds-checked little-endian reads over one file's bytes; every failure names the file and record."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = memoryview(path.read_bytes())
        self.pos = 0
        self.where = "the header"

    @property
    def left(self) -> int:
        return len(self.data) - self.pos

    def fail(self, problem: str) -> None:
        raise FormatError(f"{problem} (in {self.where}, byte {self.pos} of {len(self.data)})", self.path)

    def take(self, fmt: str) -> tuple:
        size = struct.calcsize(fmt)
        if size > self.left:
            self.fail(f"file is truncated: {size} more bytes needed, {self.left} left")
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return out

    def count(self, what: str, min_record: int) -> int:
        """A u64 count whose records (at least ``min_record`` bytes each) must fit in the rest of the file."""
        (n,) = self.take("<Q")
        if n * min_record > self.left:
            self.fail(f"declares {n} {what} but only {self.left} bytes follow (at least {n * min_record} needed)")
        return n

    def finite(self, values: tuple, what: str) -> None:
        if not all(math.isfinite(v) for v in values):
            self.fail(f"{what} holds NaN or infinite values [{', '.join(f'{v:.6g}' for v in values)}]")

    def cstring(self) -> str:
        end = bytes(self.data[self.pos : self.pos + _MAX_NAME]).find(b"\0")
        if end < 0:
            self.fail("image name is not terminated (file truncated or corrupt)")
        raw = bytes(self.data[self.pos : self.pos + end])
        self.pos += end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            self.fail("image name is not UTF-8 text")
            raise  # unreachable

    def done(self) -> None:
        if self.left:
            self.fail(f"{self.left} unexpected bytes after the last record")


def _scan_cameras_bin(path: Path) -> set[int]:
    r = _Reader(path)
    n = r.count("cameras", 24 + 3 * 8)
    ids: set[int] = set()
    for i in range(n):
        r.where = f"camera record {i}"
        cam_id, model_id, width, height = r.take("<IiQQ")
        if model_id not in CAMERA_MODELS:
            r.fail(f"camera {cam_id} has unknown model id {model_id}")
        name, n_params = CAMERA_MODELS[model_id]
        if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
            r.fail(f"camera {cam_id} ({name}) has size {width}x{height}")
        params = r.take(f"<{n_params}d")
        r.finite(params, f"camera {cam_id} parameters")
        if params[0] <= 0 or (name in ("PINHOLE", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE") and params[1] <= 0):
            r.fail(f"camera {cam_id} ({name}) has a non-positive focal length in {list(params)}")
        if cam_id in ids:
            r.fail(f"camera id {cam_id} appears twice")
        ids.add(cam_id)
    r.where = "the end"
    r.done()
    return ids


def _scan_images_bin(path: Path, camera_ids: set[int]) -> tuple[set[int], int]:
    r = _Reader(path)
    n = r.count("images", 4 + 56 + 4 + 1 + 8)
    ids: set[int] = set()
    observations = 0
    for i in range(n):
        r.where = f"image record {i}"
        (image_id,) = r.take("<I")
        pose = r.take("<7d")
        r.finite(pose, f"image {image_id} pose")
        if not any(pose[:4]):
            r.fail(f"image {image_id} has a zero rotation quaternion")
        (cam_id,) = r.take("<I")
        if camera_ids and cam_id not in camera_ids:
            r.fail(f"image {image_id} refers to camera {cam_id}, which cameras.bin does not define")
        name = r.cstring()
        if not name:
            r.fail(f"image {image_id} has an empty name")
        m = r.count(f"2D points of image {image_id}", 24)
        r.pos += 24 * m  # x, y are not checked: pycolmap reads them as they are
        observations += m
        if image_id in ids:
            r.fail(f"image id {image_id} appears twice")
        ids.add(image_id)
    r.where = "the end"
    r.done()
    return ids, observations


def _scan_points_bin(path: Path, image_ids: set[int]) -> int:
    r = _Reader(path)
    n = r.count("points", 8 + 24 + 3 + 8 + 8)
    for i in range(n):
        r.where = f"point record {i}"
        point_id, x, y, z, _r, _g, _b, err = r.take("<Q3d3Bd")
        r.finite((x, y, z), f"point {point_id} position")
        t = r.count(f"track elements of point {point_id}", 8)
        if image_ids and t:
            track = struct.unpack_from(f"<{2 * t}I", r.data, r.pos)
            unknown = set(track[0::2]) - image_ids
            if unknown:
                r.fail(f"point {point_id} is seen by image {min(unknown)}, which images.bin does not define")
        r.pos += 8 * t
    r.where = "the end"
    r.done()
    return n


def _scan_rigs_bin(path: Path) -> None:
    r = _Reader(path)
    n = r.count("rigs", 16)
    for i in range(n):
        r.where = f"rig record {i}"
        _rig_id, n_sensors, _t, _s = r.take("<IIiI")
        if n_sensors == 0 or (n_sensors - 1) * 9 > r.left:
            r.fail(f"rig declares {n_sensors} sensors")
        for _ in range(n_sensors - 1):
            _t, _s, has_pose = r.take("<iIB")
            if has_pose:
                r.finite(r.take("<7d"), "sensor pose")
    r.where = "the end"
    r.done()


def _scan_frames_bin(path: Path) -> None:
    r = _Reader(path)
    n = r.count("frames", 8 + 56 + 4)
    for i in range(n):
        r.where = f"frame record {i}"
        r.take("<II")
        r.finite(r.take("<7d"), "frame pose")
        (d,) = r.take("<I")
        if 16 * d > r.left:
            r.fail(f"frame declares {d} data ids but only {r.left} bytes follow")
        r.pos += 16 * d
    r.where = "the end"
    r.done()


def _text_lines(path: Path) -> list[tuple[int, list[str]]]:
    """(line number, tokens) of the non-comment, non-blank lines of a COLMAP text file."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise FormatError(f"not UTF-8 text (byte {err.start})", path) from err
    out = []
    for no, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.append((no, s.split()))
    return out


def _numbers(tokens: list[str], path: Path, no: int, kind: type = float) -> list:
    try:
        values = [kind(t) for t in tokens]
    except ValueError as err:
        raise FormatError(f"line {no}: {err}", path) from err
    if kind is float and not all(math.isfinite(v) for v in values):
        raise FormatError(f"line {no}: NaN or infinite value", path)
    return values


def _scan_cameras_txt(path: Path) -> set[int]:
    ids: set[int] = set()
    for no, tok in _text_lines(path):
        if len(tok) < 4:
            raise FormatError(f"line {no}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got {len(tok)} values", path)
        cam_id, width, height = _numbers([tok[0], tok[2], tok[3]], path, no, int)
        model = tok[1]
        if model not in _MODEL_PARAMS_BY_NAME:
            raise FormatError(f"line {no}: unknown camera model {model!r}", path)
        want = _MODEL_PARAMS_BY_NAME[model]
        if len(tok) - 4 != want:
            raise FormatError(f"line {no}: camera model {model} takes {want} parameters, found {len(tok) - 4}", path)
        params = _numbers(tok[4:], path, no)
        if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE) or params[0] <= 0:
            raise FormatError(f"line {no}: camera {cam_id} has size {width}x{height}, parameters {params}", path)
        ids.add(cam_id)
    return ids


def _scan_images_txt(path: Path, camera_ids: set[int]) -> tuple[set[int], int]:
    lines = _text_lines_keep_blank_pairs(path)
    ids: set[int] = set()
    observations = 0
    for k in range(0, len(lines), 2):
        no, tok = lines[k]
        if len(tok) < 10:
            raise FormatError(f"line {no}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", path)
        image_id, cam_id = _numbers([tok[0], tok[8]], path, no, int)
        pose = _numbers(tok[1:8], path, no)
        if not any(pose[:4]):
            raise FormatError(f"line {no}: image {image_id} has a zero rotation quaternion", path)
        if camera_ids and cam_id not in camera_ids:
            raise FormatError(f"line {no}: image {image_id} refers to undefined camera {cam_id}", path)
        if k + 1 >= len(lines):
            raise FormatError(f"line {no}: image {image_id} lacks its line of 2D points (file truncated?)", path)
        no2, pts = lines[k + 1]
        if len(pts) % 3:
            raise FormatError(f"line {no2}: 2D points come in triples X Y POINT3D_ID, found {len(pts)} values", path)
        _numbers(pts[0::3] + pts[1::3], path, no2)
        observations += len(pts) // 3
        ids.add(image_id)
    return ids, observations


def _text_lines_keep_blank_pairs(path: Path) -> list[tuple[int, list[str]]]:
    """images.txt: two lines per image, the second may be empty (no 2D points); comments dropped."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise FormatError(f"not UTF-8 text (byte {err.start})", path) from err
    out = [(no, line.split()) for no, line in enumerate(text.splitlines(), 1) if not line.startswith("#")]
    while out and not out[-1][1]:  # trailing blank lines
        out.pop()
    if len(out) % 2:  # an image without a (blank) points line at the very end
        out.append((len(text.splitlines()) + 1, []))
    return out


def _scan_points_txt(path: Path, image_ids: set[int]) -> int:
    n = 0
    for no, tok in _text_lines(path):
        if len(tok) < 8 or (len(tok) - 8) % 2:
            raise FormatError(
                f"line {no}: expected POINT3D_ID X Y Z R G B ERROR TRACK[] (pairs), got {len(tok)} values", path
            )
        _numbers(tok[1:4] + [tok[7]], path, no)
        track = _numbers(tok[8:], path, no, int)
        if image_ids and set(track[0::2]) - image_ids:
            raise FormatError(f"line {no}: track refers to an image that images.txt does not define", path)
        n += 1
    return n


def scan_model(path: str | PathLike[str]) -> ModelSummary:
    """Check a COLMAP sparse model folder (``.bin`` preferred, else ``.txt``) before pycolmap reads it.

    Raises :class:`InputFileError` when the folder or a file is missing and :class:`FormatError` naming the
    offending file (``cameras.bin``, not only its folder), the record and the problem: truncation, a count
    larger than the file can hold, trailing bytes, unknown camera models, non-finite numbers, references to
    undefined cameras or images. Reads each file once; memory is the file size.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise InputFileError("COLMAP model folder does not exist" if not folder.exists() else "is not a folder", folder)
    names = ("cameras", "images", "points3D")
    for ext in (".bin", ".txt"):
        files = [folder / f"{n}{ext}" for n in names]
        if all(f.exists() for f in files):
            break
    else:
        raise InputFileError("not a COLMAP model: needs cameras, images and points3D as .bin or .txt", folder)
    for f in files:
        if not f.is_file():
            raise InputFileError("is a folder, expected a COLMAP model file", f)
    cams_f, imgs_f, pts_f = files
    if ext == ".bin":
        cam_ids = _scan_cameras_bin(cams_f)
        img_ids, obs = _scan_images_bin(imgs_f, cam_ids)
        n_pts = _scan_points_bin(pts_f, img_ids)
        for extra, scan in (("rigs.bin", _scan_rigs_bin), ("frames.bin", _scan_frames_bin)):
            if (folder / extra).is_file():
                scan(folder / extra)
    else:
        cam_ids = _scan_cameras_txt(cams_f)
        img_ids, obs = _scan_images_txt(imgs_f, cam_ids)
        n_pts = _scan_points_txt(pts_f, img_ids)
    return ModelSummary(len(cam_ids), len(img_ids), n_pts, obs)
