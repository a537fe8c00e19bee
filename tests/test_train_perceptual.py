"""The LPIPS term of the trainer (fusion.train.perceptual): its gradient against central finite differences, what
it sees of the photo, the trainer option (off = bit-identical, on = called from its start step) and the train
stage's handling of the weights file."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import tomllib
import torch
from test_train_trainer import blob_set, perturbed, render_all, ring_cameras

from core.errors import ConfigError, FormatError, InputFileError
from eval import lpips as lp
from fusion.train import DefaultStrategy, TrainOptions, train_splats
from fusion.train.perceptual import MIN_SIZE, crop_span, perceptual_loss, prepare_crop
from fusion.train.views import TrainView


def _weights() -> Path | None:
    """The real LPIPS weights as the project finds them ($HYBRIDSPLAT_LPIPS_WEIGHTS, ../shared/data/lpips), if any."""
    try:
        return lp.find_weights()
    except (ConfigError, InputFileError):
        return None


WEIGHTS = _weights()


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Small images: one thread avoids OpenMP spinning on shared cores (results do not depend on it)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def random_weights(seed: int, dtype: np.dtype) -> dict[str, np.ndarray]:
    """AlexNet-LPIPS-shaped weights (the layouts eval.lpips.read_weights checks), random but seeded."""
    rng = np.random.default_rng(seed)
    shapes = ((64, 3, 11), (192, 64, 5), (384, 192, 3), (256, 384, 3), (256, 256, 3))
    out = {}
    for key, (o, i, k) in zip(("features.0", "features.3", "features.6", "features.8", "features.10"), shapes,
                              strict=True):  # fmt: skip
        out[f"{key}.weight"] = (rng.normal(size=(o, i, k, k)) / np.sqrt(i * k * k)).astype(dtype)
        out[f"{key}.bias"] = rng.normal(0, 0.05, o).astype(dtype)
    for n, (o, _, _) in enumerate(shapes):
        out[f"lin{n}.model.1.weight"] = rng.uniform(0, 0.2, (1, o, 1, 1)).astype(dtype)
    return out


def float64_network() -> lp.LPIPS:
    """The project's LPIPS in float64 (the real weights when present): finite differences need the precision."""
    weights = lp.read_weights(WEIGHTS) if WEIGHTS is not None else random_weights(0, np.float32)
    return lp.LPIPS({k: v.astype(np.float64) for k, v in weights.items()})


