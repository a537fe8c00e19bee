"""Viewer formats of one product side by side (issue 33): size against the 3DGS PLY and what the decoded file looks
like from the held-out cameras.

    python bench/bench_export_formats.py PRODUCT.ply TEST_MODEL [--splat-transform DIR]

For each format (3DGS PLY, SPZ v2 and v3, PlayCanvas compressed PLY, SOG): ``hybridsplat export`` writes it
(``min_opacity`` 0: every Gaussian), our reader decodes it, and the CPU renderer draws the decoded Gaussians at each
view of ``TEST_MODEL`` (a COLMAP model, e.g. a demo scene's ``sparse/test``) on black; the figure is the PSNR of
that render against the PLY's own render (the loss the encoding costs a viewer), mean over the views. With
``--splat-transform`` (the folder holding ``node_modules/.bin/splat-transform``) the same file is also decoded by
splat-transform (converted to a 3DGS PLY) and rendered likewise: an independent reader.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.gaussians import GaussianSet  # noqa: E402
from core.io.gaussian_ply import read_gaussian_ply  # noqa: E402
from core.io.origin import read_origin  # noqa: E402
from fusion.export import ExportOptions, export_gaussians  # noqa: E402

FORMATS = {  # name -> (file name, export options beyond min_opacity 0)
    "3DGS PLY": ("x.ply", {}),
    "SPZ v2": ("x.spz", {}),
    "SPZ v3": ("x3.spz", {"spz_version": 3}),
    "compressed PLY": ("x.compressed.ply", {}),
    "SOG": ("x.sog", {}),
}


def read_ours(path: Path) -> GaussianSet:
    """Decode a written file with our own reader."""
    name = path.name
    if name.endswith(".compressed.ply"):
        from fusion.compressed_ply_format import read_compressed_ply

        return read_compressed_ply(path).to_gaussians()
    if name.endswith(".spz"):
        from fusion.spz_format import read_spz

        return read_spz(path).to_gaussians()
    if name.endswith(".sog"):
        from fusion.sog_format import read_sog

        return read_sog(path).to_gaussians()
    return read_gaussian_ply(path)


def read_splat_transform(path: Path, tool: Path) -> GaussianSet:
    """Decode a written file with splat-transform (to a 3DGS PLY), at our file's origin (its sidecar)."""
    out = path.with_name(path.name + ".st.ply")
    subprocess.run([str(tool), "-w", str(path), str(out)], check=True, capture_output=True)
    _clamp_opacity_logits(out)
    decoded = read_gaussian_ply(out)
    decoded.origin = read_origin(path)
    return decoded


def _clamp_opacity_logits(path: Path, bound: float = 16.1) -> None:
    """splat-transform writes α = 1 (an 8-bit 255) as an infinite logit, which our reader refuses: clamp to ±16.1
    (α within 1e-7 of 0 or 1, as our readers map them) so that the render sees an opaque splat."""
    import plyfile

    ply = plyfile.PlyData.read(str(path), mmap=False)
    vertex = ply["vertex"].data
    vertex["opacity"] = np.clip(np.nan_to_num(vertex["opacity"], posinf=bound, neginf=-bound), -bound, bound)
    ply.write(str(path))


def renders(gaussians: GaussianSet, model: Path) -> list[np.ndarray]:
    from fusion.render.scene import render_gaussian_set
    from recon.model import from_reconstruction, read_reconstruction

    cameras = from_reconstruction(read_reconstruction(model))
    return [
        render_gaussian_set(gaussians, cameras.camera_of(v), v, cameras_origin=cameras.origin, backend="cpu")
        .colour.detach()
        .double()
        .numpy()
        for v in sorted(cameras, key=lambda v: v.name)
    ]


def psnr(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    return float(np.mean([10 * np.log10(1.0 / max(np.mean((x - y) ** 2), 1e-20)) for x, y in zip(a, b, strict=True)]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("product", type=Path)
    parser.add_argument("test_model", type=Path)
    parser.add_argument("--splat-transform", type=Path, default=None)
    args = parser.parse_args()
    source = read_gaussian_ply(args.product)
    tool = args.splat_transform / "node_modules/.bin/splat-transform" if args.splat_transform else None
    print(f"{args.product}: {len(source)} Gaussians, SH degree {source.sh_degree}; views: {args.test_model}")
    print(f"{'format':<16}{'bytes':>12}{'/ PLY':>8}{'B/splat':>9}{'PSNR ours':>11}{'PSNR splat-transform':>22}")
    with tempfile.TemporaryDirectory() as tmp:
        reference = None
        ply_bytes = None
        for name, (file_name, extra) in FORMATS.items():
            path = Path(tmp) / file_name
            export_gaussians(path, source, ExportOptions(min_opacity=0.0, **extra))
            size = path.stat().st_size
            ply_bytes = ply_bytes or size
            ours = renders(read_ours(path), args.test_model)
            reference = reference or ours
            theirs = "-"
            if tool is not None:
                theirs = f"{psnr(renders(read_splat_transform(path, tool), args.test_model), reference):.2f}"
            print(
                f"{name:<16}{size:>12,}{size / ply_bytes:>8.3f}{size / len(source):>9.1f}"
                f"{psnr(ours, reference):>11.2f}{theirs:>22}"
            )


if __name__ == "__main__":
    main()
