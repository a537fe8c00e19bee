"""Image files (PNG, JPEG, TIFF …) through OpenCV, as RGB uint8 arrays."""

from __future__ import annotations

import contextlib
from os import PathLike
from pathlib import Path

import cv2
import numpy as np

from core.errors import DataError, InputFileError
from core.io.atomic import atomic_path

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
#: Largest image accepted, in pixels (a corrupt header must not make the decoder allocate gigabytes).
MAX_PIXELS = 400_000_000

# OpenCV logs decoder complaints on stderr; the errors raised below say the same in one line.
with contextlib.suppress(AttributeError):
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"


def _check_structure(data: np.ndarray, path: Path) -> None:
    """Catch truncated PNG and JPEG files, which decoders may return half-grey without an error."""
    head = data[:8].tobytes()
    if head == _PNG_MAGIC:
        if data[-8:].tobytes() != _PNG_END:
            raise InputFileError("PNG file is truncated (no IEND chunk at the end)", path)
        if len(data) >= 24:
            width, height = (int.from_bytes(data[i : i + 4].tobytes(), "big") for i in (16, 20))
            if width * height > MAX_PIXELS:
                raise InputFileError(f"PNG header declares {width}x{height} pixels (corrupt?)", path)
    elif head[:3] == b"\xff\xd8\xff" and b"\xff\xd9" not in data[-1024:].tobytes():
        raise InputFileError("JPEG file is truncated (no end-of-image marker)", path)


def read_image(path: str | PathLike[str], *, grayscale: bool = False) -> np.ndarray:
    """Read an image as (H, W, 3) RGB uint8 (or (H, W) with ``grayscale``); 16-bit images are scaled to 8 bits.

    Raises :class:`InputFileError` for missing, empty or undecodable files.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError("image does not exist" if not path.exists() else "is not a file", path)
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise InputFileError("image file is empty", path)
    _check_structure(data, path)
    flags = cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_COLOR
    image = cv2.imdecode(data, flags | cv2.IMREAD_ANYDEPTH)
    if image is None:
        raise InputFileError("image cannot be decoded (corrupt or unsupported format)", path)
    if image.dtype == np.uint16:
        image = np.round(image / 257.0).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise InputFileError(f"unsupported image depth {image.dtype}", path)
    return image if grayscale else cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def write_image(path: str | PathLike[str], image: np.ndarray) -> Path:
    """Write (H, W, 3) RGB or (H, W) grey uint8 (floats in [0, 1] are converted) atomically; format from suffix."""
    path = Path(path)
    img = np.asarray(image)
    if np.issubdtype(img.dtype, np.floating):
        if not np.isfinite(img).all():
            raise DataError("image contains NaN or infinite values", path)
        img = np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    ok, encoded = cv2.imencode(path.suffix or ".png", img)
    if not ok:
        raise DataError(f"cannot encode image as {path.suffix}", path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(encoded.tobytes())
    return path
