"""``hybridsplat mesh PROJECT --budget N``: the ``mesh`` stage alone (export/mesh.ply|obj|glb from the merged set)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("mesh")
    def mesh(
        project: Path = typer.Argument(..., help="Project folder (after 'hybridsplat run' or 'merge')."),
        budget: int | None = typer.Option(None, "--budget", help="Triangles of the mesh (within 1 %)."),
        formats: list[str] = typer.Option([], "--format", help="ply | obj | glb (repeatable; default: all three)."),
        method: str | None = typer.Option(None, help="poisson (default) | tsdf (fusion of rendered depth)."),
        source: str | None = typer.Option(None, help="all (hybrid, default) | mvs (MVS Gaussians only)."),
        snapshots: bool | None = typer.Option(
            None, "--snapshots/--no-snapshots", help="Use training snapshots for transparent regions (default on)."
        ),
        decimator: str | None = typer.Option(None, help="auto (default) | fast-simplification | open3d."),
        force: bool = typer.Option(False, "--force", help="Rerun even when up to date."),
    ) -> None:
        """A triangle mesh with a polygon budget from the merged product: PROJECT/export/mesh.ply, .obj, .glb."""
        from hybridsplat.commands.common import run_project_stage

        overrides = {
            "budget": budget,
            "formats": tuple(formats) if formats else None,
            "method": method,
            "source": source,
            "snapshots": snapshots,
            "decimator": decimator,
        }
        run_project_stage(project, "mesh", overrides, force=force)
