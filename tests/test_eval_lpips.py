"""In-project LPIPS v0.1 (AlexNet) against the LPIPS project's published example distances."""

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from core.errors import ConfigError, FormatError, InputFileError
from eval import lpips as lp

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "lpips"


def _img(name: str) -> np.ndarray:
    from PIL import Image

    with Image.open(DATA / name) as im:
        return np.asarray(im.convert("RGB"))


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Small images: one thread avoids OpenMP spinning on shared cores (results do not depend on it)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def model():
    if not (DATA / lp.WEIGHTS_NAME).is_file():
        pytest.skip(f"LPIPS weights not found in {DATA}")
    return lp.LPIPS.from_path(DATA / lp.WEIGHTS_NAME)


def test_reproduces_published_distances(model):
    ref = _img("ex_ref.png")
    # Published with the LPIPS project (lpips_2imgs.py, v0.1, alex): 0.722 and 0.137.
    assert model.distance(ref, _img("ex_p0.png")) == pytest.approx(0.722, abs=1e-3)
    assert model.distance(ref, _img("ex_p1.png")) == pytest.approx(0.137, abs=1e-3)


def test_identity_symmetry_and_blur_monotonic(model):
    ref = _img("ex_ref.png")
    assert model.distance(ref, ref) == 0.0
    p0 = _img("ex_p0.png")
    assert model.distance(ref, p0) == pytest.approx(model.distance(p0, ref), abs=1e-6)
    img = ref / 255.0
    values = [model.distance(img, gaussian_filter(img, sigma=(s, s, 0))) for s in (0.5, 1.0, 2.0, 4.0)]
    assert all(b > a for a, b in zip(values, values[1:], strict=False)), values
    assert values[0] > 0


def test_masked_lpips(model):
    ref, p1 = _img("ex_ref.png"), _img("ex_p1.png")
    full = np.ones(ref.shape[:2], bool)
    assert model.distance(ref, p1, full) == pytest.approx(model.distance(ref, p1), abs=1e-6)
    assert model.distance(ref, p1, np.zeros(ref.shape[:2], bool)) == 0.0
    # on a 256 px image, a change confined to the left edge is seen by a left mask far more than by a right one
    big = np.tile(ref, (4, 4, 1))
    changed = big.copy()
    changed[:, :48] = 255 - changed[:, :48]
    left = np.zeros(big.shape[:2], bool)
    left[:, :64] = True
    right = np.zeros(big.shape[:2], bool)
    right[:, 160:] = True
    assert model.distance(big, changed, left) > 5 * model.distance(big, changed, right)


def test_forward_is_batched_and_differentiable(model):
    x = torch.rand(2, 3, 64, 64) * 2 - 1
    y = (x + 0.1 * torch.randn_like(x)).clamp(-1, 1).requires_grad_(True)
    d = model(x, y)
    assert d.shape == (2,)
    d.sum().backward()
    assert y.grad is not None and torch.isfinite(y.grad).all()


def test_weight_search_and_errors(tmp_path, monkeypatch):
    monkeypatch.setenv(lp.ENV_VAR, str(tmp_path / "missing.npz"))
    with pytest.raises(InputFileError):
        lp.find_weights()
    monkeypatch.delenv(lp.ENV_VAR)
    monkeypatch.setattr(lp, "default_weight_paths", lambda: [tmp_path / "nothing.npz"])
    with pytest.raises(ConfigError, match=lp.ENV_VAR):
        lp.find_weights()
    bad = tmp_path / "bad.npz"
    np.savez(bad, **{"features.0.weight": np.zeros((64, 3, 11, 11), np.float32)})
    with pytest.raises(FormatError, match="lack"):
        lp.load_weights(bad)
    (tmp_path / "garbage.npz").write_bytes(b"not a zip")
    with pytest.raises(FormatError):
        lp.load_weights(tmp_path / "garbage.npz")
    if (DATA / lp.WEIGHTS_NAME).is_file():
        monkeypatch.setenv(lp.ENV_VAR, str(DATA / lp.WEIGHTS_NAME))
        assert lp.find_weights() == DATA / lp.WEIGHTS_NAME


@pytest.mark.gpu
def test_cuda_matches_cpu(model):
    if not torch.cuda.is_available():
        pytest.skip("needs a CUDA GPU")
    gpu = lp.LPIPS(model.w, device="cuda")
    ref, p0 = _img("ex_ref.png"), _img("ex_p0.png")
    assert gpu.distance(ref, p0) == pytest.approx(model.distance(ref, p0), abs=1e-5)
