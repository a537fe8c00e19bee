"""Make the README's picture from a finished demo project: one held-out view as the photo, MVS only, the whole-scene
3DGS baseline and the hybrid, side by side with a label each.

The renders are those the evaluation wrote (the left part of each product's ``render | photo | error`` panel in
``eval/plots/``, listed in ``eval/metrics.json``), so the picture shows what the report measured. The view is the
one whose non-collaborative mask is largest unless ``--view`` names one. The PNG is quantised to 256 colours to stay
small (``--scale`` shrinks the tiles).

    .venv/bin/python -m hybridsplat demo --out /tmp/demo
    PYTHONPATH=$PWD .venv/bin/python scripts/make_readme_image.py /tmp/demo/project --out docs/img/demo.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from eval.metrics_io import read_metrics  # noqa: E402
from hybridsplat.layout import ProjectLayout  # noqa: E402

COLUMNS = (("mvs", "MVS only"), ("baseline", "whole-scene 3DGS"), ("merged", "hybridsplat"))
GAP_PX = 4  # eval.render_eval.side_by_side: white columns between render, photo and error
LABEL_PX = 22


def _panels(layout: ProjectLayout, view: str | None) -> tuple[str, dict[str, Path]]:
    """The chosen view and, per product, its panel's path."""
    products = read_metrics(layout.metrics_json)["products"]
    rows = {name: {r["view"]: r for r in products[name]["images"]["per_view"]} for name, _ in COLUMNS}
    common = [v for v in rows["merged"] if all(v in rows[name] for name, _ in COLUMNS)]
    if not common:
        raise SystemExit(f"{layout.metrics_json}: no held-out view rendered for every one of {[n for n, _ in COLUMNS]}")
    chosen = view if view is not None else max(common, key=lambda v: rows["merged"][v]["mask_share"])
    if chosen not in common:
        raise SystemExit(f"{layout.metrics_json}: no panels of view {chosen!r} (known: {', '.join(common)})")
    return chosen, {name: layout.eval_dir / rows[name][chosen]["files"]["panel"] for name, _ in COLUMNS}


def _thirds(panel: Path) -> tuple[np.ndarray, np.ndarray]:
    """(render, photo) of a ``render | photo | error`` panel."""
    image = np.asarray(Image.open(panel).convert("RGB"))
    width = (image.shape[1] - 2 * GAP_PX) // 3
    return image[:, :width], image[:, width + GAP_PX : 2 * width + GAP_PX]


def compose(layout: ProjectLayout, view: str | None, scale: float) -> Image.Image:
    """The labelled strip, each tile ``scale`` × the rendered size."""
    chosen, panels = _panels(layout, view)
    tiles = [("held-out photo", _thirds(panels["merged"])[1])]
    tiles += [(label, _thirds(panels[name])[0]) for name, label in COLUMNS]
    height, width = (round(n * scale) for n in tiles[0][1].shape[:2])
    canvas = Image.new("RGB", (len(tiles) * width + (len(tiles) - 1) * GAP_PX, height + LABEL_PX), "white")
    draw = ImageDraw.Draw(canvas)
    font = ImageFont.load_default(size=15)
    for i, (label, tile) in enumerate(tiles):
        x = i * (width + GAP_PX)
        canvas.paste(Image.fromarray(tile).resize((width, height), Image.Resampling.LANCZOS), (x, LABEL_PX))
        draw.text((x + width / 2, LABEL_PX / 2), label, fill="black", font=font, anchor="mm")
    print(f"view {chosen}: {', '.join(label for label, _ in tiles)}")
    return canvas


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("project", type=Path, help="a finished demo project (DEMO/project)")
    parser.add_argument("--out", type=Path, required=True, help="the PNG to write")
    parser.add_argument("--view", help="held-out view (e.g. test_002.png; default: the largest mask)")
    parser.add_argument("--scale", type=float, default=0.75, help="tile size against the renders' (default 0.75)")
    args = parser.parse_args(argv)
    image = compose(ProjectLayout(args.project), args.view, args.scale).quantize(256, method=Image.Quantize.MEDIANCUT)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    image.save(args.out, optimize=True)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
