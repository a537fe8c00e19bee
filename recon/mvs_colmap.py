"""COLMAP PatchMatch stereo backend (needs a CUDA build of pycolmap; probed, never assumed)."""

from __future__ import annotations

from pathlib import Path

from core.errors import ConfigError


def colmap_available() -> bool:
    """True when the installed pycolmap was built with CUDA (``pycolmap.has_cuda``)."""
    try:
        import pycolmap
    except ImportError:
        return False
    return bool(getattr(pycolmap, "has_cuda", False))


def run_patch_match(dense_dir: str | Path, max_image_size: int = -1, geom_consistency: bool = True) -> None:
    """Run ``pycolmap.patch_match_stereo`` on an undistorted workspace; writes photometric + geometric maps.

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
    pycolmap.patch_match_stereo(str(dense_dir), workspace_format="COLMAP", options=opts)
