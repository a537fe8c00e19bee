"""The project's input as the stages see it: photos, known cameras, held-out views and ground truth.

``resolve_source(InputOptions)`` looks at INPUT once (:func:`recon.inputs.resolve_input`: a folder of photos,
directly or under ``images/``; a COLMAP workspace; a data_synth scene) and adds what the options decide: which
cameras are known (poses fixed) and which photos are held out for evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from core.errors import InputFileError
from hybridsplat.config import InputOptions
from recon.inputs import Holdout, InputSpec, choose_holdout, resolve_input


@dataclass(frozen=True)
class Source:
    """The resolved input.

    spec: what INPUT holds (photos, cameras, truth), see :class:`recon.inputs.InputSpec`.
    known_cameras: COLMAP model whose cameras are used as they are (poses fixed), or None (full SfM).
    holdout: the held-out views: the input's own (``source == "input"``: outside ``image_dir``, with their
        cameras) or photos of ``image_dir`` (``"every"``: registered by SfM, never used for depth, fusion or
        training).
    """

    spec: InputSpec
    known_cameras: Path | None
    holdout: Holdout

    @property
    def image_dir(self) -> Path:
        return self.spec.image_dir

    @property
    def holdout_names(self) -> tuple[str, ...]:
        """Photos of ``image_dir`` kept out of depth estimation, fusion and training."""
        return self.holdout.names if self.holdout.source == "every" else ()

    @property
    def training_names(self) -> tuple[str, ...]:
        held = set(self.holdout_names)
        return tuple(n for n in self.spec.image_names if n not in held)


def resolve_source(options: InputOptions) -> Source:
    """Resolve ``options.path`` and decide known cameras and held-out photos (see :class:`InputOptions`)."""
    if not options.path:
        raise InputFileError("no input recorded in config.toml ([input] path)")
    spec = resolve_input(options.path, model=options.model)
    known = Path(options.cameras) if options.cameras else None
    if known is None and options.use_scene_cameras:
        known = spec.known_cameras
    holdout = choose_holdout(spec, None if options.holdout == -1 else options.holdout)
    return Source(spec=spec, known_cameras=known, holdout=holdout)
