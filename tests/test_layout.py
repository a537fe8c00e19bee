"""The project folder's documented names are exactly the ones ProjectLayout spells."""

import re
from pathlib import Path

from hybridsplat.layout import ProjectLayout

DOCS = Path(__file__).resolve().parents[1] / "docs" / "conventions.md"


def _documented() -> list[str]:
    text = DOCS.read_text(encoding="utf-8")
    section = text.split("## The project folder", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `([^`]+)` \|", section, flags=re.M)


def test_docs_list_every_layout_path_and_nothing_else():
    layout = ProjectLayout("/some/project")
    documented = _documented()
    assert len(documented) == len(set(documented))
    assert sorted(documented) == sorted(layout.documented_paths())
    for name, rel in layout.documented_paths().items():
        assert str(rel) == name.rstrip("/"), name


def test_paths_are_under_the_root_and_masks_follow_colmap_names():
    layout = ProjectLayout("/p")
    assert layout.mask_path("0001.jpg") == Path("/p/classify/masks/0001.jpg.png")
    assert layout.fused_ply == Path("/p/dense/fused.ply") and layout.log("mvs") == Path("/p/logs/mvs.log")
    assert all(str(p).startswith("/p/") for p in (layout.root / rel for rel in layout.documented_paths().values()))
