"""LPIPS v0.1 (Zhang et al. 2018) with the AlexNet backbone, computed in-project in torch.

torchvision does not import beside the CPU build of torch here, so the network is rebuilt from its
definition: AlexNet ``features`` up to relu5 (conv 11/4 → relu → maxpool → conv 5 → relu → maxpool →
conv 3 → relu → conv 3 → relu → conv 3 → relu), the LPIPS input scaling, channel-wise unit
normalisation of the five relu outputs, squared differences, the learned 1×1 linear heads, spatial mean,
and the sum over layers. Weights come from a local ``.npz`` file (see :func:`find_weights`); nothing
is ever downloaded.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from core.errors import ConfigError, DataError, FormatError, InputFileError

if TYPE_CHECKING:
    import torch

# torch is imported inside the functions that compute: finding and checking the weights (find_weights,
# read_weights) needs numpy only, so a bad weights file is reported before torch is loaded.

ENV_VAR = "HYBRIDSPLAT_LPIPS_WEIGHTS"
WEIGHTS_NAME = "alexnet_lpips_v0.1.npz"
# LPIPS ScalingLayer: inputs in [-1, 1] are shifted and scaled to ImageNet statistics.
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
# (conv key, stride, padding, max-pool before this conv)
_CONVS = (("features.0", 4, 2, False), ("features.3", 1, 2, True), ("features.6", 1, 1, True),
          ("features.8", 1, 1, False), ("features.10", 1, 1, False))  # fmt: skip
_CHANNELS = (64, 192, 384, 256, 256)
#: Largest uncompressed archive accepted (bytes); the AlexNet LPIPS weights take ~10 MB.
MAX_WEIGHTS_BYTES = 256 * 1024**2


def default_weight_paths() -> list[Path]:
    """Where :func:`find_weights` looks when neither a path nor the environment variable is given."""
    repo = Path(__file__).resolve().parents[1]
    return [repo.parent / "shared" / "data" / "lpips" / WEIGHTS_NAME, repo / "weights" / WEIGHTS_NAME]


def find_weights(path: str | PathLike[str] | None = None) -> Path:
    """The weights file: ``path`` (e.g. the config key ``eval.lpips_weights``), else ``$HYBRIDSPLAT_LPIPS_WEIGHTS``,
    else the first existing :func:`default_weight_paths`. Raises :class:`ConfigError` when none exists."""
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise InputFileError("LPIPS weights file not found", p)
        return p
    env = os.environ.get(ENV_VAR)
    if env:
        p = Path(env)
        if not p.is_file():
            raise InputFileError(f"LPIPS weights file named by ${ENV_VAR} not found", p)
        return p
    for p in default_weight_paths():
        if p.is_file():
            return p
    raise ConfigError(
        f"no LPIPS weights: set ${ENV_VAR} or the config key eval.lpips_weights to a {WEIGHTS_NAME} file "
        f"(looked in {', '.join(str(p) for p in default_weight_paths())})"
    )


def load_weights(path: str | PathLike[str]) -> dict[str, torch.Tensor]:
    """Read and check the ``.npz`` weights (torch layouts, float32) as torch tensors (see :func:`read_weights`)."""
    import torch

    return {k: torch.from_numpy(v) for k, v in read_weights(path).items()}


def read_weights(path: str | PathLike[str]) -> dict[str, np.ndarray]:
    """Read and check the ``.npz`` weights without torch: float32 arrays in torch layouts, keyed as in the file.

    Raises :class:`InputFileError` (missing, empty, a folder) or :class:`FormatError` (not an archive, too
    large, unreadable, NaN/inf, missing or mis-shaped layers)."""
    p = Path(path)
    if p.is_dir():
        raise InputFileError("is a folder, expected an LPIPS weights file (.npz)", p)
    if not p.is_file():
        raise InputFileError("LPIPS weights file not found", p)
    if p.stat().st_size == 0:
        raise InputFileError("LPIPS weights file is empty", p)
    if not zipfile.is_zipfile(p):
        raise FormatError("not an .npz archive (no zip directory: truncated or another format)", p)
    try:
        with zipfile.ZipFile(p) as archive:
            declared = sum(info.file_size for info in archive.infolist())
        if declared > MAX_WEIGHTS_BYTES:
            raise FormatError(f"archive declares {declared} bytes of arrays; LPIPS AlexNet needs ~10 MB", p)
        with np.load(p, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                raise FormatError("expected an .npz archive of named arrays, found a single array", p)
            arrays = {k: np.asarray(data[k], dtype=np.float32) for k in data.files}
    except FormatError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, TypeError) as err:
        text = " ".join(str(err).split())[:120]
        raise FormatError(f"cannot read LPIPS weights ({type(err).__name__}: {text})", p) from err
    for key, value in arrays.items():
        if not np.isfinite(value).all():
            raise FormatError(f"LPIPS weights {key} hold NaN or infinite values", p)
    expected_in = 3
    for (key, *_), ch in zip(_CONVS, _CHANNELS, strict=True):
        for suffix in ("weight", "bias"):
            if f"{key}.{suffix}" not in arrays:
                raise FormatError(f"LPIPS weights lack {key}.{suffix}", p)
        w = arrays[f"{key}.weight"]
        if w.ndim != 4 or w.shape[0] != ch or w.shape[1] != expected_in:
            raise FormatError(f"{key}.weight has shape {tuple(w.shape)}, expected ({ch}, {expected_in}, k, k)", p)
        if tuple(arrays[f"{key}.bias"].shape) != (ch,):
            raise FormatError(f"{key}.bias has shape {tuple(arrays[f'{key}.bias'].shape)}, expected ({ch},)", p)
        expected_in = ch
    for i, ch in enumerate(_CHANNELS):
        key = f"lin{i}.model.1.weight"
        if key not in arrays or tuple(arrays[key].shape) != (1, ch, 1, 1):
            raise FormatError(f"LPIPS weights lack {key} of shape (1, {ch}, 1, 1)", p)
    return arrays


class LPIPS:
    """LPIPS v0.1 / AlexNet distance. Build with :meth:`from_path` (or :meth:`default`)."""

    def __init__(
        self, weights: dict[str, torch.Tensor] | dict[str, np.ndarray], device: str | torch.device = "cpu"
    ) -> None:
        """``weights``: as :func:`load_weights` (torch tensors) or :func:`read_weights` (numpy arrays) returns."""
        import torch

        self.device = torch.device(device)
        self.w = {k: torch.as_tensor(v).to(self.device) for k, v in weights.items()}
        self.shift = torch.tensor(_SHIFT, device=self.device).view(1, 3, 1, 1)
        self.scale = torch.tensor(_SCALE, device=self.device).view(1, 3, 1, 1)

    @classmethod
    def from_path(cls, path: str | PathLike[str] | None = None, device: str | torch.device = "cpu") -> LPIPS:
        """Load weights from ``path`` or the search of :func:`find_weights`."""
        return cls(load_weights(find_weights(path)), device)

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five relu outputs for (B, 3, H, W) float32 input in [-1, 1]."""
        import torch.nn.functional as F

        h = (x - self.shift) / self.scale
        out = []
        for key, stride, pad, pool in _CONVS:
            if pool:
                h = F.max_pool2d(h, kernel_size=3, stride=2)
            h = F.relu(F.conv2d(h, self.w[f"{key}.weight"], self.w[f"{key}.bias"], stride=stride, padding=pad))
            out.append(h)
        return out

    def forward(self, x: torch.Tensor, y: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) distances for (B, 3, H, W) inputs in [-1, 1]; ``mask`` (B, 1, H, W) in [0, 1] weights the
        spatial means (area-resized to each layer). Differentiable."""
        import torch
        import torch.nn.functional as F

        total = torch.zeros(x.shape[0], device=x.device, dtype=x.dtype)
        for i, (fx, fy) in enumerate(zip(self.features(x), self.features(y), strict=True)):
            nx = fx / (torch.sqrt((fx * fx).sum(dim=1, keepdim=True)) + 1e-10)
            ny = fy / (torch.sqrt((fy * fy).sum(dim=1, keepdim=True)) + 1e-10)
            layer = F.conv2d((nx - ny) ** 2, self.w[f"lin{i}.model.1.weight"])  # (B, 1, h, w)
            if mask is None:
                total = total + layer.mean(dim=(1, 2, 3))
            else:
                m = F.interpolate(mask.to(layer.dtype), size=layer.shape[2:], mode="area")
                wsum = m.sum(dim=(1, 2, 3)).clamp_min(1e-12)
                total = total + (layer * m).sum(dim=(1, 2, 3)) / wsum
        return total

    __call__ = forward

    def distance(self, a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
        """LPIPS between two (H, W, 3) images (uint8 or float in [0, 1]); ``mask`` (H, W) bool restricts the
        spatial averages to the masked region (0 for an empty mask)."""
        import torch

        from eval.image_metrics import to_float_image

        x, y = to_float_image(a, "first image"), to_float_image(b, "second image")
        if x.shape != y.shape:
            raise DataError(f"images differ in size: {x.shape[:2]} vs {y.shape[:2]}")
        if min(x.shape[:2]) < 32:
            raise DataError(f"LPIPS needs images of at least 32×32 pixels, got {x.shape[1]}×{x.shape[0]}")
        tm = None
        if mask is not None:
            mk = np.asarray(mask).astype(bool)
            if mk.shape != x.shape[:2]:
                raise DataError(f"mask has shape {mk.shape} but the images are {x.shape[:2]}")
            if not mk.any():
                return 0.0
            tm = torch.from_numpy(mk.astype(np.float32))[None, None].to(self.device)
        with torch.no_grad():
            tx, ty = (_to_tensor(v, self.device) for v in (x, y))
            return float(self.forward(tx, ty, tm)[0])


def _to_tensor(img: np.ndarray, device: torch.device) -> torch.Tensor:
    import torch

    t = torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1), dtype=np.float32))[None]
    return (t * 2.0 - 1.0).to(device)
