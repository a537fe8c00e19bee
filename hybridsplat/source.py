"""The project's input as the stages see it: photos, known cameras, held-out views and ground truth.

``resolve_source(InputOptions)`` looks at INPUT once: a folder of photos (directly or under ``images/``), a COLMAP
workspace (``sparse/`` or ``sparse/N`` beside ``images/``) or a data_synth scene (``images/``, ``sparse/0``,
``sparse/test`` + ``test/``, ``gt/``, ``scene.json``), via :func:`recon.inputs.resolve_input`, and adds what the
pipeline decides from the options: which cameras are known and which photos are held out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from core.errors import InputFileError
from hybridsplat.config import InputOptions
from recon.inputs import InputSpec, resolve_input, select_holdout


@dataclass(frozen=True)
class Source:
    """The resolved input.

    spec: what INPUT holds (photos, cameras, truth), see :class:`recon.inputs.InputSpec`.
    known_cameras: COLMAP model whose cameras are used as they are (poses fixed), or None (full SfM).
    holdout_names: photos of ``spec.image_dir`` never used for depth, fusion or training; evaluated on.
    """

    spec: InputSpec
    known_cameras: Path | None
    holdout_names: tuple[str, ...]

    @property
    def image_dir(self) -> Path:
        return self.spec.image_dir

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
    if options.holdout == -1:
        # the input's own held-out views (a data_synth scene's test/) are outside image_dir already
        holdout = () if spec.has_own_holdout else select_holdout(spec.image_names, 8)
    else:
        holdout = select_holdout(spec.image_names, options.holdout)
    return Source(spec=spec, known_cameras=known, holdout_names=tuple(holdout))
