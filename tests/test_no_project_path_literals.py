"""Only hybridsplat/layout.py spells the project folder's file names (COLMAP's own names: recon/workspace.py): not
the packages, nor the benchmarks and scripts, which ask ``hybridsplat.layout.ProjectLayout`` like everything else."""

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCANNED = ("core", "data_synth", "recon", "classify", "fusion", "eval", "hybridsplat", "bench", "scripts")
ALLOWED = {Path("hybridsplat/layout.py"), Path("recon/workspace.py")}
# file names of the project folder (docs/conventions.md) that no other module may spell
PROJECT_NAMES = {
    "manifest.json", "config.toml", "fused.ply", "fused.ply.vis", "points.ply", "mvs_gaussians.ply", "merged.ply",
    "merged_points.ply", "merged_points.las", "splats.ply", "trained.ply", "cleaned.ply", "baseline.ply",
    "metrics.json", "report.html", "report.md", "report.json",
}  # fmt: skip


def _spelled_names() -> dict[Path, list[tuple[int, str]]]:
    """(line, name) of every project file name spelled as a string constant, per scanned file outside ALLOWED."""
    found: dict[Path, list[tuple[int, str]]] = {}
    for folder in SCANNED:
        for path in sorted((REPO / folder).rglob("*.py")):
            rel = path.relative_to(REPO)
            if rel in ALLOWED:
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in PROJECT_NAMES:
                    found.setdefault(rel, []).append((node.lineno, node.value))
    return found


def test_project_file_names_are_spelled_only_by_the_layout():
    offenders = [f"{rel}:{line}: {name!r}" for rel, hits in _spelled_names().items() for line, name in hits]
    assert not offenders, "ask hybridsplat.layout.ProjectLayout for these paths:\n" + "\n".join(offenders)
