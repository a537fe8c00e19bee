"""Are two SfM runs with the same inputs and seed byte-identical? Full SfM and known-pose triangulation.

Runs each mode ``--repeats`` times on a data_synth scene (the ``tiny`` preset by default, generated into a
temporary folder) and prints, per run, the SHA-256 of every ``sparse/*.bin`` file, the number of registered
images and points, and whether all runs agree. ``--threads`` sets ``SfmOptions.num_threads`` (-1 = all cores).

    PYTHONPATH=$PWD python bench/bench_sfm_determinism.py --repeats 3
    PYTHONPATH=$PWD python bench/bench_sfm_determinism.py --threads -1   # the multi-threaded variant
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
from pathlib import Path


def _hashes(model: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()[:16] for p in sorted(model.glob("*.bin"))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, help="a data_synth scene folder (default: generate the tiny preset)")
    ap.add_argument("--preset", default="tiny")
    ap.add_argument("--images", type=Path, help="a folder of photos instead of a scene (full SfM only)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--threads", type=int, default=None, help="SfmOptions.num_threads (default: the option's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--nondeterministic", action="store_true", help="SfmOptions(deterministic=False): all threads")
    args = ap.parse_args()

    from data_synth import generate_scene
    from recon.model import from_reconstruction, read_reconstruction
    from recon.sfm import SfmOptions, run_sfm, triangulate_known_poses

    with tempfile.TemporaryDirectory(prefix="bench_sfm_det_") as tmpname:
        tmp = Path(tmpname)
        if args.images:
            import shutil

            scene = tmp / "photos"
            shutil.copytree(args.images, scene / "images")  # a private copy: nothing is written next to the data
        else:
            scene = args.scene or generate_scene(args.preset, tmp / "scene", seed=0)
        kw = {"seed": args.seed, "deterministic": not args.nondeterministic}
        kw |= {"num_threads": args.threads} if args.threads is not None else {}
        options = SfmOptions(**kw)
        print(f"scene {scene}  options {options}")
        known = (Path(scene) / "sparse" / "0").is_dir()
        cams = from_reconstruction(read_reconstruction(Path(scene) / "sparse" / "0")) if known else None
        for mode in ("full", "known") if known else ("full",):
            runs = []
            for r in range(args.repeats):
                out = tmp / f"{mode}_{r}" / "sparse"
                t0 = time.perf_counter()
                if mode == "full":
                    _, report = run_sfm(Path(scene) / "images", out, options, log_path=tmp / "colmap.log")
                else:
                    _, report = triangulate_known_poses(cams, Path(scene) / "images", out, options, tmp / "colmap.log")
                dt = time.perf_counter() - t0
                h = _hashes(out)
                runs.append(h)
                print(
                    f"{mode:5s} run {r}: {len(report.registered)} registered, {report.num_points} points, "
                    f"{dt:.1f} s  " + " ".join(f"{k}={v}" for k, v in h.items())
                )
                for w in report.warnings:
                    print(f"      {w}")
            same = all(h == runs[0] for h in runs)
            print(f"{mode:5s}: {'IDENTICAL' if same else 'DIFFERENT'} over {args.repeats} runs")


if __name__ == "__main__":
    main()
