"""Full-reference image metrics: MSE, PSNR, SSIM, MS-SSIM and ΔE (CIEDE2000), whole image and masked.

Images are (H, W, 3) RGB, either uint8 (0–255) or float in [0, 1]; every metric works on colours in
[0, 1] (data range 1). Masks are (H, W) bool, True where a pixel counts (e.g. the non-collaborative region).

- MSE: mean over pixels and channels of the squared colour difference (colours in [0, 1]).
- PSNR: 10·log10(1 / MSE) dB, clamped at :data:`PSNR_MAX` for identical images.
- SSIM: Wang et al. 2004 with an 11×11 Gaussian window (σ = 1.5), K1 = 0.01, K2 = 0.03, population
  statistics, mean over the "valid" region (the window fully inside the image) and over channels; this is
  scikit-image's ``structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
  data_range=1, channel_axis=-1)``.
- MS-SSIM: Wang et al. 2003, 5 scales with weights (0.0448, 0.2856, 0.3001, 0.2363, 0.1333), 2×2 average
  pooling between scales (odd sizes replicate their last row/column), contrast-structure terms at every
  scale and luminance at the coarsest, each clamped at 0 (as pytorch-msssim does) so fractional powers stay
  real; computed per colour channel and averaged over channels (as TensorFlow and pytorch-msssim do).
  Images too small for 5 scales (the window must fit at the coarsest) use as many scales as fit, weights
  rescaled to the published sum (1.0001).
- ΔE: mean CIEDE2000 difference between the images in CIE L*a*b* (D65), via scikit-image.

Masked variants average the per-pixel maps over the mask (for SSIM the map is the valid region, for
MS-SSIM the mask is average-pooled with the images and used as weights at every scale).
SSIM / MS-SSIM use float64 separable Gaussian filtering (scipy.ndimage).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import correlate1d
from skimage.color import deltaE_ciede2000, rgb2lab

from core.errors import DataError

PSNR_MAX = 100.0  # dB; the PSNR of images whose MSE is below 1e-10
MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
WINDOW = 11
SIGMA = 1.5
K1, K2 = 0.01, 0.03
IMAGE_METRIC_NAMES = ("mse", "psnr", "ssim", "ms_ssim", "lpips", "delta_e")


@dataclass(frozen=True)
class ImageScores:
    """Metrics of one image pair (or their mean over views). LPIPS is None when not computed."""

    mse: float
    psnr: float
    ssim: float
    ms_ssim: float
    delta_e: float
    lpips: float | None = None

    def as_dict(self) -> dict[str, float | None]:
        return {k: getattr(self, k) for k in IMAGE_METRIC_NAMES}


def to_float_image(image: np.ndarray, name: str = "image") -> np.ndarray:
    """(H, W, 3) float64 in [0, 1] from uint8 (0–255) or float input; grey (H, W) is repeated to RGB."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise DataError(f"{name} must have shape (H, W, 3), got {a.shape}")
    a = a[..., :3]
    if a.dtype == np.uint8:
        return a.astype(np.float64) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float64) / 65535.0
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise DataError(f"{name} contains NaN or infinite values")
    return np.clip(a, 0.0, 1.0)


def _pair(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    x, y = to_float_image(a, "first image"), to_float_image(b, "second image")
    if x.shape != y.shape:
        raise DataError(f"images differ in size: {x.shape[:2]} vs {y.shape[:2]}")
    if mask is not None:
        mask = np.asarray(mask).astype(bool)
        if mask.shape != x.shape[:2]:
            raise DataError(f"mask has shape {mask.shape} but the images are {x.shape[:2]}")
    return x, y, mask


def _masked_mean(values: np.ndarray, mask: np.ndarray | None) -> float:
    if mask is None:
        return float(values.mean())
    if not mask.any():
        return 0.0
    return float(values[mask].mean())


def mse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean squared error of colours in [0, 1], over the whole image or the masked pixels (0 if mask empty)."""
    x, y, m = _pair(a, b, mask)
    return _masked_mean(((x - y) ** 2).mean(axis=2), m)


def psnr_from_mse(value: float) -> float:
    """PSNR in dB for data range 1, clamped at :data:`PSNR_MAX`."""
    return float(min(10.0 * np.log10(1.0 / max(value, 1e-10)), PSNR_MAX))


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Peak signal-to-noise ratio in dB (data range 1), whole image or masked."""
    return psnr_from_mse(mse(a, b, mask))


def _gaussian_taps() -> np.ndarray:
    # scikit-image truncates its Gaussian at 3.5 σ: radius int(3.5 * 1.5 + 0.5) = 5, i.e. the 11-tap window.
    r = WINDOW // 2
    t = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-(t**2) / (2 * SIGMA**2))
    return g / g.sum()


_TAPS = _gaussian_taps()


def _blur_valid(t: np.ndarray) -> np.ndarray:
    """Separable Gaussian filter of (H, W, C) float64, keeping only the valid region (H-10, W-10, C)."""
    r = WINDOW // 2
    out = correlate1d(correlate1d(t, _TAPS, axis=0, mode="constant"), _TAPS, axis=1, mode="constant")
    return out[r:-r, r:-r]