def tiny_view(h: int = 40, w: int = 44, seed: int = 0, dtype=torch.float64) -> TrainView:
    """A view with a blob-shaped mask away from the borders and a seeded 10 % hold-out inside it."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    mask = ((yy - 18) / 9.0) ** 2 + ((xx - 24) / 12.0) ** 2 < 1.0
    hold = mask & (rng.random((h, w)) < 0.1)
    image = torch.from_numpy(rng.uniform(0.1, 0.9, (h, w, 3))).to(dtype)
    eye = torch.eye(4, dtype=torch.float32)
    return TrainView("t", image, torch.from_numpy(mask & ~hold), torch.from_numpy(hold), eye, eye[:3, :3], w, h,
                     int(mask.sum()), None)  # fmt: skip


def test_crop_span_grows_clips_and_keeps_the_minimum_size() -> None:
    for lo, hi, margin, size in ((10, 20, 4, 100), (0, 3, 2, 40), (38, 40, 0, 40), (5, 90, 16, 100), (0, 10, 0, 20)):
        a, b = crop_span(lo, hi, margin, size)
        assert a <= lo and b >= hi and 0 <= a and b <= size
        assert b - a >= min(MIN_SIZE, size)
        assert b - a == max(min(MIN_SIZE, size), min(size, hi + margin) - max(0, lo - margin))


def test_gradient_matches_central_differences() -> None:
    """d LPIPS / d rendered at loss pixels and along random directions, float64, step 1e-6; exactly zero at every
    pixel that is not a loss pixel (outside the mask and on the hold-out pixels)."""
    net = float64_network()
    view = tiny_view()
    crop = prepare_crop(view, margin=4)
    rng = np.random.default_rng(1)
    rendered = (view.image + torch.from_numpy(rng.normal(0, 0.1, view.image.shape))).requires_grad_(True)
    value = perceptual_loss(rendered, crop, net)
    assert value.dtype == torch.float64 and float(value.detach()) > 0
    (grad,) = torch.autograd.grad(value, rendered)
    loss_px = view.loss_mask.numpy()
    assert not grad.numpy()[~loss_px].any()  # no gradient off the loss pixels
    assert np.abs(grad.numpy()[loss_px]).max() > 0

    def f(x: torch.Tensor) -> float:
        with torch.no_grad():
            return float(perceptual_loss(x, crop, net))

    eps = 1e-6
    ys, xs = np.nonzero(loss_px)
    pick = rng.choice(len(ys), 12, replace=False)
    base = rendered.detach()
    for j in pick:
        c = int(rng.integers(3))
        step = torch.zeros_like(base)
        step[ys[j], xs[j], c] = eps
        numeric = (f(base + step) - f(base - step)) / (2 * eps)
        assert numeric == pytest.approx(float(grad[ys[j], xs[j], c]), rel=1e-5, abs=1e-9)
    for _ in range(3):
        d = torch.from_numpy(rng.normal(size=base.shape))
        numeric = (f(base + eps * d) - f(base - eps * d)) / (2 * eps)
        assert numeric == pytest.approx(float((grad * d).sum()), rel=1e-5)


def test_the_term_sees_neither_unmasked_renders_nor_held_out_photo_pixels() -> None:
    net = lp.LPIPS(random_weights(2, np.float32))
    view = tiny_view(dtype=torch.float32)
    crop = prepare_crop(view)
    rng = np.random.default_rng(3)
    rendered = torch.from_numpy(rng.uniform(0, 1, view.image.shape).astype(np.float32))
    value = float(perceptual_loss(rendered, crop, net))
    off = ~view.loss_mask
    # another render off the loss pixels: same value
    noise = torch.rand(rendered.shape, generator=torch.Generator().manual_seed(0))
    other = torch.where(off[..., None], noise, rendered)
    assert float(perceptual_loss(other, crop, net)) == value
    # another photo on the hold-out pixels: same crop target
    hold = view.holdout_mask[..., None]
    photo2 = torch.where(hold, 1.0 - view.image, view.image)
    view2 = TrainView(view.name, photo2, view.loss_mask, view.holdout_mask, view.viewmat, view.K, view.width,
                      view.height, view.mask_pixels, None)  # fmt: skip
    crop2 = prepare_crop(view2)
    assert torch.equal(crop2.target, crop.target)
    # a render equal to the photo on the loss pixels scores 0
    assert float(perceptual_loss(view.image, crop, net)) == pytest.approx(0.0, abs=1e-7)


def test_whole_image_term_is_the_plain_lpips_distance() -> None:
    """No mask and no hold-out: the crop is the image and the term is LPIPS of the two images."""
    net = lp.LPIPS(random_weights(4, np.float32))
    view = tiny_view(dtype=torch.float32)
    whole = TrainView("w", view.image, None, torch.zeros_like(view.holdout_mask), view.viewmat, view.K, view.width,
                      view.height, view.width * view.height, None)  # fmt: skip
    crop = prepare_crop(whole)
    assert crop.rows == (0, view.height) and crop.cols == (0, view.width)
    rendered = view.image.flip(0).contiguous()
    expected = float(net(rendered.permute(2, 0, 1)[None] * 2 - 1, view.image.permute(2, 0, 1)[None] * 2 - 1)[0])
    assert float(perceptual_loss(rendered, crop, net)) == pytest.approx(expected, rel=1e-6)


class _Spy:
    """An LPIPS network that counts its calls (and refuses to be called when ``forbid``)."""

    def __init__(self, net: lp.LPIPS | None, forbid: bool = False) -> None:
        self.net, self.forbid, self.calls = net, forbid, 0

    def __call__(self, x, y, mask=None):
        assert not self.forbid, "the LPIPS network must not be called when the term is off"
        self.calls += 1
        return self.net(x, y, mask)


def _tiny_training():
    cams = ring_cameras(4)
    truth = blob_set(120, 4)
    photos = render_all(truth, cams)
    masks = {k: np.zeros(p.shape[:2], bool) for k, p in photos.items()}
    for m in masks.values():
        m[8:40, 12:52] = True
    return cams, photos, masks, perturbed(truth, 5)


def test_weight_zero_is_bit_identical_and_never_calls_the_network() -> None:
    cams, photos, masks, init = _tiny_training()
    base = dict(iterations=12, sh_degree=1, sh_degree_interval=4, seed=1, strategy=DefaultStrategy(refine_start=6,
                refine_every=3, grow_grad2d=1e-7, cap=200))  # fmt: skip
    a = train_splats(cams, photos, masks, init, options=TrainOptions(**base))
    b = train_splats(cams, photos, masks, init, options=TrainOptions(**base, lpips_weight=0.0, lpips_start=0.0),
                     lpips=_Spy(None, forbid=True))  # fmt: skip
    for key in ("means", "log_scales", "quats", "logit_opacities", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(a.splats, key), getattr(b.splats, key))
    assert [c.loss for c in a.history] == [c.loss for c in b.history]


def test_weight_above_zero_adds_the_term_from_its_start_step() -> None:
    cams, photos, masks, init = _tiny_training()
    base = dict(iterations=10, sh_degree=0, seed=2, strategy=DefaultStrategy(refine_start=10_000))
    off = train_splats(cams, photos, masks, init, options=TrainOptions(**base))
    spy = _Spy(lp.LPIPS(random_weights(5, np.float32)))
    on = train_splats(cams, photos, masks, init, options=TrainOptions(**base, lpips_weight=0.5, lpips_start=0.6),
                      lpips=spy)  # fmt: skip
    assert spy.calls == 4  # steps 6..9 of 10
    assert not np.array_equal(off.splats.sh_dc, on.splats.sh_dc)
    with pytest.raises(ConfigError, match="LPIPS network"):
        train_splats(cams, photos, masks, init, options=TrainOptions(**base, lpips_weight=0.1))
    with pytest.raises(ConfigError):
        TrainOptions(lpips_start=1.5)


def test_stage_records_the_option_and_checks_the_weights_file_first(tmp_path) -> None:
    from test_train_stages import make_project

    from hybridsplat.config import ProjectConfig, read_config
    from hybridsplat.options import options_with
    from hybridsplat.stages.base import StageContext
    from hybridsplat.stages.train import MaskedTrainingOptions, TrainStage

    def train_options(**values):
        return options_with(MaskedTrainingOptions, values)

    opts = train_options(**{"training.iterations": 8, "training.lpips_weight": 0.15, "training.lpips_start": 0.5,
                            "lpips_weights": str(tmp_path / "no.npz")})  # fmt: skip
    config = ProjectConfig().with_stage_options("train", opts)
    text = config.to_toml()
    table = tomllib.loads(text)["train"]["training"]
    assert table["lpips_weight"] == 0.15 and table["lpips_start"] == 0.5
    (tmp_path / "config.toml").write_text(text)
    assert read_config(tmp_path / "config.toml", {"train": MaskedTrainingOptions}).stages["train"] == opts
    layout, _, _ = make_project(tmp_path / "p")
    ctx = StageContext(layout=layout, config=config, source=SimpleNamespace(holdout_names=()))
    with pytest.raises(InputFileError) as err:
        TrainStage().run(ctx)
    assert "no.npz" in str(err.value)
    assert not layout.trained_splats.exists()
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an archive")
    ctx = StageContext(layout=layout, config=ProjectConfig().with_stage_options(
        "train", train_options(**{"training.iterations": 8, "training.lpips_weight": 0.1, "lpips_weights": str(bad)})),
        source=SimpleNamespace(holdout_names=()))  # fmt: skip
    with pytest.raises(FormatError) as err:
        TrainStage().run(ctx)
    assert "bad.npz" in str(err.value)
    with pytest.raises(ConfigError):
        train_options(**{"training.lpips_weight": -1.0})
    if WEIGHTS is not None:  # the whole wiring: weights resolved, network built, term used, file recorded
        good = train_options(**{"training.iterations": 6, "init.rays_per_view": 20, "training.sh_degree": 0,
                                "training.lpips_weight": 0.1, "training.lpips_start": 0.5,
                                "lpips_weights": str(WEIGHTS)})  # fmt: skip
        ctx = StageContext(layout=layout, config=ProjectConfig().with_stage_options("train", good),
                           source=SimpleNamespace(holdout_names=()))  # fmt: skip
        counts = TrainStage().run(ctx)
        assert counts.iterations == 6 and counts.lpips_weights == str(WEIGHTS)
        assert layout.trained_splats.is_file()
