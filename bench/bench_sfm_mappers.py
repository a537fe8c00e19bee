"""Incremental, global (GLOMAP) and hierarchical mapping on the same photos (issue 34), side by side.

For each photo set with known true cameras: full SfM (``recon.sfm.run_sfm``, the project's defaults) once per
mapper; prints photos registered, points, mean reprojection error (px), camera-centre error against the true
cameras after a similarity alignment (rms and max, metres and as a share of the camera path's extent), and the
mapping seconds (features and matching, identical for every mapper, are printed apart), with ratios against
incremental.

    python bench/bench_sfm_mappers.py [--fountain ../shared/data/real/fountain-P11] [--preset demo --preset tiny]
    python bench/bench_sfm_mappers.py --fountain none --scene BLOCK/scene      # the 126-photo aerial block

Synthetic presets are generated into ``--cache`` (their true cameras are the scene's sparse/0).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from recon.align import align_reconstruction_to_centers  # noqa: E402
from recon.model import from_reconstruction, read_reconstruction  # noqa: E402
from recon.sfm import Mapper, SfmOptions, run_sfm  # noqa: E402

MAPPERS = (Mapper.INCREMENTAL, Mapper.GLOBAL, Mapper.HIERARCHICAL)


def _photo_sets(args: argparse.Namespace) -> list[tuple[str, Path, dict[str, np.ndarray]]]:
    sets = []
    fountain = Path(args.fountain)
    if fountain.is_dir():
        from recon.reference import read_strecha_cameras

        truth = {v.name: v.center for v in read_strecha_cameras(fountain / "gt_dense_cameras")}
        sets.append(("fountain-P11", fountain / "images", truth))
    else:
        print(f"{fountain} is absent: fountain-P11 skipped")
    from data_synth import generate_scene

    for scene in args.scene or []:  # a generated scene, e.g. the 126-photo aerial block (docs/tiling.md)
        cameras = from_reconstruction(read_reconstruction(Path(scene) / "sparse" / "0"))
        sets.append((Path(scene).parent.name, Path(scene) / "images", {v.name: v.center for v in cameras}))
    for preset in args.preset or ([] if args.scene else ["tiny", "demo"]):
        root = Path(args.cache) / preset
        if not (root / "scene.json").is_file():
            generate_scene(preset, root, seed=1)
        cameras = from_reconstruction(read_reconstruction(root / "sparse" / "0"))
        sets.append((f"{preset} (seed 1)", root / "images", {v.name: v.center for v in cameras}))
    return sets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--fountain", default=str(Path(__file__).resolve().parents[2] / "shared/data/real/fountain-P11")
    )
    parser.add_argument("--preset", action="append", help="data_synth presets (default: tiny, demo)")
    parser.add_argument("--scene", action="append", help="a generated data_synth scene folder (its sparse/0: truth)")
    parser.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "hybridsplat_bench_mappers"))
    args = parser.parse_args()
    for name, images, truth in _photo_sets(args):
        extent = float(np.ptp(np.stack(list(truth.values())), axis=0).max())
        print(f"\n{name}: {len(truth)} true cameras, camera path extent {extent:.3g} m")
        print(
            f"{'mapper':<14}{'reg':>5}{'points':>8}{'reproj px':>10}{'rms m':>10}{'max m':>10}{'rms/ext':>9}"
            f"{'map s':>8}{'ratio':>7}{'feat+match s':>14}"
        )
        base = None
        for mapper in MAPPERS:
            with tempfile.TemporaryDirectory() as tmp:
                log = Path(tmp) / "colmap.log"
                rec, report = run_sfm(images, Path(tmp) / "sparse", SfmOptions(mapper=mapper), log_path=log)
            aligned = align_reconstruction_to_centers(rec, truth, threshold=0.05 * extent)
            base = base or report.seconds_mapping
            print(
                f"{mapper.value:<14}{len(report.registered):>5}{report.num_points:>8}"
                f"{report.mean_reprojection_error:>10.3f}{aligned.rms_inliers:>10.4f}{aligned.residuals.max():>10.4f}"
                f"{aligned.rms_inliers / extent:>9.5f}{report.seconds_mapping:>8.2f}"
                f"{report.seconds_mapping / base:>7.2f}{report.seconds_features + report.seconds_matching:>14.1f}"
            )


if __name__ == "__main__":
    main()