def _ssim_maps(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SSIM and contrast-structure maps (h, w, C) over the valid region of (H, W, C) float64 images."""
    mu_x, mu_y = _blur_valid(x), _blur_valid(y)
    sxx = _blur_valid(x * x) - mu_x**2
    syy = _blur_valid(y * y) - mu_y**2
    sxy = _blur_valid(x * y) - mu_x * mu_y
    c1, c2 = K1**2, K2**2
    cs = (2 * sxy + c2) / (sxx + syy + c2)
    lum = (2 * mu_x * mu_y + c1) / (mu_x**2 + mu_y**2 + c1)
    return lum * cs, cs


def _channel_means(values: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """(C,) per-channel means of (h, w, C) values, weighted per pixel by (h, w) weights when given."""
    if weights is None:
        return values.mean(axis=(0, 1))
    total = float(weights.sum())
    if total <= 0:
        return np.zeros(values.shape[2])
    return np.einsum("hwc,hw->c", values, weights) / total


def _crop(weights: np.ndarray | None) -> np.ndarray | None:
    r = WINDOW // 2
    return None if weights is None else weights[r:-r, r:-r]


def _halve(t: np.ndarray) -> np.ndarray:
    """2×2 average pooling of (H, W, ...) arrays; an odd last row/column is replicated first."""
    if t.shape[0] % 2:
        t = np.concatenate([t, t[-1:]], axis=0)
    if t.shape[1] % 2:
        t = np.concatenate([t, t[:, -1:]], axis=1)
    return 0.25 * (t[0::2, 0::2] + t[1::2, 0::2] + t[0::2, 1::2] + t[1::2, 1::2])


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Structural similarity (Gaussian window, see module doc), whole image or averaged over the mask."""
    x, y, m = _pair(a, b, mask)
    if min(x.shape[:2]) < WINDOW:
        raise DataError(f"SSIM needs images of at least {WINDOW}×{WINDOW} pixels, got {x.shape[1]}×{x.shape[0]}")
    s, _ = _ssim_maps(x, y)
    return float(_channel_means(s, _crop(None if m is None else m.astype(np.float64))).mean())


def ms_ssim_scales(height: int, width: int, max_scales: int = len(MS_SSIM_WEIGHTS)) -> int:
    """How many MS-SSIM scales fit an image: the window must fit inside the coarsest scale."""
    scales, h, w = 0, height, width
    while scales < max_scales and min(h, w) >= WINDOW:
        scales += 1
        h, w = (h + 1) // 2, (w + 1) // 2
    return scales


def ms_ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Multi-scale SSIM (Wang 2003; see module doc), whole image or mask-weighted at every scale."""
    x, y, m = _pair(a, b, mask)
    scales = ms_ssim_scales(*x.shape[:2])
    if scales == 0:
        raise DataError(f"MS-SSIM needs images of at least {WINDOW}×{WINDOW} pixels, got {x.shape[1]}×{x.shape[0]}")
    # The published weights sum to 1.0001; keep them as they are (as every reference implementation does)
    # and rescale to that sum when fewer scales fit.
    weights = np.asarray(MS_SSIM_WEIGHTS[:scales], dtype=np.float64)
    weights = weights * (sum(MS_SSIM_WEIGHTS) / weights.sum())
    wm = None if m is None else m.astype(np.float64)
    values = []
    for level in range(scales):
        s, cs = _ssim_maps(x, y)
        term = s if level == scales - 1 else cs
        values.append(np.maximum(_channel_means(term, _crop(wm)), 0.0))
        if level < scales - 1:
            x, y = _halve(x), _halve(y)
            wm = None if wm is None else _halve(wm)
    v = np.stack(values)  # (scales, C)
    return float(np.prod(v ** weights[:, None], axis=0).mean())


def delta_e_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) float64 CIEDE2000 colour difference per pixel (sRGB -> CIE L*a*b*, D65, via scikit-image)."""
    x, y, _ = _pair(a, b, None)
    return deltaE_ciede2000(rgb2lab(x), rgb2lab(y), channel_axis=-1)


def delta_e(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean CIEDE2000 ΔE over the whole image or the masked pixels (0 for an empty mask)."""
    x, y, m = _pair(a, b, mask)
    return _masked_mean(delta_e_map(x, y), m)


def error_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) float64 per-pixel RMS colour error in [0, 1] (for error-map previews)."""
    x, y, _ = _pair(a, b, None)
    return np.sqrt(((x - y) ** 2).mean(axis=2))


def image_scores(
    rendered: np.ndarray, photo: np.ndarray, mask: np.ndarray | None = None, lpips_model: object | None = None
) -> ImageScores:
    """Every metric for one pair, whole image (``mask`` None) or masked. ``lpips_model`` is an
    :class:`eval.lpips.LPIPS` (optional; LPIPS is None without one)."""
    x, y, m = _pair(rendered, photo, mask)
    value = mse(x, y, m)
    lp = None
    if lpips_model is not None:
        lp = float(lpips_model.distance(x, y, mask=m))  # type: ignore[attr-defined]
    return ImageScores(
        mse=value,
        psnr=psnr_from_mse(value),
        ssim=ssim(x, y, m),
        ms_ssim=ms_ssim(x, y, m),
        delta_e=delta_e(x, y, m),
        lpips=lp,
    )


@dataclass(frozen=True)
class ScoreSummary:
    """Mean and population standard deviation of per-view scores over ``views`` views."""

    views: int
    mean: ImageScores
    std: ImageScores

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"views": self.views, **self.mean.as_dict()}
        out["std"] = self.std.as_dict()
        return out


def summarize(scores: list[ImageScores]) -> ScoreSummary | None:
    """Aggregate per-view scores (mean, std; LPIPS only when every view has it). None for no views."""
    if not scores:
        return None
    names = ("mse", "psnr", "ssim", "ms_ssim", "delta_e", "lpips")
    mean: dict[str, float | None] = {}
    std: dict[str, float | None] = {}
    for name in names:
        vals = [getattr(s, name) for s in scores]
        if any(v is None for v in vals):
            mean[name] = std[name] = None
            continue
        arr = np.asarray(vals, dtype=np.float64)
        mean[name], std[name] = float(arr.mean()), float(arr.std())
    return ScoreSummary(len(scores), ImageScores(**mean), ImageScores(**std))  # type: ignore[arg-type]
