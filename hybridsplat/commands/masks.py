"""``hybridsplat masks PROJECT``: the ``masks`` stage alone (classify/masks/<photo>.png, 255 = needs splats)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("masks")
    def masks(
        project: Path = typer.Argument(..., help="Project folder (after 'hybridsplat classify predict' or 'run')."),
        footprint: float | None = typer.Option(None, help="Point radius in point spacings (default 1.5)."),
        close_px: int | None = typer.Option(None, help="Closing radius in pixels (default 3)."),
        dilate_px: int | None = typer.Option(None, help="Dilation radius in pixels, at least (default 2)."),
        dilate_spacings: float | None = typer.Option(
            None, help="Dilation radius in point spacings at the photo's median depth, when larger (default 3)."
        ),
        holes: bool | None = typer.Option(None, "--holes/--no-holes", help="Add MVS holes to the masks."),
        hole_area: str | None = typer.Option(
            None, help="Where holes are looked for: hull_below (default) | hull | below | enclosed."
        ),
        explained_by: str | None = typer.Option(
            None, help="Points that explain pixels: seen (fused by the photo or of its colour, default) | all."
        ),
        hole_gsd: float | None = typer.Option(
            None, help="Radius (ground sample distances) within which a point explains pixels (default 2.5)."
        ),
        grow_area: int | None = typer.Option(
            None, help="GrabCut iterations growing the hole area by what looks like the scene (default 3; 0 off)."
        ),
        infinity: bool | None = typer.Option(
            None, "--infinity/--no-infinity", help="Pixels at infinity (no parallax: sky, backdrop) are no holes."
        ),
        force: bool = typer.Option(False, "--force", help="Rerun even when up to date."),
    ) -> None:
        """Region masks per registered photo: non-collaborative points, MVS holes and user masks, united."""
        from hybridsplat.commands.common import run_project_stage

        overrides = {
            "footprint": footprint,
            "close_px": close_px,
            "dilate_px": dilate_px,
            "dilate_spacings": dilate_spacings,
            "holes": holes,
            "hole_area": hole_area,
            "explained_by": explained_by,
            "hole_gsd": hole_gsd,
            "grow_area": grow_area,
            "infinity": infinity,
        }
        run_project_stage(project, "masks", overrides, force=force)
