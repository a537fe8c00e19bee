"""COLMAP PatchMatch stereo backend (needs a CUDA build of pycolmap; probed, never assumed).

PatchMatch runs on the problems of ``stereo/patch-match.cfg`` (COLMAP's format, see
:meth:`recon.workspace.DenseWorkspace.write_patch_match_cfg`): we write it ourselves, with explicit source lists chosen
by :func:`recon.view_selection.select_views` as the CPU backend chooses them, so that held-out photos are never a
reference (no depth map) nor a source (their pixels are never read). COLMAP's undistorter writes ``__auto__, 20`` for
every photo instead, which would use them.
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

from core.errors import ConfigError
from recon.view_selection import select_views

COLMAP_NUM_SOURCES = 20  # source photos per reference: COLMAP's default (its undistorter writes "__auto__, 20")


def colmap_available() -> bool:
    """True when the installed pycolmap was built with CUDA (``pycolmap.has_cuda``)."""
    try:
        import pycolmap
    except ImportError:
        return False
    return bool(getattr(pycolmap, "has_cuda", False))


def patch_match_problems(
    rec,  # pycolmap.Reconstruction: the dense workspace's undistorted model
    held_out: Collection[str] = frozenset(),
    num_sources: int = COLMAP_NUM_SOURCES,
) -> dict[str, list[str]]:
    """PatchMatch problems: reference image name → its source image names, best first, in image-id order.

    Sources come from :func:`recon.view_selection.select_views` (the CPU backend's view selection) with the
    ``held_out`` photos (image names) excluded: none of them is a reference or a source. A photo without any
    source (it shares no sparse point at a usable angle with another photo) is left out, as COLMAP would skip it;
    it is nobody's source either, since the selection score is symmetric.
    """
    held_out_ids = frozenset(int(i) for i in rec.reg_image_ids() if rec.image(i).name in held_out)
    sel = select_views(rec, num_sources=num_sources, exclude=held_out_ids)
    return {rec.image(ref).name: [rec.image(s).name for s in srcs] for ref, srcs in sorted(sel.sources.items()) if srcs}


def run_patch_match(
    dense_dir: str | Path,
    max_image_size: int = -1,
    geom_consistency: bool = True,
    config_path: str | Path | None = None,
) -> None:
    """Run ``pycolmap.patch_match_stereo`` on an undistorted workspace; writes photometric + geometric maps.

    config_path: the ``patch-match.cfg`` to run (None: COLMAP's default, ``dense_dir/stereo/patch-match.cfg``).
    Raises :class:`ConfigError` when pycolmap has no CUDA (install a CUDA build of pycolmap, or use ``--backend cpu``).
    """
    if not colmap_available():
        raise ConfigError(
            "the 'colmap' MVS backend needs pycolmap built with CUDA (pycolmap.has_cuda is False); "
            "use --backend cpu or install a CUDA build of pycolmap"
        )
    import pycolmap

    opts = pycolmap.PatchMatchOptions()
    opts.max_image_size = int(max_image_size)
    opts.geom_consistency = bool(geom_consistency)
    extra = {} if config_path is None else {"config_path": str(config_path)}
    pycolmap.patch_match_stereo(str(dense_dir), workspace_format="COLMAP", options=opts, **extra)
