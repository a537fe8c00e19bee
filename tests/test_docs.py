"""The user documentation holds together: the README stays short, every relative link of the README and of docs/
reaches an existing file and heading, and only the developer page links the experiment logs."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]  # docs/experiments/ is not a user page
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"```.*?```", re.S)


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return {_slug(m.group(1)) for m in re.finditer(r"^#+ (.+)$", text, re.M)}


def _links(page: Path) -> list[str]:
    return LINK.findall(FENCE.sub("", page.read_text(encoding="utf-8")))


def test_slug_is_githubs():
    assert _slug("Troubleshooting by exit code") == "troubleshooting-by-exit-code"
    assert _slug("hybridsplat classify predict") == "hybridsplat-classify-predict"
    assert _slug("Tiles for large surveys (`hybridsplat run --tiles auto|NxM`)") == (
        "tiles-for-large-surveys-hybridsplat-run---tiles-autonxm"
    )


def test_readme_is_short_and_its_picture_small():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 120
    pictures = [link for link in _links(ROOT / "README.md") if link.endswith(".png")]
    assert pictures and all((ROOT / p).stat().st_size <= 150 * 1024 for p in pictures)


def test_every_relative_link_reaches_a_file_and_a_heading():
    broken = []
    for page in PAGES:
        for link in _links(page):
            if re.match(r"[a-z]+:", link):  # http:, mailto:
                continue
            target, _, anchor = link.partition("#")
            path = (page.parent / target).resolve() if target else page
            if not path.exists():
                broken.append(f"{page.relative_to(ROOT)}: {link} (no such file)")
            elif anchor and path.suffix == ".md" and anchor not in _anchors(path):
                broken.append(f"{page.relative_to(ROOT)}: {link} (no such heading)")
    assert not broken, "\n".join(broken)


def test_only_the_developer_page_links_the_experiment_logs():
    linking = [
        page.relative_to(ROOT).as_posix()
        for page in PAGES
        if page.name != "developers.md" and "experiments/" in page.read_text(encoding="utf-8")
    ]
    assert linking == []
    assert any("experiments/" in link for link in _links(ROOT / "docs" / "developers.md"))
