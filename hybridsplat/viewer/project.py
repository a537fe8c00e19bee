"""The project folder as the viewer and ``hybridsplat measure`` see it: its layout and the cameras' frame."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from core.errors import InputFileError
from hybridsplat.layout import ProjectLayout


def open_project(project: str | PathLike[str]) -> ProjectLayout:
    """The layout of an existing project folder; :class:`InputFileError` when there is none."""
    root = Path(project)
    if not root.is_dir():
        raise InputFileError("project folder does not exist" if not root.exists() else "is not a folder", root)
    return ProjectLayout(root)


def cameras_origin(layout: ProjectLayout, fallback: np.ndarray) -> np.ndarray:
    """World coordinates of the COLMAP model's local frame: the SfM record's ``origin``, else ``fallback``.

    ``fallback`` is the merged product's origin (its ``.origin.json`` sidecar), which equals the model's frame
    whenever the products were made from this model.
    """
    from hybridsplat.project_io import model_origin

    return model_origin(layout, fallback)
