"""Only hybridsplat/layout.py spells the project folder's file names (COLMAP's own names: recon/workspace.py)."""

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("core", "data_synth", "recon", "classify", "fusion", "eval", "hybridsplat")
ALLOWED = {Path("hybridsplat/layout.py"), Path("recon/workspace.py")}
# file names of the project folder (docs/conventions.md) that no other module may spell
PROJECT_NAMES = {
    "manifest.json", "config.toml", "fused.ply", "fused.ply.vis", "points.ply", "mvs_gaussians.ply", "merged.ply",
    "merged_points.ply", "merged_points.las", "splats.ply", "trained.ply", "cleaned.ply", "baseline.ply",
    "metrics.json", "report.html", "report.md", "report.json",
}  # fmt: skip


def test_project_file_names_are_spelled_only_by_the_layout():
    offenders = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO)
            if rel in ALLOWED:
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in PROJECT_NAMES:
                    offenders.append(f"{rel}:{node.lineno}: {node.value!r}")
    assert not offenders, "\n".join(offenders)
