"""Time and peak memory of every malformed-input case of ``tests/fuzz`` through the CLI.

Each case runs ``python -m hybridsplat ...`` in a subprocess (60 s, 2 GB address space, as the tests).
Peak memory is the child's peak RSS minus the baseline: the peak RSS of ``hybridsplat --version``, which
imports the same command modules. Without ``--modules`` the peak is ``wait4``'s ``ru_maxrss``, which also
counts the copy of this (growing) process made by ``fork``; with ``--modules`` it is the child's own VmHWM.
Targets: every case < 5 s and < 500 MB above the baseline. Prints one row per case, then the verdict counts
(clean, traceback, silent success, output left behind, unclear) and the slowest and largest cases, with
``uptime``'s load.

With ``--modules`` each case runs through ``MODULE_RECORDER`` (tests/fuzz/harness.py) and a column names the
heavy libraries (torch, open3d, numba, ...) it had imported when it exited; a summary line gives the slowest
case among those that imported torch. ``HYBRIDSPLAT_FUZZ_REPO=/path/to/checkout`` runs another checkout's CLI
(e.g. main, for a before/after comparison) on the same cases.

Usage: ``PYTHONPATH=. python bench/bench_fuzz.py [--only GLOB[,GLOB...]] [--repeat-baseline 3] [--modules]``
"""

from __future__ import annotations

import argparse
import fnmatch
import os
import shutil
import sys
import tempfile
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fuzz.cases import all_cases  # noqa: E402
from fuzz.harness import REPO, heavy_imports, run_case, run_cli  # noqa: E402

TARGET_S = 5.0
TARGET_MB = 500.0


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="*", help="run only the cases whose name matches one of these globs (a,b)")
    parser.add_argument("--repeat-baseline", type=int, default=3)
    parser.add_argument("--modules", action="store_true", help="record the heavy libraries each case imports")
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bench_fuzz_"))
    try:
        record = root / ".baseline.modules.json" if args.modules else None  # same wrapper as the cases
        base = [run_cli(["--version"], root, record_modules=record) for _ in range(args.repeat_baseline)]
        base_s = min(b[3] for b in base)
        base_mb = max(b[4] for b in base)
        print(f"CLI of {REPO}")
        print(f"load average before: {load()}")
        print(f"baseline `hybridsplat --version`: {base_s:.2f} s, peak RSS {base_mb:.0f} MB")
        heavy_head = "  heavy imports" if args.modules else ""
        print(
            f"{'case':46s} {'verdict':9s} {'exit':>4s} {'s':>6s} {'s-base':>6s} {'MB':>6s} {'MB-base':>7s}{heavy_head}"
        )
        outcomes = []
        for case in all_cases():
            if not any(fnmatch.fnmatch(case.name, glob) for glob in args.only.split(",")):
                continue
            o = run_case(case, root / case.name, record_modules=args.modules)
            outcomes.append(o)
            heavy = ""
            if args.modules:
                heavy = "  (no record)" if o.modules is None else "  " + (",".join(heavy_imports(o.modules)) or "-")
            print(
                f"{o.case:46s} {o.verdict:9s} {o.code if o.code is not None else 'kill':>4} {o.seconds:6.2f} "
                f"{o.seconds - base_s:6.2f} {o.peak_rss_mb:6.0f} {o.peak_rss_mb - base_mb:7.0f}{heavy}",
                flush=True,
            )
        counts = Counter(o.verdict for o in outcomes)
        slowest = max(outcomes, key=lambda o: o.seconds)
        largest = max(outcomes, key=lambda o: o.peak_rss_mb)
        print(f"\nload average after: {load()}")
        print(
            f"cases {len(outcomes)}: clean {counts['clean']}, traceback {counts['traceback']}, "
            f"silent success {counts['silent']}, output left behind {counts['leftover']}, unclear {counts['unclear']}"
        )
        print(
            f"slowest: {slowest.case} {slowest.seconds:.2f} s ({slowest.seconds - base_s:.2f} s above the "
            f"{base_s:.2f} s start-up); largest: {largest.case} {largest.peak_rss_mb:.0f} MB "
            f"({largest.peak_rss_mb - base_mb:.0f} MB above baseline)"
        )
        if args.modules:
            torch_cases = [o for o in outcomes if o.modules is not None and "torch" in heavy_imports(o.modules)]
            line = f"cases that imported torch: {len(torch_cases)}"
            if torch_cases:
                worst = max(torch_cases, key=lambda o: o.seconds)
                line += f"; slowest of them: {worst.case} {worst.seconds:.2f} s"
            print(line)
        over_s = [o.case for o in outcomes if o.seconds > TARGET_S]
        over_mb = [o.case for o in outcomes if o.peak_rss_mb - base_mb > TARGET_MB]
        print(f"over {TARGET_S:g} s (wall, start-up included): {len(over_s)}; over {TARGET_MB:g} MB above baseline: "
              f"{len(over_mb)} {over_mb}")  # fmt: skip
        bad = [o for o in outcomes if o.verdict != "clean"]
        for o in bad:
            print(f"\n--- {o.case}: {o.verdict}, exit {o.code}, leftovers {o.leftovers}\n{o.stderr.strip()[-800:]}")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
