"""Image metrics against independent references on real photographs.

References: scikit-image (PSNR, SSIM maps), a straightforward numpy/scipy MS-SSIM written here from
Wang et al. 2003, pytorch-msssim when installed, and Sharma et al. 2005's published CIEDE2000 test pairs.
Tolerance 1e-4 as the issue asks (observed differences are ~1e-12 for SSIM/PSNR; pytorch-msssim differs by
~3e-6 because it builds its Gaussian window in float32).
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import correlate1d
from skimage.color import deltaE_ciede2000, rgb2lab
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from core.errors import DataError
from eval import image_metrics as im

FOUNTAIN = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "fountain-P11" / "images"
LPIPS_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "lpips"


def _load(path: Path, factor: int = 8) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as img:
        return np.asarray(img.convert("RGB").reduce(factor))


@pytest.fixture(scope="module")
def fountain_pair():
    if not (FOUNTAIN / "0000.jpg").is_file():
        pytest.skip(f"shared test data not found at {FOUNTAIN}")
    a, b = _load(FOUNTAIN / "0000.jpg"), _load(FOUNTAIN / "0001.jpg")  # 384 x 256, different viewpoints
    return a, b


@pytest.fixture(scope="module")
def noisy_pair(fountain_pair):
    a = fountain_pair[0] / 255.0
    rng = np.random.default_rng(0)
    return a, np.clip(a + rng.normal(0, 0.04, a.shape), 0, 1)


def _skimage_ssim(a, b, full=False):
    return structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1, full=full
    )


def test_psnr_mse_match_skimage(fountain_pair, noisy_pair):
    for a, b in (fountain_pair, noisy_pair):
        fa, fb = im.to_float_image(a), im.to_float_image(b)
        assert im.psnr(a, b) == pytest.approx(peak_signal_noise_ratio(fa, fb, data_range=1.0), abs=1e-4)
        assert im.mse(a, b) == pytest.approx(((fa - fb) ** 2).mean(), abs=1e-12)
    a = fountain_pair[0]
    assert im.psnr(a, a) == im.PSNR_MAX and im.mse(a, a) == 0.0


def test_ssim_matches_skimage(fountain_pair, noisy_pair):
    for a, b in (fountain_pair, noisy_pair):
        fa, fb = im.to_float_image(a), im.to_float_image(b)
        assert im.ssim(a, b) == pytest.approx(_skimage_ssim(fa, fb), abs=1e-4)
    a = fountain_pair[0]
    assert im.ssim(a, a) == pytest.approx(1.0, abs=1e-12)


def test_masked_ssim_psnr_delta_e_match_skimage_maps(noisy_pair):
    a, b = noisy_pair
    h, w = a.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    mask = (xx - w / 3) ** 2 + (yy - h / 2) ** 2 < (h / 3) ** 2
    _, smap = _skimage_ssim(a, b, full=True)
    r = 5  # skimage averages its map over the region where the 11x11 window is inside the image
    inner = mask[r:-r, r:-r]
    expected = smap[r:-r, r:-r][inner].mean()
    assert im.ssim(a, b, mask) == pytest.approx(expected, abs=1e-4)
    expected_mse = ((a - b) ** 2).mean(axis=2)[mask].mean()
    assert im.mse(a, b, mask) == pytest.approx(expected_mse, abs=1e-12)
    assert im.psnr(a, b, mask) == pytest.approx(10 * np.log10(1 / expected_mse), abs=1e-9)
    de = deltaE_ciede2000(rgb2lab(a), rgb2lab(b), channel_axis=-1)
    assert im.delta_e(a, b, mask) == pytest.approx(de[mask].mean(), abs=1e-4)
    assert im.delta_e(a, b) == pytest.approx(de.mean(), abs=1e-4)
    # an all-true mask equals the whole image; an empty one gives 0, not NaN
    full = np.ones((h, w), bool)
    assert im.ms_ssim(a, b, full) == pytest.approx(im.ms_ssim(a, b), abs=1e-12)
    assert im.ssim(a, b, np.zeros((h, w), bool)) == 0.0


def _ms_ssim_reference(a: np.ndarray, b: np.ndarray) -> float:
    """MS-SSIM from Wang, Simoncelli & Bovik 2003, written straight from the paper with scipy (per channel,
    averaged over channels; Gaussian 11-tap window σ=1.5; 2x2 mean downsampling; sizes divisible by 16)."""
    weights = np.array([0.0448, 0.2856, 0.3001, 0.2363, 0.1333])
    t = np.arange(-5, 6)
    g = np.exp(-(t**2) / (2 * 1.5**2))
    g /= g.sum()
    c1, c2 = 0.01**2, 0.03**2

    def filt(x):  # valid-region Gaussian filtering
        return correlate1d(correlate1d(x, g, axis=0), g, axis=1)[5:-5, 5:-5]

    out = []
    for ch in range(3):
        x, y = a[..., ch].astype(np.float64), b[..., ch].astype(np.float64)
        terms = []
        for level in range(5):
            mx, my = filt(x), filt(y)
            vx, vy, cxy = filt(x * x) - mx**2, filt(y * y) - my**2, filt(x * y) - mx * my
            cs = ((2 * cxy + c2) / (vx + vy + c2)).mean()
            if level == 4:
                lum_cs = ((2 * mx * my + c1) / (mx**2 + my**2 + c1) * (2 * cxy + c2) / (vx + vy + c2)).mean()
                terms.append(max(lum_cs, 0.0))
            else:
                terms.append(max(cs, 0.0))
                x = 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])
                y = 0.25 * (y[0::2, 0::2] + y[1::2, 0::2] + y[0::2, 1::2] + y[1::2, 1::2])
        out.append(np.prod(np.array(terms) ** weights))
    return float(np.mean(out))


def test_ms_ssim_matches_reference_from_definition(fountain_pair, noisy_pair):
    for a, b in (fountain_pair, noisy_pair):
        fa, fb = im.to_float_image(a), im.to_float_image(b)
        assert im.ms_ssim(a, b) == pytest.approx(_ms_ssim_reference(fa, fb), abs=1e-4)
    a = fountain_pair[0]
    assert im.ms_ssim(a, a) == pytest.approx(1.0, abs=1e-12)


def test_ms_ssim_matches_pytorch_msssim(fountain_pair, noisy_pair):
    pm = pytest.importorskip("pytorch_msssim", reason="pytorch-msssim is an optional cross-check")
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small convolutions: one thread avoids OpenMP spinning on shared cores
    try:
        compared = _compare_with_pytorch_msssim(pm, torch, (fountain_pair, noisy_pair))
    finally:
        torch.set_num_threads(threads)
    assert compared == 2


def _compare_with_pytorch_msssim(pm, torch, pairs):
    """Asserts agreement pair by pair; returns how many pairs were compared."""
    for a, b in pairs:
        fa, fb = im.to_float_image(a), im.to_float_image(b)
        # float32 keeps torch on its fast convolution path; its rounding (~1e-6) is far below the tolerance
        ta, tb = (torch.from_numpy(x.astype(np.float32)).permute(2, 0, 1)[None] for x in (fa, fb))
        assert im.ms_ssim(a, b) == pytest.approx(float(pm.ms_ssim(ta, tb, data_range=1.0)), abs=1e-4)
    return len(pairs)


def test_ms_ssim_small_images_use_fewer_scales():
    rng = np.random.default_rng(1)
    a = rng.random((48, 64, 3))
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    assert im.ms_ssim_scales(48, 64) == 3
    v = im.ms_ssim(a, b)
    assert 0 < v < 1 and np.isfinite(v)
    with pytest.raises(DataError):
        im.ms_ssim(a[:8], b[:8])


# Sharma, Wu & Dalal (2005), "The CIEDE2000 color-difference formula: implementation notes, supplementary
# test data, and mathematical observations", Table 1: (Lab1, Lab2, ΔE00).
SHARMA = [
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, 3.1571, -77.2803), (50.0, 0.0, -82.7485), 2.8615),
    ((50.0, 2.8361, -74.0200), (50.0, 0.0, -82.7485), 3.4412),
    ((50.0, -1.3802, -84.2814), (50.0, 0.0, -82.7485), 1.0000),
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
    ((50.0, 2.5, 0.0), (61.0, -5.0, 29.0), 22.8977),
    ((50.0, 2.5, 0.0), (56.0, -27.0, -3.0), 31.9030),
    ((50.0, 2.5, 0.0), (58.0, 24.0, 15.0), 19.4535),
]


def test_delta_e_backend_reproduces_sharma_test_data():
    lab1 = np.array([p[0] for p in SHARMA])
    lab2 = np.array([p[1] for p in SHARMA])
    got = deltaE_ciede2000(lab1, lab2)
    np.testing.assert_allclose(got, [p[2] for p in SHARMA], atol=1e-4)


def test_delta_e_identical_and_uniform_shift(fountain_pair):
    a = fountain_pair[0]
    assert im.delta_e(a, a) == 0.0
    grey1 = np.full((16, 16, 3), 0.5)
    grey2 = np.full((16, 16, 3), 0.6)
    lab1, lab2 = rgb2lab(grey1[:1, :1]), rgb2lab(grey2[:1, :1])
    assert im.delta_e(grey1, grey2) == pytest.approx(float(deltaE_ciede2000(lab1, lab2)[0, 0]), abs=1e-9)


def test_image_scores_and_summary(noisy_pair):
    a, b = noisy_pair
    s = im.image_scores(a, b)
    assert s.psnr == pytest.approx(im.psnr(a, b)) and s.lpips is None
    summary = im.summarize([s, im.image_scores(a, a)])
    assert summary.views == 2
    assert summary.mean.mse == pytest.approx(s.mse / 2)
    assert summary.std.mse == pytest.approx(s.mse / 2)
    assert summary.mean.lpips is None
    assert im.summarize([]) is None


def test_input_validation():
    a = np.zeros((20, 20, 3))
    with pytest.raises(DataError, match="differ in size"):
        im.mse(a, np.zeros((21, 20, 3)))
    with pytest.raises(DataError, match="mask"):
        im.mse(a, a, np.ones((3, 3), bool))
    with pytest.raises(DataError, match="NaN"):
        im.mse(a, np.full((20, 20, 3), np.nan))
    assert im.to_float_image(np.full((2, 2, 3), 255, np.uint8)).max() == 1.0
